"""Photos -> a scene folder: structure from motion with pycolmap, undistortion, downscaled copies,
and text masks from the OCR detector.

Stages (each timed; the summary lists them):
  resize     copy the photos, upright (EXIF orientation applied) and at most `max_size` px on the
             long side, so SfM stays fast on a small machine
  features   SIFT extraction (pycolmap.extract_features), one shared camera when all photos agree
  matching   exhaustive for small sets, sequential (video-like order) for large ones
  mapping    incremental SfM; the model with the most registered images is kept
  undistort  to PINHOLE cameras (pycolmap.undistort_images), the layout every method reads
  downscale  images_2/, images_4/ at the sizes Scene expects (round(w / f))
  masks      OCR word polygons filled into masks/<stem>.png (tight; dilated at use time)

The scene is built in a temporary sibling folder and renamed into place at the end, so an
interrupted run never leaves a half-made scene where `--datasets` would find it.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from PIL import Image, ImageOps
from tqdm import tqdm

from strings_bench.core.errors import DatasetError
from strings_bench.core.io import atomic_write_json, cache_root

log = logging.getLogger(__name__)

PHOTO_SUFFIXES = {".jpg", ".jpeg", ".png"}
EXHAUSTIVE_MAX_IMAGES = 80  # exhaustive matching is O(n^2); above this use sequential pairs
DOWNSCALES = (2, 4)


@dataclass
class PrepareResult:
    scene_dir: Path
    num_photos: int
    num_registered: int
    num_points: int
    num_models: int
    matcher: str
    stage_seconds: dict[str, float] = field(default_factory=dict)
    num_masks: int | None = None  # None: masks were not made
    num_masks_with_text: int | None = None
    unregistered: list[str] = field(default_factory=list)

    def summary(self) -> str:
        lines = [
            f"scene {self.scene_dir}",
            f"  registered {self.num_registered} of {self.num_photos} photos "
            f"({self.num_models} model(s) found, kept the largest; matcher: {self.matcher})",
            f"  {self.num_points} sparse points",
        ]
        if self.unregistered:
            shown = ", ".join(self.unregistered[:8]) + (" ..." if len(self.unregistered) > 8 else "")
            lines.append(f"  not registered (left out of the scene): {shown}")
        if self.num_masks is not None:
            lines.append(f"  masks: {self.num_masks} written, {self.num_masks_with_text} with text")
        else:
            lines.append("  masks: not made (--no-masks)")
        total = sum(self.stage_seconds.values())
        lines.append("  time per stage: " + ", ".join(f"{k} {v:.1f}s" for k, v in self.stage_seconds.items())
                     + f" (total {total:.1f}s)")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {
            "scene_dir": str(self.scene_dir),
            "num_photos": self.num_photos,
            "num_registered": self.num_registered,
            "num_points": self.num_points,
            "num_models": self.num_models,
            "matcher": self.matcher,
            "stage_seconds": self.stage_seconds,
            "num_masks": self.num_masks,
            "num_masks_with_text": self.num_masks_with_text,
            "unregistered": self.unregistered,
        }


def list_photos(photos_dir: Path) -> list[Path]:
    photos_dir = Path(photos_dir)
    if not photos_dir.is_dir():
        raise DatasetError(f"photo folder {photos_dir} does not exist", hint="pass the folder that holds your photos")
    photos = sorted(p for p in photos_dir.iterdir() if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES)
    if not photos and (photos_dir / "images").is_dir():
        return list_photos(photos_dir / "images")
    if len(photos) < 3:
        raise DatasetError(
            f"{photos_dir} holds {len(photos)} photo(s) (.jpg/.jpeg/.png); SfM needs at least 3, better 20+",
            hint="take overlapping photos walking around the object, then point `prepare` at their folder",
        )
    return photos


def default_scene_dir(name: str) -> Path:
    return cache_root() / "scenes" / name


def prepare_scene(
    photos_dir: str | Path,
    name: str,
    out: str | Path | None = None,
    max_size: int = 1600,
    masks: bool = True,
    matcher: str = "auto",
    num_threads: int = -1,
    overwrite: bool = False,
    register: bool = True,
    ocr_backend: str = "rapidocr",
    max_features: int = 8192,
    progress: bool = True,
    echo: Callable[[str], None] = print,
    seed: int = 0,
    intrinsics: tuple[float, float, float, float] | None = None,
) -> PrepareResult:
    """Run the whole photos -> scene pipeline; returns counts and per-stage seconds.

    `intrinsics` (fx, fy, cx, cy in pixels of the photos as stored, OpenCV's convention: the first pixel's centre is
    (0, 0); e.g. a sequence's published calibration) gives
    every photo one PINHOLE camera that SfM keeps fixed instead of estimating it; the photos must share one size."""
    import pycolmap

    # COLMAP's RANSAC and mapper draw random numbers: seeded, a single-threaded run (num_threads=1)
    # is repeatable; multi-threaded runs still vary (on a 12-photo test capture 2 of 12 photos
    # registered in about 1 run in 5).
    pycolmap.set_random_seed(int(seed))

    photos = list_photos(Path(photos_dir))
    scene_dir = Path(out) if out is not None else default_scene_dir(name)
    scene_dir = scene_dir.resolve()
    if scene_dir.exists():
        if not overwrite:
            raise DatasetError(f"{scene_dir} already exists", hint="pass --overwrite to rebuild it, or --out elsewhere")
    if matcher not in ("auto", "exhaustive", "sequential"):
        raise DatasetError(f"unknown matcher {matcher!r}", hint="use auto, exhaustive or sequential")
    if matcher == "auto":
        matcher = "exhaustive" if len(photos) <= EXHAUSTIVE_MAX_IMAGES else "sequential"

    # COLMAP logs every image and every BA step; keep its warnings, show the rest with -v.
    old_log_level = pycolmap.logging.minloglevel
    if not log.isEnabledFor(logging.DEBUG):
        pycolmap.logging.minloglevel = max(old_log_level, 1)

    work = scene_dir.with_name(f".{scene_dir.name}.prepare-tmp")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    stages: dict[str, float] = {}
    stage = numbered_stages(7 if masks else 6, stages, echo)

    try:
        # 1. resize: upright, bounded copies that SfM and every later stage share.
        t = stage(f"resize {len(photos)} photos to <= {max_size} px")
        raw = work / "input"
        raw.mkdir()
        for p in tqdm(photos, desc="resize", unit="img", disable=not progress):
            _write_upright_resized(p, raw / p.name, max_size)
        stages["resize"] = time.perf_counter() - t

        # 2. features
        t = stage("extract SIFT features")
        db = work / "database.db"
        sizes = {Image.open(raw / p.name).size for p in photos}
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "SIMPLE_RADIAL"
        if intrinsics is not None:
            reader.camera_model = "PINHOLE"
            reader.camera_params = known_camera_params(intrinsics, photos, sizes)
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = num_threads
        extraction.sift.max_num_features = max_features
        pycolmap.extract_features(
            db, raw,
            camera_mode=pycolmap.CameraMode.SINGLE if len(sizes) == 1 else pycolmap.CameraMode.AUTO,
            reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
        )
        stages["features"] = time.perf_counter() - t

        # 3. matching
        t = stage(f"match features ({matcher})")
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = num_threads
        # Guided matching re-matches with the verified geometry; on the wall-clock capture it took
        # registration from 27 to 42 of 44 photos (plain walls give few putative matches).
        matching.guided_matching = True
        if matcher == "exhaustive":
            pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
        else:
            pycolmap.match_sequential(db, matching_options=matching, device=pycolmap.Device.cpu)
        stages["matching"] = time.perf_counter() - t

        # 4. mapping
        t = stage("incremental mapping")
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = num_threads
        if intrinsics is not None:  # known calibration: bundle adjustment moves poses and points only
            options.ba_refine_focal_length = False
            options.ba_refine_principal_point = False
            options.ba_refine_extra_params = False
        maps = pycolmap.incremental_mapping(db, raw, work / "sparse_raw", options=options)
        stages["mapping"] = time.perf_counter() - t
        if not maps:
            raise DatasetError(
                f"SfM registered no images from {photos_dir}",
                hint="the photos need overlap and texture: walk around the object taking a photo every few degrees",
            )
        best_idx, best = max(maps.items(), key=lambda kv: (kv[1].num_reg_images(), kv[1].num_points3D()))
        # Self-calibration on few photos can end with a camera of focal length <= 0 (a mirrored camera no
        # method can train with); `datasets check` refuses such a model, so those photos are left out here.
        broken = _drop_invalid_cameras(best)
        if broken:
            echo(f"leaving out {len(broken)} photo(s) whose self-calibrated camera came out invalid "
                 f"(focal length <= 0 or not finite): {', '.join(broken[:8])}{' ...' if len(broken) > 8 else ''}")
            if not best.num_reg_images():
                raise DatasetError(f"SfM registered no usable images from {photos_dir}",
                                   hint="the photos need overlap and texture: walk around the object taking a photo "
                                        "every few degrees")
            shutil.rmtree(work / "sparse_raw" / str(best_idx), ignore_errors=True)
        num_registered = best.num_reg_images()
        registered_names = {im.name for im in best.images.values() if im.has_pose}
        unregistered = sorted(p.name for p in photos if p.name not in registered_names)
        best_dir = work / "sparse_raw" / str(best_idx)
        if not best_dir.is_dir():  # older pycolmap versions write models only on request
            best_dir.mkdir(parents=True)
            best.write(str(best_dir))

        scene_tmp, num_masks, num_text = finish_scene(best_dir, raw, work, max_size, masks, ocr_backend, progress, stage,
                                                      stages)
        rec = pycolmap.Reconstruction(str(scene_tmp / "sparse" / "0"))
        result = PrepareResult(
            scene_dir=scene_dir, num_photos=len(photos), num_registered=num_registered,
            num_points=rec.num_points3D(), num_models=len(maps), matcher=matcher, stage_seconds=stages,
            num_masks=num_masks, num_masks_with_text=num_text, unregistered=unregistered,
        )
        split = write_sparse_split(scene_tmp)
        atomic_write_json(scene_tmp / "prepare.json", {**result.to_dict(), "photos_dir": str(Path(photos_dir).resolve()),
                                                       "max_size": max_size, "split": split,
                                                       "intrinsics": None if intrinsics is None else
                                                       {"fx": intrinsics[0], "fy": intrinsics[1], "cx": intrinsics[2],
                                                        "cy": intrinsics[3], "refined": False}})
        publish_scene(scene_tmp, scene_dir)
    finally:
        shutil.rmtree(work, ignore_errors=True)
        pycolmap.logging.minloglevel = old_log_level

    if register:
        register_scene(name, scene_dir)
    return result


def known_camera_params(intrinsics, photos: list[Path], sizes: set[tuple[int, int]]) -> str:
    """COLMAP's PINHOLE parameters "fx,fy,cx,cy" for the resized copies, from `intrinsics` given for the photos as
    stored; DatasetError when the photos differ in size (one calibration cannot describe them)."""
    if len(sizes) != 1:
        raise DatasetError(f"known intrinsics were given but the photos have {len(sizes)} sizes: {sorted(sizes)[:4]}",
                           hint="one calibration describes photos of one size; leave out --intrinsics to estimate them")
    with Image.open(photos[0]) as im:
        stored_w = ImageOps.exif_transpose(im).size[0]
    scale = next(iter(sizes))[0] / stored_w
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    if not (fx > 0 and fy > 0):
        raise DatasetError(f"known intrinsics {intrinsics} have a focal length <= 0", hint="fx and fy are in pixels, > 0")
    # Published calibrations (OpenCV, TUM RGB-D) put the first pixel's centre at 0, COLMAP at 0.5: cx + 0.5.
    return ",".join(f"{v:.6g}" for v in (fx * scale, fy * scale, (cx + 0.5) * scale, (cy + 0.5) * scale))


def write_sparse_split(scene_dir: Path) -> dict:
    """Write split.json where the scene is too sparse for the every-8th test split (scene.sparse_split); returns the
    rule applied and the test views, for the scene's record."""
    from strings_bench.scene.colmap import read_model
    from strings_bench.scene.scene import SPLIT_FILE, TEST_EVERY, sparse_split

    names = read_model(scene_dir).names
    test, every = sparse_split(names)
    if every != TEST_EVERY:
        atomic_write_json(scene_dir / SPLIT_FILE, {"test": test, "rule": f"one view in {every} (sorted by name): "
                                                   f"one in {TEST_EVERY} would hold out fewer than 3"})
    return {"every": every, "test": test, "views": len(names)}


def publish_scene(scene_tmp: Path, scene_dir: Path) -> None:
    """Move a finished scene folder into place, replacing an older one (prepare and prepare --bundler)."""
    if scene_dir.exists():
        shutil.rmtree(scene_dir)
    scene_dir.parent.mkdir(parents=True, exist_ok=True)
    os.replace(scene_tmp, scene_dir)


def register_scene(name: str, scene_dir: Path) -> None:
    """Record a prepared scene in the user's index of local copies (the registry reads new entries on lookup)."""
    from strings_bench.datasets.card import read_index, write_index

    index = read_index()
    index[name] = str(scene_dir)
    write_index(index)


def numbered_stages(total: int, stages: dict[str, float], echo: Callable[[str], None]) -> Callable[[str], float]:
    """`stage(label)`: prints "[k/total] label ..." (k: the stages recorded in `stages` so far, plus one) and returns
    the start time; the caller records the stage's seconds in `stages`. Shared by SfM and datasets/bundler.py."""
    def stage(label: str) -> float:
        echo(f"[{len(stages) + 1}/{total}] {label} ...")
        return time.perf_counter()

    return stage


def finish_scene(model_dir: Path, raw: Path, work: Path, max_size: int, masks: bool, ocr_backend: str, progress: bool,
                 stage: Callable[[str], float], stages: dict[str, float]) -> tuple[Path, int | None, int | None]:
    """The stages after the model is known (SfM here, given cameras in datasets/bundler.py): undistort
    `raw` images with the model in `model_dir` into work/scene (images/, sparse/0/), write images_2/ and
    images_4/, and the text masks. Returns (the scene folder, masks written, masks with text)."""
    import pycolmap

    best_dir = model_dir
    # 5. undistort into the final layout
    t = stage("undistort to pinhole cameras")
    undist = work / "undistorted"
    undistort_options = pycolmap.UndistortCameraOptions()
    if max_size and max_size > 0:
        # The undistorted frame can come out larger than the input; keep the --max-size promise.
        undistort_options.max_image_size = max_size
    pycolmap.undistort_images(undist, best_dir, raw, output_type="COLMAP", undistort_options=undistort_options)
    scene_tmp = work / "scene"
    scene_tmp.mkdir()
    os.replace(undist / "images", scene_tmp / "images")
    (scene_tmp / "sparse").mkdir()
    model_src = undist / "sparse"
    if (model_src / "0").is_dir():
        model_src = model_src / "0"
    os.replace(model_src, scene_tmp / "sparse" / "0")
    stages["undistort"] = time.perf_counter() - t

    # 6. downscaled copies at the sizes Scene.image_path expects
    t = stage("write images_2/ and images_4/")
    images = sorted((scene_tmp / "images").iterdir())
    for f in DOWNSCALES:
        d = scene_tmp / f"images_{f}"
        d.mkdir()
        for p in tqdm(images, desc=f"images_{f}", unit="img", disable=not progress):
            with Image.open(p) as im:
                w, h = im.size
                size = (max(1, int(round(w / f))), max(1, int(round(h / f))))
                save_like(im.convert("RGB").resize(size, Image.Resampling.LANCZOS), d / p.name)
    stages["downscale"] = time.perf_counter() - t

    # 7. text masks
    num_masks = num_text = None
    if masks:
        t = stage(f"text masks from OCR ({ocr_backend})")
        num_masks, num_text = write_text_masks(scene_tmp / "images", scene_tmp / "masks", ocr_backend, progress)
        stages["masks"] = time.perf_counter() - t

    return scene_tmp, num_masks, num_text


def _drop_invalid_cameras(rec) -> list[str]:
    """Deregister the images of `rec` whose camera has a focal length <= 0 or non-finite parameters;
    returns their names."""
    bad = []
    for im in list(rec.images.values()):
        if not im.has_pose:
            continue
        cam = rec.cameras[im.camera_id]
        params = np.asarray(cam.params, dtype=np.float64)
        if not np.all(np.isfinite(params)) or cam.focal_length_x <= 0 or cam.focal_length_y <= 0:
            bad.append(im.name)
            rec.deregister_frame(im.frame_id)
    return sorted(bad)


def save_like(im: Image.Image, dest: Path) -> None:
    if dest.suffix.lower() in (".jpg", ".jpeg"):
        im.save(dest, quality=95)
    else:
        im.save(dest)


def _write_upright_resized(src: Path, dest: Path, max_size: int) -> None:
    try:
        with Image.open(src) as im:
            # Phones store pixels sideways plus an EXIF flag; SfM and OCR both want upright pixels.
            im = ImageOps.exif_transpose(im).convert("RGB")
            w, h = im.size
            scale = max_size / max(w, h) if max_size and max_size > 0 else 1.0
            if scale < 1.0:
                im = im.resize((max(1, round(w * scale)), max(1, round(h * scale))), Image.Resampling.LANCZOS)
            save_like(im, dest)
    except OSError as exc:
        raise DatasetError(f"cannot read photo {src}: {exc}", hint="remove or replace the corrupt file") from exc


# ---- text masks -----------------------------------------------------------------------------
def write_text_masks(images_dir: Path, masks_dir: Path, backend: str = "rapidocr", progress: bool = True) -> tuple[int, int]:
    """One PNG per image, white inside the word polygons the OCR detector finds.

    The masks are tight (filled polygons, not dilated): strings_bench.eval.text_masks dilates them at use
    time with the chosen kernel (paper 5 % of the width), exactly as it does for Hi-SAM masks.
    Returns (masks written, masks with any text).
    """
    from strings_bench.eval.ocr import get_engine, read_many
    from strings_bench.eval.text_masks import word_polygon_mask

    ocr = get_engine(backend)
    masks_dir.mkdir(parents=True, exist_ok=True)
    photos = sorted(images_dir.iterdir())

    def loader(p: Path):
        def load() -> np.ndarray:  # in the OCR worker, so that only `workers` photos are in memory at once
            with Image.open(p) as im:
                return np.asarray(im.convert("RGB"))
        return load

    def sizes(p: Path) -> tuple[int, int]:
        with Image.open(p) as im:
            return im.height, im.width

    # The detector is the slow part (123 s for 42 photos one at a time): read_many runs it on the cores.
    reads = read_many(ocr, [loader(p) for p in photos], progress=progress, desc="masks")
    written = with_text = 0
    for p, words in zip(photos, reads):
        if isinstance(words, Exception):
            raise words
        mask = word_polygon_mask(words, sizes(p))
        Image.fromarray((mask * 255).astype(np.uint8)).save(masks_dir / f"{p.stem}.png")
        written += 1
        with_text += int(mask.any())
    return written, with_text
