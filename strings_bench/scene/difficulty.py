"""rho: how far one position step of 3DGS moves a Gaussian, measured in text strokes. A property of the scene.

3DGS' position learning rate starts at 1.6e-4 x the scene extent (Kerbl et al. 2023, section 7.1; the
extent is 1.1 x the largest distance of a training camera from their mean, `Scene.extent`), in world
units per step. A text stroke is some millimetres wide. Their ratio

    rho = 1.6e-4 x extent / stroke width (both in world units)

is the fraction of a stroke that one early position step can move a text Gaussian. It depends neither on
the image resolution nor on the distance to the text: a capture with small text relative to its extent
(book titles in a room, labels on a shelf) has a large rho, a close-up of a big sign a small one. STRinGS
locks text positions during its phase 1 (paper, section 4.3); whether that helps should depend on how
far positions move, i.e. on rho.

The stroke width is measured on the images: for each word of a view whose polygon is known (the
synthetic scenes' annotations, or OCR boxes of real photos), the word's pixels are split into ink and
background by Otsu's threshold inside the polygon (ink: the smaller class); each pixel's ink coverage is
its grey level between the two classes' medians (anti-aliased edges count in part), and the stroke width
in pixels is the ink's area over its skeleton's length (a stroke of width w and length L covers w L
pixels). A skeleton pixel counts as one unit of length, diagonal steps too, so slanted strokes read
up to ~1.4x wide. It becomes world units at the word's depth: the camera's distance to the word's centre
where the scene records it (synthetic scenes), else the median camera-space depth of the SfM points
observed inside the polygon. rho uses the median over words.

**Strokes under about 3 pixels read wide.** No pixel of a thinner stroke is all ink, so the ink class's
median is a partial grey and the coverage normalised to it overstates the width: text drawn at 8x and
box-filtered down reads 1.6x wide at 0.9-pixel strokes, 1.2x at 1.5, 1.07x at 2.2 and within 3 % from 3 pixels
up (the measured width settles near 1.7 pixels however thin the stroke; tests/scene/test_difficulty.py).
Where the words can be rendered again at a finer resolution (the suite's synthetic scenes,
`datasets/synthetic/rho.py`) they are measured there (`measured_on` in the record); elsewhere
`reliable` says whether the median stroke is at least MIN_RELIABLE_STROKE_PX pixels.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

POSITION_LR_INIT = 1.6e-4  # 3DGS' initial position learning rate, times the extent (Kerbl et al. 2023)
MIN_WORD_PX = 6  # a word box lower than this (pixels) is too small to measure its strokes
MIN_RELIABLE_STROKE_PX = 3.0  # median strokes (pixels where measured) thinner than this read wide (module doc)
ON_IMAGES = "images"  # `measured_on` of a measurement on the scene's own images


@dataclass(frozen=True)
class Difficulty:
    """rho and what it is made of, for a scene's record (`asdict` for JSON)."""

    rho: float | None
    extent: float  # world units
    stroke_world: float | None  # median stroke width, world units
    stroke_px: float | None  # median stroke width, pixels (at the images' full size)
    words: int  # words measured
    # where the strokes were measured: ON_IMAGES, or how the words were rendered again (synthetic scenes)
    measured_on: str = ON_IMAGES
    reliable: bool | None = None  # the median stroke, where measured, at least MIN_RELIABLE_STROKE_PX pixels

    def as_dict(self) -> dict:
        return asdict(self)

    def how_measured(self) -> str:
        """Where the strokes were measured, and a warning where they were too thin to read true."""
        where = "" if self.measured_on == ON_IMAGES else f"; strokes measured on {self.measured_on}"
        warn = ("" if self.reliable is not False else
                f"; median stroke under {MIN_RELIABLE_STROKE_PX:g} px where measured: strokes read wide, so rho reads low")
        return where + warn


def difficulty_from_strokes(extent: float, strokes_px, strokes_world, measured_px=None,
                            measured_on: str = ON_IMAGES) -> Difficulty:
    """rho from per-word stroke widths: in the scene's image pixels, in world units, and in the pixels they were
    measured at (default: the image pixels), medians over the words."""
    if not strokes_world:
        return Difficulty(None, extent, None, None, 0, measured_on, None)
    stroke = float(np.median(strokes_world))
    at = strokes_px if measured_px is None else measured_px
    return Difficulty(rho=POSITION_LR_INIT * extent / stroke, extent=extent, stroke_world=stroke,
                      stroke_px=float(np.median(strokes_px)), words=len(strokes_world), measured_on=measured_on,
                      reliable=bool(np.median(at) >= MIN_RELIABLE_STROKE_PX))


def stroke_width_px(gray: np.ndarray, polygon: np.ndarray) -> float | None:
    """Median stroke width in pixels of the text inside `polygon` ((K, 2) x, y) of a grey image (H, W) in
    any range; None where the box is too small or holds no two classes of pixels."""
    from skimage.draw import polygon as fill_polygon
    from skimage.filters import threshold_otsu
    from skimage.morphology import skeletonize

    H, W = gray.shape
    x0, y0 = np.floor(polygon.min(0)).astype(int)
    x1, y1 = np.ceil(polygon.max(0)).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1 + 1, W), min(y1 + 1, H)
    if x1 - x0 < MIN_WORD_PX or y1 - y0 < MIN_WORD_PX:
        return None
    crop = gray[y0:y1, x0:x1].astype(np.float64)
    inside = np.zeros(crop.shape, bool)
    rr, cc = fill_polygon(polygon[:, 1] - y0, polygon[:, 0] - x0, crop.shape)
    inside[rr, cc] = True
    values = crop[inside]
    if values.size < MIN_WORD_PX ** 2 or values.max() - values.min() < 1e-6:
        return None
    t = threshold_otsu(values)
    dark = (crop <= t) & inside
    light = (crop > t) & inside
    ink = dark if dark.sum() <= light.sum() else light
    if ink.sum() < MIN_WORD_PX:
        return None
    ink_level = float(np.median(crop[ink]))
    bg_level = float(np.median(crop[inside & ~ink]))
    coverage = np.clip((crop - bg_level) / (ink_level - bg_level), 0.0, 1.0) * inside
    skeleton = skeletonize(ink)
    length = int(skeleton.sum())
    if length == 0:
        return None
    return float(coverage.sum() / length)


