"""Text masks: where the text is in each view, for STRinGS training and for OCR-CER.

One module for every text mask of the suite: STRinGS trains with `text_masks`, the evaluation
protocol reads OCR through `eval_mask`, and `strings-bench prepare` (datasets/sfm.py) writes
its OCR masks with `word_polygon_mask`. A metric therefore never depends on one method's package.

Three providers make the *tight* mask of a view (text strokes / word boxes):

- ``"dataset"``: the scene's ``masks/`` folder (one PNG per image, ``<image stem>.png``). This is
  how Hi-SAM masks made elsewhere come in (see docs/strings.md); synthetic scenes ship their
  ground-truth masks there.
- ``"ocr"``: the word polygons an OCR backend detects (offline stand-in for Hi-SAM), filled.
- ``"gt"``: ground truth of synthetic scenes: the ``masks/`` file (when present) united with the
  filled polygons of ``text_annotations.json``.

The tight mask is then dilated with a circular kernel whose diameter is a fraction of the image
width (paper: 5 %; the release README says 20 %; the release script's default is an absolute
225 px, settable here as ``dilation_px``). Dilation is computed exactly with a Euclidean distance
transform: a pixel is in the dilated mask iff its centre lies within ``diameter / 2`` of the centre
of a mask pixel, which equals binary dilation with ``skimage.morphology.disk(diameter / 2)`` for an
integer radius (tested).

Masks shipped *already dilated*: the STRinGS release's datasets ship masks/ that are the output of
its Hi-SAM script (`text_segmentation.sh <dataset> <dilation>`, 20 % of the width "for all
experiments"), and both its training (`view.gt_mask`) and its OCR-CER (`metrics_ocr`, image x
mask > 127) read them as they are. ``MaskSettings.predilated`` says how the ``"dataset"`` provider
treats a scene's masks/: ``"auto"`` (default) uses them undilated when the scene is in the release's
layout (``hisam_jsons/`` and ``masks_vis/`` beside ``masks/``) or its card says ``masks_dilated``,
and dilates them otherwise; ``"yes"`` / ``"no"`` force either.

Dilated masks are cached as PNG under ``cache_root()/masks/<scene hash>/<settings hash>/``; the
file name carries a hash of the inputs (mask file / image / annotation file size and mtime), so an
edited input is never served stale.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Mapping

import numpy as np

from strings_bench.scene.polygons import fill_polygons
from strings_bench.core.errors import DatasetError, StringsBenchError
from strings_bench.core.io import atomic_write, cache_root

if TYPE_CHECKING:
    from strings_bench.scene.scene import Scene

log = logging.getLogger(__name__)

MASK_SOURCES = ("dataset", "ocr", "gt")
PREDILATED = ("auto", "yes", "no")
# Folders the STRinGS release ships beside masks/ (its Hi-SAM polygons and mask previews): a scene
# folder holding them is the release's, whose masks are already dilated.
RELEASE_LAYOUT_DIRS = ("hisam_jsons", "masks_vis")
PAPER_DILATION_FRACTION = 0.05  # paper: kernel diameter = 5 % of the image width
RELEASE_README_DILATION_FRACTION = 0.20  # authors' release README
RELEASE_SCRIPT_DILATION_PX = 225.0  # authors' release script default (pixels at full resolution)
_CACHE_VERSION = 1  # bump when the way masks are made changes


class MissingMasksError(DatasetError):
    """A view has no text mask from the chosen provider."""


@dataclass(frozen=True)
class MaskSettings:
    """How text masks are made. Everything that changes a mask is here (it keys the cache).

    source: "dataset" | "ocr" | "gt" (see module docstring).
    dilation_fraction: kernel diameter as a fraction of the image width (0 = no dilation).
    dilation_px: if set, an absolute kernel diameter in full-resolution pixels (release script: 225),
        scaled with the downscale factor; overrides dilation_fraction.
    ocr_backend: OCR backend name for source="ocr".
    predilated: source="dataset" only: are the scene's masks/ already dilated (then used as they are)?
        "auto" (the release's layout or the card's `masks_dilated` say so), "yes" or "no".
    """

    source: str = "dataset"
    dilation_fraction: float = PAPER_DILATION_FRACTION
    dilation_px: float | None = None
    ocr_backend: str = "rapidocr"
    predilated: str = "auto"

    def __post_init__(self):
        if self.source not in MASK_SOURCES:
            raise StringsBenchError(f"unknown text-mask source {self.source!r}",
                                    hint=f"use one of: {', '.join(MASK_SOURCES)}")
        if not (np.isfinite(self.dilation_fraction) and 0 <= self.dilation_fraction <= 1):
            raise StringsBenchError(f"mask dilation_fraction must be in [0, 1], got {self.dilation_fraction}",
                                    hint="the paper uses 0.05 (5 % of the image width)")
        if self.dilation_px is not None and not (np.isfinite(self.dilation_px) and self.dilation_px >= 0):
            raise StringsBenchError(f"mask dilation_px must be >= 0, got {self.dilation_px}",
                                    hint="the release script uses 225 (pixels at full resolution)")
        if self.predilated not in PREDILATED:
            raise StringsBenchError(f"mask setting predilated must be one of {', '.join(PREDILATED)}, got {self.predilated!r}",
                                    hint="auto: the STRinGS release's masks/ are used as shipped (already dilated)")

    @classmethod
    def coerce(cls, value: "MaskSettings | Mapping | None") -> "MaskSettings":
        if value is None:
            return cls()
        if isinstance(value, MaskSettings):
            return value
        unknown = sorted(set(value) - set(cls.__dataclass_fields__))
        if unknown:
            raise StringsBenchError(f"unknown mask setting(s): {', '.join(unknown)}",
                                    hint=f"known: {', '.join(cls.__dataclass_fields__)}")
        return cls(**dict(value))

    def key(self) -> dict:
        d = asdict(self)
        if self.source != "ocr":
            d.pop("ocr_backend")  # does not change dataset/gt masks
        if self.source != "dataset" or self.predilated == "no":
            d.pop("predilated")  # keeps the cache keys of masks made before the setting existed
        return d

    def for_scene(self, scene: "Scene") -> "MaskSettings":
        """These settings with `predilated` decided for `scene` ("yes" or "no"; see the module docstring)."""
        if self.predilated != "auto":
            return self
        return replace(self, predilated="yes" if self.source == "dataset" and masks_shipped_dilated(scene) else "no")

    def dilates(self) -> bool:
        """False when the masks are used as they are (dataset masks shipped dilated)."""
        return not (self.source == "dataset" and self.predilated == "yes")

    def kernel_diameter(self, width: int, full_width: int) -> float:
        """Kernel diameter in pixels for an image `width` pixels wide (full resolution: `full_width`)."""
        if self.dilation_px is not None:
            return float(self.dilation_px) * width / full_width
        return float(self.dilation_fraction) * width


def masks_shipped_dilated(scene: "Scene") -> bool:
    """Whether `scene`'s masks/ are already dilated: its card says so (`masks_dilated`), else the folder
    is in the STRinGS release's layout (hisam_jsons/ and masks_vis/ beside masks/)."""
    given = scene.settings.get("masks_dilated") if isinstance(scene.settings, dict) else None
    if given is not None:
        return bool(given)
    return scene.masks_dir is not None and all((Path(scene.root) / d).is_dir() for d in RELEASE_LAYOUT_DIRS)


