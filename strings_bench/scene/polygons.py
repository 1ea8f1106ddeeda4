"""Word polygons drawn into pixel masks, in the continuous pixel frame of scene/camera.py."""

from __future__ import annotations

from typing import Iterable

import numpy as np


def fill_polygons(polygons: Iterable[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """Boolean (H, W) mask of the pixels whose centre lies inside any polygon.

    Polygons are (K, 2) x, y in the continuous pixel frame (pixel centres at integer + 0.5, as in
    camera.py); skimage.draw.polygon samples at integer coordinates, hence the -0.5 shift.
    """
    from skimage.draw import polygon as draw_polygon

    mask = np.zeros(shape, dtype=bool)
    for poly in polygons:
        poly = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
        if len(poly) < 3 or not np.isfinite(poly).all():
            continue
        rr, cc = draw_polygon(poly[:, 1] - 0.5, poly[:, 0] - 0.5, shape=shape)
        mask[rr, cc] = True
    return mask