def _view_points(scene, view: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices and image positions of the SfM points observed in `view`."""
    model = scene.model
    track_view = np.asarray(model.track_view)
    hits = np.nonzero(track_view == view)[0]
    point_of = np.searchsorted(np.asarray(model.track_ptr), hits, side="right") - 1
    return point_of, np.asarray(model.track_xy)[hits]


def _sfm_depth(scene, view: int, polygon: np.ndarray, points=None) -> float | None:
    """Median camera-space depth of the SfM points observed in `view` inside `polygon`; `points` is
    `_view_points(scene, view)` when the caller has it."""
    from matplotlib.path import Path as PolyPath

    idx, xy = points if points is not None else _view_points(scene, view)
    if idx.size == 0:
        return None
    inside = PolyPath(polygon).contains_points(xy)
    if not inside.any():
        return None
    cam = scene.model.cameras[view]
    z = cam.world_to_camera(np.asarray(scene.model.xyz)[idx[inside]])[:, 2]
    z = z[z > 0]
    return float(np.median(z)) if z.size else None


def mask_regions(mask: np.ndarray) -> list[np.ndarray]:
    """The bounding boxes (as 4-point polygons) of a text mask's connected regions: where a scene knows
    no words (real photos), its text masks stand for them."""
    from scipy.ndimage import find_objects, label

    labels, _ = label(mask > 0)
    boxes = []
    for sl in find_objects(labels):
        if sl is None:
            continue
        y0, y1, x0, x1 = sl[0].start, sl[0].stop - 1, sl[1].start, sl[1].stop - 1
        boxes.append(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float))
    return boxes


def scene_difficulty(scene, words=None, views=None) -> Difficulty:
    """rho of `scene` from its known words, else from its text masks' regions, or from `words` ({view
    index: [polygon, ...]}, e.g. OCR boxes), over `views` (default: every view with words)."""
    from PIL import Image

    extent = float(scene.extent)
    if words is None:
        words = {}
        for i in range(scene.num_views):
            known = scene.known_words(i)
            if known:
                words[i] = [(k.polygon, k.distance) for k in known]
            elif scene.known_text is None and (mask := scene.load_mask(i)) is not None:
                words[i] = [(box, None) for box in mask_regions(mask)]
    else:
        words = {i: [(np.asarray(p, float), None) for p in polys] for i, polys in words.items()}
    if views is not None:
        words = {i: w for i, w in words.items() if i in set(views)}
    strokes_px, strokes_world = [], []
    for i, items in sorted(words.items()):
        gray = np.asarray(Image.open(scene.image_path(i)).convert("L"), np.float64)
        fx = float(scene.model.cameras[i].fx)
        points = None
        for polygon, distance in items:
            w = stroke_width_px(gray, polygon)
            if w is None or w <= 0:
                continue
            if distance is None and points is None:
                points = _view_points(scene, i)
            depth = distance if distance is not None else _sfm_depth(scene, i, polygon, points)
            if depth is None:
                continue
            strokes_px.append(w)
            strokes_world.append(w * depth / fx)
    return difficulty_from_strokes(extent, strokes_px, strokes_world)


DIFFICULTY_FILE = "difficulty.json"  # the scene's record of rho, beside its images (scenes in the cache)
DIFFICULTY_VERSION = 2  # bump when the measurement changes: older records are measured again


def read_difficulty(root) -> Difficulty | None:
    """The record of the scene folder `root` when it is of the current version, else None."""
    try:
        rec = json.loads((Path(root) / DIFFICULTY_FILE).read_text())
        if rec.get("version") == DIFFICULTY_VERSION:
            return Difficulty(**{f.name: rec[f.name] for f in fields(Difficulty)})
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


def write_difficulty(root, d: Difficulty) -> None:
    """Keep `d` as the scene folder's record (atomic)."""
    from strings_bench.core.io import atomic_write_json

    atomic_write_json(Path(root) / DIFFICULTY_FILE, {"version": DIFFICULTY_VERSION, **d.as_dict()})


def recorded_difficulty(scene) -> Difficulty:
    """`scene_difficulty`, kept in the scene folder's difficulty.json when the folder is in the suite's
    cache (built scenes: synthetic rooms, prepared photos); a folder of the user's is only read."""
    from strings_bench.core.io import cache_root

    rec = read_difficulty(scene.root)
    if rec is not None:
        return rec
    d = scene_difficulty(scene)
    try:
        scene.root.resolve().relative_to(cache_root().resolve())
    except ValueError:
        return d
    write_difficulty(scene.root, d)
    return d


def measured_rho(scene) -> float | None:
    """`recorded_difficulty(scene).rho`, or None (with a warning) where it cannot be measured (no known words and no
    text masks) or the measurement fails: a scene property for the record, never worth a failed build or cell."""
    try:
        return recorded_difficulty(scene).rho
    except Exception as exc:
        log.warning("rho of %s not measured: %s", getattr(scene, "root", scene), exc)
        return None
