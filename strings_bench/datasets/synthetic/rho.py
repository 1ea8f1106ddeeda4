"""rho of a synthetic scene, its strokes measured on the words rendered again at a finer resolution.

The stroke measurement (`scene.difficulty.stroke_width_px`) reads strokes under about 2.5 pixels wide, and the
CPU scenes' words are drawn with strokes of 1-2 pixels. rho is a property of the world (one position step over a
stroke's width), not of the images, and the generator holds the world: each measured word is rendered again, alone
in a crop of its view around its box, at `factor` times the view's resolution, enough for the box to be about
CROP_BOX_PX pixels tall and at most MAX_FACTOR (the text textures hold 5 texels per pixel of the scene's own
resolution, `scenes360.TEXELS_PER_PIXEL`), without the photometric effects of the views (a clean render), and
measured there: the words of every view that the scene annotates (a quarter of the views gave rho 3-8 % apart
from one quarter to the next on the CPU rooms), the depth the camera's distance to the word's centre, as for the
scene's own words. On the CPU rooms (320x240) this takes 10-35 s of one core (35 s for the storeroom on a loaded core).
"""

from __future__ import annotations

import math

import numpy as np

from strings_bench.core import vec3
from strings_bench.scene.camera import Camera
from strings_bench.scene.difficulty import Difficulty, difficulty_from_strokes, stroke_width_px

CROP_BOX_PX = 48  # a word's box height (pixels) its crop is rendered at (strokes ~3.5 px), where the view's is lower
MAX_FACTOR = 4  # finest re-rendering: the text textures hold 5 texels per pixel of the scene's resolution
MARGIN_PX = 2  # pixels around the word's box in the view, in the crop


def crop_camera(cam: Camera, x0: int, y0: int, width: int, height: int, factor: int) -> Camera:
    """The camera whose image is the window (x0, y0, width, height) of `cam`'s image rendered `factor` times finer
    (x0, y0 in the finer image's pixels): same pose, the focal length times `factor`, the principal point moved."""
    return Camera(cam.fx * factor, cam.fy * factor, cam.cx * factor - x0, cam.cy * factor - y0, width, height,
                  cam.R, cam.t, name=cam.name)


def word_factor(polygon: np.ndarray) -> int:
    """The re-rendering factor of a word whose box is `polygon` in the view's pixels."""
    height = 0.5 * (vec3.norm_2d(polygon[0] - polygon[3]) + vec3.norm_2d(polygon[1] - polygon[2]))
    return int(min(MAX_FACTOR, max(1, math.ceil(CROP_BOX_PX / max(height, 1e-6)))))


def word_stroke(spec, cam: Camera, polygon: np.ndarray, supersample: int, factor: int) -> float | None:
    """The word's median stroke width in the view's pixels, measured on its crop rendered `factor` times finer."""
    lo = np.floor(polygon.min(0) * factor).astype(int) - MARGIN_PX * factor
    hi = np.ceil(polygon.max(0) * factor).astype(int) + MARGIN_PX * factor
    width, height = int(hi[0] - lo[0]), int(hi[1] - lo[1])
    res = spec.world.render(crop_camera(cam, int(lo[0]), int(lo[1]), width, height, factor), supersample)
    gray = vec3.dot(np.asarray(res.rgb, np.float64), np.array([0.299, 0.587, 0.114]))  # BT.601 luma
    w = stroke_width_px(gray, polygon * factor - lo)
    return None if w is None or w <= 0 else w / factor


def rendered_difficulty(spec, cams: list[Camera], words_of, supersample: int, extent: float,
                        views=None) -> Difficulty:
    """rho of the scene `spec` seen by `cams`, over the words `words_of(cam)` (KnownWords with polygon and distance)
    of `views` (default: every camera), measured on their crops rendered finer (module docstring) with
    `supersample` x `supersample` rays per pixel. `extent` is the built scene's (`Scene.extent`).
    `generate.synthetic_difficulty` calls it for a scene and its settings."""
    views = range(len(cams)) if views is None else views
    strokes_px, strokes_world, measured_px = [], [], []
    for i in views:
        cam = cams[i]
        for word in words_of(cam):
            factor = word_factor(word.polygon)
            w = word_stroke(spec, cam, word.polygon, supersample, factor)
            if w is None:
                continue
            strokes_px.append(w)
            measured_px.append(w * factor)
            strokes_world.append(w * word.distance / cam.fx)
    return difficulty_from_strokes(extent, strokes_px, strokes_world, measured_px,
                                   measured_on=f"word crops rendered up to {MAX_FACTOR}x finer")
