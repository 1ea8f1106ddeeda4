"""The `captures` dataset: real photographs with text, one scene per capture, built on first use.

Each capture is a folder of photos in the captures' data folder (`data_root`): the environment variable
STRINGS_BENCH_CAPTURES, else the folder recorded by `strings-bench datasets add captures DIR`, else
`shared/data` in the folder that holds the repository (where the suite's tests read them). A scene is made from
its photos by the path of `strings-bench prepare` (datasets/sfm.py, or datasets/bundler.py where the capture's own
Bundler cameras are given): photos upright, SfM, undistortion, OCR text masks, the held-out split; then
the capture's record (`capture.json`: photos registered and not, the split, the characters the OCR engine
reads on the held-out views' ground truth at each image size, whether that clears the floor below which
OCR-CER is not scored, and rho) is written beside it. The scene lives in CACHE/captures/<name>-<key>, the key
naming the settings it was built with; `capture.json` is written last, so a folder without it is rebuilt.

What the captures need, and why (docs/guide/datasets.md, "Real captures"):
- saharov32: its Bundler cameras are used (no SfM); its pixels are stored sideways with EXIF orientation 8,
  written upright with the cameras turned with them. Its text is Cyrillic: the GT is read with Tesseract `rus`.
- tum_freiburg3_office: PNG frames named by timestamp; the sequence's published intrinsics are given to SfM,
  which keeps them fixed.
- bundler_et: 9 photos, too few for every-8th test views (scene.sparse_split); some frames were shot with the
  camera turned (pixels rotated, EXIF orientation 1): OCR reads text turned by 90 degrees too.
- watch_clock: 44 phone photos; SfM does not register all of them (the record lists those left out).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

from strings_bench.core.errors import DatasetError
from strings_bench.core.io import atomic_write_json, cache_root
from strings_bench.eval.floors import MIN_GT_CHARS

CAPTURES_ENV = "STRINGS_BENCH_CAPTURES"
DATASET_ID = "captures"
# The default data folder: shared/data in the folder that holds the repository (a checkout of the suite).
DEFAULT_DATA_ROOT = Path(__file__).resolve().parents[3] / "shared" / "data"
RECORD_FILE = "capture.json"
RECORD_VERSION = 1  # bump when the build or the record changes: older builds are made again

# OCR-CER of a scene whose held-out GT reads fewer characters than MIN_GT_CHARS is not scored (eval/floors.py says
# why 50; eval/protocol.py applies it).
GT_DOWNSCALES = (1, 2)  # the image sizes whose GT characters the record counts


@dataclass(frozen=True)
class Capture:
    """One capture: where its photos are under the data folder and how its scene is made."""

    name: str
    folder: str  # under the data folder
    description: str
    photos: str = ""  # the photos' sub-folder ("": the folder itself)
    bundler: bool = False  # the folder holds a Bundler reconstruction (cameras.out): its cameras are used, no SfM
    intrinsics: tuple[float, float, float, float] | None = None  # fx, fy, cx, cy (OpenCV convention), kept fixed
    max_size: int = 1600
    gt_ocr: str = "rapidocr"  # the engine that reads the GT's text (`run --ocr`)
    # SfM threads. Seeded single-threaded SfM is repeatable; multi-threaded it is not, and small changes of the
    # self-calibrated cameras move the OCR masks and what the GT reads: three 2-thread builds of bundler_et read
    # 59, 80 and 107 characters on its held-out views.
    sfm_threads: int = 1
    source: str = ""

    def key(self) -> str:
        """A short hash of the build settings (the cache folder's suffix)."""
        spec = {**asdict(self), "version": RECORD_VERSION, "min_gt_chars": MIN_GT_CHARS}
        spec.pop("description"), spec.pop("source")
        return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:8]