# ---- primitives ------------------------------------------------------------------------------

def dilate_mask(mask: np.ndarray, diameter: float) -> np.ndarray:
    """Dilate a boolean mask with a disk of the given diameter (pixels).

    Exact Euclidean dilation: pixel p is set iff some mask pixel q has |p - q| <= diameter / 2.
    Runs in O(H W) whatever the diameter (distance transform), so the release's 225 px kernel is as
    cheap as the paper's 5 %.
    """
    from scipy.ndimage import distance_transform_edt

    mask = np.asarray(mask, dtype=bool)
    if diameter <= 0 or not mask.any():
        return mask.copy()
    if mask.all():
        return mask.copy()
    dist = distance_transform_edt(~mask)  # distance of each pixel to the nearest mask pixel
    return dist <= diameter / 2.0


def kernel_footprint(diameter: float) -> np.ndarray:
    """The disk footprint `dilate_mask` is equivalent to (for documentation and tests)."""
    r = diameter / 2.0
    k = int(np.floor(r))
    y, x = np.mgrid[-k:k + 1, -k:k + 1]
    return (x * x + y * y) <= r * r


# ---- providers -------------------------------------------------------------------------------

def _image_size(scene: "Scene", i: int, downscale: float) -> tuple[int, int]:
    cam = scene.camera(i, downscale)
    return cam.width, cam.height


def _stat_key(path: Path | None) -> str:
    if path is None or not path.exists():
        return "none"
    st = path.stat()
    return f"{path.name}:{st.st_size}:{st.st_mtime_ns}"


