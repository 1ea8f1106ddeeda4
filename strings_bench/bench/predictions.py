"""Reading predictions made anywhere: the three layouts of `strings-bench evaluate` (bench/evaluate.py),
archives unpacked safely, images and masks read with errors that name the file, renders matched to views.

- ``inria``: MODEL/test/ours_<N>/{renders,gt,masks}/00000.png (Inria 3DGS, the STRinGS release's render.py);
- ``nerfbaselines``: color/, gt-color/, optional mask/ and info.json; a folder, .zip or .tar.gz;
- ``folder``: a plain folder of renders named after the test views.
"""

from __future__ import annotations

import contextlib
import json
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Iterator

import numpy as np

from strings_bench.core.archives import safe_extract
from strings_bench.core.errors import StringsBenchError

LAYOUTS = ("inria", "nerfbaselines", "folder")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
OURS_DIR = re.compile(r"^ours_(\d+)$")


class PredictionsError(StringsBenchError):
    """The predictions (or the ground truth given with them) cannot be evaluated as they are."""


# ---- reading the predictions ----------------------------------------------------------------------
@dataclass
class Checkpoint:
    """One checkpoint's files: render key -> path; gt and masks keyed the same way (None: not in the layout)."""

    iteration: int
    renders: dict[str, Path]
    gt: dict[str, Path] | None = None
    masks: dict[str, Path] | None = None
    label: str | None = None


@dataclass
class Predictions:
    layout: str
    root: Path
    checkpoints: list[Checkpoint]
    info: dict = field(default_factory=dict)  # nerfbaselines' info.json
    index_named: bool = False  # render keys are positions in the test split (Inria's 00000.png)


def image_files(folder: Path, recursive: bool = False) -> dict[str, Path]:
    """Image files of `folder` keyed by their path relative to it without the suffix."""
    if not folder.is_dir():
        return {}
    pattern = "**/*" if recursive else "*"
    out = {}
    for p in sorted(folder.glob(pattern)):
        if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES:
            key = p.relative_to(folder).with_suffix("").as_posix()
            if key in out:
                raise PredictionsError(f"{out[key]} and {p} name the same view",
                                       hint="keep one image per view name (.png or .jpg, not both)")
            out[key] = p
    return out


def _inria_checkpoint(folder: Path, n: int) -> Checkpoint:
    renders = image_files(folder / "renders")
    if not renders:
        raise PredictionsError(f"{folder / 'renders'} has no images", hint="expected renders/00000.png, ...")
    gt = image_files(folder / "gt") if (folder / "gt").is_dir() else None
    masks = image_files(folder / "masks") if (folder / "masks").is_dir() else None
    return Checkpoint(n, renders, gt, masks)