CAPTURES: dict[str, Capture] = {c.name: c for c in (
    Capture("saharov32", "saharov32", "monument with Cyrillic lettering, a plaque and building signs; given Bundler "
            "cameras", photos="images", bundler=True, gt_ocr="tesseract:lang=rus:upscale=3:mask_fill=128",
            source="PhotogrammetryCourse/PhotogrammetryTasks2024 (MIT)"),
    Capture("watch_clock", "watch_clock", "wall clock: dial numerals and a brand name; 44 phone photos",
            photos="images", source="cobanov/nerf-watch-dataset (no licence stated)"),
    Capture("bundler_et", "bundler_et", "book spines and a phone-book cover beside a plush toy; 9 photos, frames "
            "shot sideways", source="snavely/bundler_sfm, examples/ET (GPL repository)"),
    Capture("tum_freiburg3_office", "tum_freiburg3_office", "office desk: bottle labels, a magazine, a globe; 17 "
            "frames named by timestamp, published intrinsics", intrinsics=(535.4, 539.2, 320.1, 247.6),
            source="TUM RGB-D fr3 long_office_household (CC BY 4.0)"),
)}


def data_root() -> tuple[Path, str]:
    """The captures' data folder and how it was found (environment, index, default)."""
    env = os.environ.get(CAPTURES_ENV)
    if env:
        return Path(env).expanduser(), f"${CAPTURES_ENV}"
    from strings_bench.datasets.card import read_index

    index = read_index()
    if DATASET_ID in index:
        return Path(index[DATASET_ID]), "`strings-bench datasets add captures DIR`"
    return DEFAULT_DATA_ROOT, "the default location"


def _where_hint() -> str:
    return (f"point the suite at the folder holding {', '.join(c.folder for c in CAPTURES.values())}: "
            f"`export {CAPTURES_ENV}=DIR` or `strings-bench datasets add captures DIR`")


def get_capture(name: str) -> Capture:
    if name not in CAPTURES:
        raise DatasetError(f"dataset captures has no scene {name!r}", hint=f"its scenes: {', '.join(CAPTURES)}")
    return CAPTURES[name]


def capture_source(name: str, root: Path | None = None) -> Path:
    """The folder of a capture's photos (and Bundler files); DatasetError saying where it looked."""
    cap = get_capture(name)
    how = "given"
    if root is None:
        root, how = data_root()
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"the captures' data folder {root} does not exist (found through {how})", hint=_where_hint())
    src = root / cap.folder
    if not src.is_dir():
        raise DatasetError(f"capture {name!r} is not in the data folder {root} (looked for {src}; found through {how})",
                           hint=_where_hint())
    return src


def check_data_root(path: Path) -> list[str]:
    """The captures present in `path`; DatasetError when it holds none (for `datasets add captures DIR`)."""
    present = [c.name for c in CAPTURES.values() if (Path(path) / c.folder).is_dir()]
    if not present:
        raise DatasetError(f"{path} holds none of the captures ({', '.join(c.folder for c in CAPTURES.values())})",
                           hint="pass the folder that holds the capture folders")
    return present


def scene_dir(name: str) -> Path:
    """Where capture `name`'s scene is (or will be) built."""
    return cache_root() / DATASET_ID / f"{name}-{get_capture(name).key()}"


def is_built(name: str) -> bool:
    return (scene_dir(name) / RECORD_FILE).is_file()


def read_record(path: Path) -> dict | None:
    """A built capture's record (capture.json), None when there is none."""
    try:
        return json.loads((Path(path) / RECORD_FILE).read_text())
    except (OSError, ValueError):
        return None


def build_capture(name: str, root: Path | None = None, force: bool = False, progress: bool = True,
                  echo: Callable[[str], None] = print) -> Path:
    """The scene folder of capture `name`, built (SfM or the given cameras, masks, split, record) when it is not."""
    cap = get_capture(name)
    dest = scene_dir(name)
    if is_built(name) and not force:
        return dest
    src = capture_source(name, root)
    t0 = time.perf_counter()
    echo(f"building capture {name} from {src} into {dest}")
    if cap.bundler:
        from strings_bench.datasets.bundler import prepare_bundler_scene

        result = prepare_bundler_scene(src, name, out=dest, max_size=cap.max_size, overwrite=True, register=False,
                                       progress=progress, echo=echo)
    else:
        from strings_bench.datasets.sfm import prepare_scene

        result = prepare_scene(src / cap.photos if cap.photos else src, name, out=dest, max_size=cap.max_size,
                               overwrite=True, register=False, progress=progress, echo=echo, intrinsics=cap.intrinsics,
                               num_threads=cap.sfm_threads)
    prepare_seconds = time.perf_counter() - t0
    t1 = time.perf_counter()
    record = measure(dest, cap)
    record.update(prepare=json.loads((dest / "prepare.json").read_text()), prepare_seconds=prepare_seconds,
                  record_seconds=time.perf_counter() - t1, source=str(src))
    atomic_write_json(dest / RECORD_FILE, record)
    echo(result.summary())
    return dest