def _missing(scene: "Scene", names: list[str], source: str, why: str) -> MissingMasksError:
    shown = ", ".join(names[:5]) + (f" ... ({len(names)} in all)" if len(names) > 5 else "")
    hints = {
        "dataset": "put one PNG per image in SCENE/masks/<image stem>.png (Hi-SAM masks: see docs/strings.md), "
                   "or use mask_source='ocr' to make masks from the OCR detector's word polygons",
        "gt": "ground-truth masks exist only for synthetic scenes (masks/ or text_annotations.json); "
              "for real scenes use mask_source='dataset' (Hi-SAM masks) or 'ocr'",
        "ocr": "",
    }
    return MissingMasksError(f"scene {scene.name} ({scene.root}): {why} for {shown} (mask source {source!r})",
                             hint=hints.get(source) or None)


def check_masks_available(scene: "Scene", views: Iterable[int], settings: "MaskSettings | Mapping | None" = None) -> None:
    """Raise MissingMasksError naming every view of `views` the provider cannot make a mask for."""
    settings = MaskSettings.coerce(settings)
    views = list(views)
    if settings.source == "dataset":
        if scene.masks_dir is None:
            raise _missing(scene, [scene.names[i] for i in views], "dataset",
                           f"there is no masks/ folder in {scene.root}, so no text mask")
        missing = [scene.names[i] for i in views if scene.mask_path(i) is None]
        if missing:
            raise _missing(scene, missing, "dataset", f"{scene.masks_dir} has no mask file (<image stem>.png)")
    elif settings.source == "gt":
        missing = [scene.names[i] for i in views if scene.mask_path(i) is None
                   and (scene.known_text is None or scene.names[i] not in scene.known_text)]
        if missing:
            raise _missing(scene, missing, "gt", "there is neither a masks/ file nor a text_annotations.json entry")


def tight_text_mask(scene: "Scene", i: int, downscale: float = 1, settings: "MaskSettings | Mapping | None" = None) -> np.ndarray:
    """The undilated text mask of view i at `downscale` (bool H x W)."""
    settings = MaskSettings.coerce(settings)
    w, h = _image_size(scene, i, downscale)
    if settings.source == "dataset":
        check_masks_available(scene, [i], settings)
        return np.array(scene.load_mask(i, downscale), dtype=bool)
    if settings.source == "gt":
        check_masks_available(scene, [i], settings)
        mask = np.zeros((h, w), dtype=bool)
        if scene.mask_path(i) is not None:
            mask |= scene.load_mask(i, downscale)
        words = scene.known_words(i, downscale) or []
        return mask | fill_polygons([wd.polygon for wd in words], (h, w))
    # "ocr": detect at full resolution (small text survives), then scale the polygons.
    words = _backend(settings.ocr_backend).read(_full_image_uint8(scene, i))
    full = scene.model.cameras[i]
    return word_polygon_mask(words, (h, w), (w / full.width, h / full.height))


_backends: dict[str, object] = {}


def _backend(name: str):
    from strings_bench.eval.ocr import get_backend

    if name not in _backends:
        _backends[name] = get_backend(name)  # with the on-disk OCR cache (_prefetch_ocr relies on it)
    return _backends[name]


def _full_image_uint8(scene: "Scene", i: int) -> np.ndarray:
    return (np.clip(scene.load_image(i, 1), 0, 1) * 255).round().astype(np.uint8)