def detect_layout(root: Path) -> Predictions:
    """The layout of the predictions folder `root` (see the module docstring); a clear error when none fits."""
    root = Path(root)
    if not root.exists():
        raise PredictionsError(f"predictions {root} do not exist", hint="give a folder of renders, an Inria 3DGS "
                               "model folder, or nerfbaselines predictions (folder, .zip or .tar.gz)")
    if not root.is_dir():
        raise PredictionsError(f"predictions {root} are a file, not a folder or a .zip / .tar.gz archive",
                               hint="give the folder that holds the renders")
    # Inria: MODEL/test/ours_N, MODEL/test, or ours_N itself
    for test_dir in (root / "test", root):
        ours = sorted((int(m.group(1)), p) for p in (test_dir.iterdir() if test_dir.is_dir() else [])
                      if p.is_dir() and (m := OURS_DIR.match(p.name)))
        if ours:
            return Predictions("inria", root, [_inria_checkpoint(p, n) for n, p in ours], index_named=True)
    if (m := OURS_DIR.match(root.name)) and (root / "renders").is_dir():
        return Predictions("inria", root, [_inria_checkpoint(root, int(m.group(1)))], index_named=True)
    if (root / "color").is_dir() and (root / "gt-color").is_dir():
        info = {}
        if (root / "info.json").exists():
            try:
                info = json.loads((root / "info.json").read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise PredictionsError(f"cannot read {root / 'info.json'}: {exc}",
                                       hint="nerfbaselines writes it with the predictions; restore or delete it") from exc
        renders = image_files(root / "color", recursive=True)
        if not renders:
            raise PredictionsError(f"{root / 'color'} has no images", hint="nerfbaselines writes color/<image>.png")
        masks = image_files(root / "mask", recursive=True) if (root / "mask").is_dir() else None
        it = info.get("num_iterations") if isinstance(info, dict) else None
        return Predictions("nerfbaselines", root,
                           [Checkpoint(int(it) if isinstance(it, int) and it >= 0 else 0, renders,
                                       image_files(root / "gt-color", recursive=True), masks)], info=info or {})
    renders = image_files(root)
    if renders:
        return Predictions("folder", root, [Checkpoint(0, renders)])
    raise PredictionsError(
        f"{root} holds no renders: no images, no test/ours_<N>/renders (Inria 3DGS), no color/ + gt-color/ "
        f"(nerfbaselines)", hint="point evaluate at the folder of renders (see docs/guide/evaluate.md)")


@contextlib.contextmanager
def open_predictions(path: Path, progress: bool = False) -> Iterator[Path]:
    """`path` as a folder: itself, or a .zip / .tar.gz extracted into a temporary folder (removed after) by the
    suite's one archive reader (core/archives.py: no paths outside the archive, no links, a size limit)."""
    path = Path(path)
    if path.is_dir() or not path.exists():
        yield path
        return
    if not path.name.lower().endswith((".zip", ".tar.gz", ".tgz", ".tar")):
        raise PredictionsError(f"predictions {path} are a file, not a folder or a .zip / .tar.gz archive",
                               hint="give the folder that holds the renders")
    with tempfile.TemporaryDirectory(prefix="strings-bench-pred-") as tmp:
        root = safe_extract(path, Path(tmp) / "predictions", progress=progress)
        entries = list(root.iterdir())
        # an archive of one folder (predictions/...) is read as that folder
        yield entries[0] if len(entries) == 1 and entries[0].is_dir() and not (root / "color").is_dir() else root


def read_rgb(path: Path) -> np.ndarray:
    """An image file as (H, W, 3) uint8; a clear error naming the file when it cannot be read."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("RGBA", "LA") or (im.mode == "P" and "transparency" in im.info):
                # as nerfbaselines' image_to_srgb does: alpha blended onto black
                arr = np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0
                return (arr[..., :3] * arr[..., 3:] * 255.0 + 0.5).astype(np.uint8)
            return np.asarray(im.convert("RGB"), dtype=np.uint8).copy()
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise PredictionsError(f"cannot read image {path}: {exc}", hint="the file is missing or corrupt; replace it") from exc


def read_mask(path: Path) -> np.ndarray:
    """A mask file as (H, W) bool: > 127 after conversion to 8-bit grey, as the release's metrics_ocr does."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("L")) > 127
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise PredictionsError(f"cannot read mask {path}: {exc}", hint="the file is missing or corrupt; replace it") from exc


# ---- matching renders to views ----------------------------------------------------------------------
def shown(items, n: int = 5) -> str:
    items = list(items)
    return ", ".join(str(x) for x in items[:n]) + (f" ... ({len(items)} in all)" if len(items) > n else "")


def match_renders(view_names: list[str], renders: dict[str, Path], index_named: bool, where: Path) -> dict[str, Path]:
    """view name -> render file. Renders are matched by the view's stem (its path without the suffix), or, for
    index-named renders (00000, 00001, ...), by position in `view_names`. Renders matching no view are an error."""
    if index_named and all(k.isdigit() for k in renders):
        by_key = {f"{i:05d}": n for i, n in enumerate(view_names)}
    else:
        by_key = {str(PurePosixPath(n).with_suffix("")): n for n in view_names}
    stray = [renders[k].name for k in renders if k not in by_key]
    if stray and len(stray) == len(renders):
        raise PredictionsError(
            f"no render in {where} is named after a test view: renders {shown(sorted(renders))}; "
            f"test views {shown(view_names)}",
            hint="name each render after its test view (<view stem>.png), or index them 00000.png... in test-split order")
    if stray:
        raise PredictionsError(f"render(s) {shown(sorted(stray))} in {where} match no test view",
                               hint=f"test views: {shown(view_names)}; remove the extra files or fix their names")
    return {by_key[k]: p for k, p in renders.items()}