def measure(path: Path, cap: Capture) -> dict:
    """The record's measurements on a prepared scene: the GT characters read on the held-out views at each size of
    GT_DOWNSCALES by the capture's GT engine, and rho (scene/difficulty.py)."""
    from strings_bench.scene.difficulty import recorded_difficulty
    from strings_bench.scene.scene import Scene

    scene = Scene.load(path, name=cap.name, settings=scene_settings(cap))
    d = recorded_difficulty(scene)
    gt = {str(ds): gt_characters(scene, cap.gt_ocr, ds) for ds in GT_DOWNSCALES}
    return {"version": RECORD_VERSION, "capture": cap.name, "key": cap.key(), "gt_ocr": cap.gt_ocr,
            "min_gt_chars": MIN_GT_CHARS, "gt_characters": gt,
            "test_views": [scene.names[i] for i in scene.test_idx], "train_views": len(scene.train_idx),
            "difficulty": d.as_dict()}


def gt_characters(scene, engine_spec: str, downscale: float) -> dict:
    """What `engine_spec` reads on the scene's held-out GT views at `downscale`, through the evaluation text mask as
    a run reads them: characters as OCR-CER counts them (its denominator), per view, and the words."""
    from strings_bench.eval import cer
    from strings_bench.eval.ocr import get_engine
    from strings_bench.eval.protocol import scene_views, to_uint8

    engine = get_engine(engine_spec)
    pairs, texts = {}, {}
    for v in scene_views(scene, downscale):
        words = engine.read(to_uint8(v.gt), mask=v.mask)
        pairs[v.name] = (words, words)
        texts[v.name] = " ".join(w.text for w in words)
    scored = cer.scene_cer(pairs)  # counts characters as OCR-CER does
    views = {n: scored.images[n].chars if n in scored.images else 0 for n in pairs}
    return {"chars": scored.chars, "views": views, "texts": texts, "scored": scored.chars >= MIN_GT_CHARS}


def scene_settings(cap: Capture) -> dict:
    """The per-scene settings of a capture's card: the floor on GT characters and the engine that reads its text."""
    return {"min_gt_chars": MIN_GT_CHARS, "gt_ocr": cap.gt_ocr}


def locate(name: str) -> Path:
    """The card's locate: build capture `name` on first use (with progress bars unless the command turned them off)."""
    from strings_bench.core.progress import progress_shown

    return build_capture(name, progress=progress_shown())


def card():
    from strings_bench.datasets.card import DatasetCard, SceneCard

    return DatasetCard(
        id=DATASET_ID,
        title="real photographs with text (one scene per capture, built on first use from the data folder)",
        scenes=[SceneCard(c.name, scene_settings(c), c.description) for c in CAPTURES.values()],
        source="; ".join(f"{c.name}: {c.source}" for c in CAPTURES.values()),
        licence="per capture (see source); the photos are not shipped with the suite",
        layout="DIR/<capture>/ photos (saharov32/: images/, cameras.out, ordered_filenames.txt); DIR from "
               f"${CAPTURES_ENV}, `datasets add captures DIR`, else shared/data in the folder that holds the repository",
        locate=locate,
        notes=f"OCR-CER is not scored on a scene whose held-out GT reads fewer than {MIN_GT_CHARS} characters; "
              "saharov32's text is Cyrillic: run it with --ocr tesseract:lang=rus:upscale=3:mask_fill=128.",
    )