def word_polygon_mask(words, shape: tuple[int, int], scale: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """The tight mask of OCR words: their polygons (scaled by (sx, sy)) filled into an H x W bool mask.
    The "ocr" provider and `strings-bench prepare`'s masks/ are both made by it."""
    s = np.asarray(scale, dtype=np.float64)
    return fill_polygons([np.asarray(wd.polygon, dtype=np.float64) * s for wd in words], shape)



def _scene_hash(scene: "Scene") -> str:
    cams = scene.model.cameras
    data = {"root": str(Path(scene.root).resolve()), "views": [(c.name, c.width, c.height) for c in cams]}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def _settings_hash(settings: MaskSettings) -> str:
    data = {"v": _CACHE_VERSION, **settings.key()}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def _input_hash(scene: "Scene", i: int, settings: MaskSettings) -> str:
    from strings_bench.scene.scene import ANNOTATION_FILE

    if settings.source == "dataset":
        parts = [_stat_key(scene.mask_path(i))]
    elif settings.source == "gt":
        parts = [_stat_key(scene.mask_path(i)), _stat_key(Path(scene.root) / ANNOTATION_FILE)]
    else:
        parts = [_stat_key(scene.image_path(i, 1))]
    return hashlib.sha256("|".join(parts).encode()).hexdigest()[:12]


def mask_cache_dir(scene: "Scene", settings: "MaskSettings | Mapping | None" = None) -> Path:
    settings = MaskSettings.coerce(settings).for_scene(scene)
    return cache_root() / "masks" / _scene_hash(scene) / _settings_hash(settings)


def _mask_cache_path(scene: "Scene", i: int, downscale: float, settings: MaskSettings) -> Path:
    stem = Path(scene.names[i]).stem
    return mask_cache_dir(scene, settings) / f"ds{downscale:g}" / f"{stem}-{_input_hash(scene, i, settings)}.png"


def _write_png(path: Path, mask: np.ndarray) -> None:
    from PIL import Image

    atomic_write(path, lambda p: Image.fromarray(mask.astype(np.uint8) * 255, mode="L").save(p, format="PNG"))


@lru_cache(maxsize=512)
def _read_png(path: str) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        arr = np.asarray(im.convert("L")) > 127
    arr.setflags(write=False)
    return arr


def dilated_text_mask(scene: "Scene", i: int, downscale: float = 1,
                      settings: "MaskSettings | Mapping | None" = None, use_cache: bool = True) -> np.ndarray:
    """The dilated text mask of view i at `downscale` (bool H x W, read-only), cached on disk.

    This is the mask STRinGS trains with and the one OCR-CER multiplies images by.
    Raises MissingMasksError when the provider has no mask for the view.
    """
    settings = MaskSettings.coerce(settings).for_scene(scene)
    w, h = _image_size(scene, i, downscale)
    path = None
    if use_cache:
        path = _mask_cache_path(scene, i, downscale, settings)
        if path.exists():
            try:
                cached = _read_png(str(path))
                if cached.shape == (h, w):
                    return cached
            except OSError:
                log.warning("ignoring unreadable cached mask %s", path)
    tight = tight_text_mask(scene, i, downscale, settings)
    if tight.shape != (h, w):
        raise DatasetError(f"text mask of {scene.names[i]} is {tight.shape[1]}x{tight.shape[0]}, expected {w}x{h}",
                           hint="regenerate the masks from this scene's undistorted images")
    full_w = scene.model.cameras[i].width
    mask = dilate_mask(tight, settings.kernel_diameter(w, full_w)) if settings.dilates() else tight.copy()
    if path is not None:
        _write_png(path, mask)
    mask.setflags(write=False)
    return mask


def text_masks(scene: "Scene", views: Iterable[int], downscale: float = 1,
               settings: "MaskSettings | Mapping | None" = None, progress: bool = True) -> dict[int, np.ndarray]:
    """Dilated masks of several views; checks availability of all of them before making any."""
    settings = MaskSettings.coerce(settings).for_scene(scene)
    views = list(views)
    check_masks_available(scene, views, settings)
    it = views
    if progress and len(views) > 8:
        from tqdm import tqdm

        it = tqdm(views, desc=f"text masks ({settings.source})", unit="view", leave=False)
    if settings.source == "ocr":
        _prefetch_ocr(scene, views, downscale, settings, progress)
    return {i: dilated_text_mask(scene, i, downscale, settings) for i in it}


def _prefetch_ocr(scene: "Scene", views: list[int], downscale: float, settings: MaskSettings, progress: bool) -> None:
    """Run the OCR detector on the views whose mask is not cached yet, on all cores at once
    (eval.ocr.read_many). The reads land in the OCR disk cache, where tight_text_mask's one-at-a-time
    read finds them; a failed read is left to that read to raise."""
    from strings_bench.eval.ocr import read_many

    todo = [i for i in views if not _mask_cache_path(scene, i, downscale, settings).exists()]
    if len(todo) > 1:
        read_many(_backend(settings.ocr_backend), [lambda i=i: _full_image_uint8(scene, i) for i in todo],
                  progress=progress, desc="text masks (ocr)")


def with_source(settings: "MaskSettings | Mapping | None", source: str) -> MaskSettings:
    return replace(MaskSettings.coerce(settings), source=source)


# ---- the masks OCR-CER reads through -----------------------------------------------------------
def eval_mask_settings(scene: "Scene") -> dict | None:
    """Mask settings for OCR-CER: the scene's `eval_masks` setting, else its masks/ folder, else
    (synthetic scenes without masks/) the known-word polygons; None = whole image. Dataset masks shipped
    dilated (the STRinGS release's) are used as they are, as its metrics_ocr does."""
    given = scene.settings.get("eval_masks") if isinstance(scene.settings, dict) else None
    if given is not None:
        return dict(given)
    if scene.masks_dir is not None:
        return {"source": "dataset"}
    if scene.known_text is not None:
        return {"source": "gt"}
    return None


def eval_mask(scene: "Scene", i: int, downscale: float, settings: dict | None) -> np.ndarray | None:
    """The mask OCR reads view i through for OCR-CER, or None (whole image: no settings, or no mask for this
    view, which the evaluation records per view)."""
    if settings is None:
        return None
    try:
        return dilated_text_mask(scene, i, downscale, settings)
    except MissingMasksError:
        return None
