"""3D text segmentation (STRinGS Algorithm 1): which SfM points are text.

Each SfM point is projected into every image of its track (COLMAP visibility set V_i); a projection
counts as a hit when the point is in front of the camera (z > 0), lands inside the frame and the
text mask is set at that pixel. A point with at least `tau` hits is a text point (paper: tau = 1).

Pixel lookup: the continuous projection (u, v) (pixel centres at integer + 0.5, camera.py) is
looked up at pixel (floor(v), floor(u)), i.e. the pixel whose square contains the projection.
Masks can be used at full resolution or at a downscale; the camera is scaled with them.

Vectorised: the track elements are grouped by view and each view's points are projected and
looked up at once; hits are counted per point with np.bincount. `segment_text_points_loop` is the
plain per-point loop of the paper, kept as the reference the tests compare against.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Mapping

import numpy as np

from strings_bench.scene.camera import Camera
from strings_bench.core.errors import StringsBenchError

if TYPE_CHECKING:
    from strings_bench.scene.scene import Scene


@dataclass
class TextSegmentation:
    """Algorithm 1's result over M SfM points: is_text, (M,) bool, hits >= tau; hits, (M,) int, per point the views
    of its track whose text mask holds its projection; tau, the threshold."""
    is_text: np.ndarray  # (M,) bool
    hits: np.ndarray  # (M,) int: images in which the point lands inside the text mask
    tau: int

    @property
    def num_text(self) -> int:
        """How many SfM points are text."""
        return int(self.is_text.sum())


def _lookup(mask: np.ndarray, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    with np.errstate(invalid="ignore"):
        px = np.floor(uv[:, 0])
        py = np.floor(uv[:, 1])
        ok = (z > 0) & np.isfinite(px) & np.isfinite(py) & (px >= 0) & (px < w) & (py >= 0) & (py < h)
    out = np.zeros(len(uv), dtype=bool)
    out[ok] = mask[py[ok].astype(np.int64), px[ok].astype(np.int64)]
    return out


def count_mask_hits(xyz: np.ndarray, track_ptr: np.ndarray, track_view: np.ndarray,
                    cameras: Mapping[int, Camera] | list[Camera], masks: Mapping[int, np.ndarray]) -> np.ndarray:
    """Per point, the number of track images whose mask contains its projection.

    Track elements whose view has no entry in `masks` are skipped (views not used, e.g. test views).
    `cameras[j]` must match the size of `masks[j]`.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    m = xyz.shape[0]
    track_ptr = np.asarray(track_ptr, dtype=np.int64)
    track_view = np.asarray(track_view, dtype=np.int64)
    if track_ptr.shape != (m + 1,) or track_ptr[-1] != len(track_view):
        raise StringsBenchError(f"tracks do not match the points: track_ptr has {track_ptr.shape} entries for {m} points",
                                hint="the COLMAP model is inconsistent; re-read it")
    point_of = np.repeat(np.arange(m, dtype=np.int64), np.diff(track_ptr))
    hit_points = []
    order = np.argsort(track_view, kind="stable")
    views_sorted = track_view[order]
    starts = np.searchsorted(views_sorted, list(masks), side="left")
    ends = np.searchsorted(views_sorted, list(masks), side="right")
    for (j, mask), a, b in zip(masks.items(), starts, ends):
        if a == b:
            continue
        cam = cameras[j]
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (cam.height, cam.width):
            raise StringsBenchError(f"mask of view {j} is {mask.shape[1]}x{mask.shape[0]} but its camera is "
                                    f"{cam.width}x{cam.height}", hint="scale the camera with the mask (scene.camera(i, downscale))")
        pts = point_of[order[a:b]]
        uv, z = cam.project(xyz[pts])
        hit_points.append(pts[_lookup(mask, uv, z)])
    if not hit_points:
        return np.zeros(m, dtype=np.int64)
    return np.bincount(np.concatenate(hit_points), minlength=m).astype(np.int64)


def inherited_tracks(track_ptr: np.ndarray, track_view: np.ndarray, point_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(track_ptr, track_view) of a list of rows that each carry the track of SfM point `point_ids[k]`
    (Gaussians re-localised with their parent point's track, as the release's point_track_ids)."""
    track_ptr = np.asarray(track_ptr, dtype=np.int64)
    point_ids = np.asarray(point_ids, dtype=np.int64).reshape(-1)
    if len(point_ids) and (point_ids.min() < 0 or point_ids.max() >= len(track_ptr) - 1):
        raise StringsBenchError(f"point ids out of range 0..{len(track_ptr) - 2}")
    lengths = track_ptr[point_ids + 1] - track_ptr[point_ids]
    ptr = np.zeros(len(point_ids) + 1, dtype=np.int64)
    np.cumsum(lengths, out=ptr[1:])
    # element e of row k is track_view[track_ptr[point_ids[k]] + (e - ptr[k])]
    row = np.repeat(np.arange(len(point_ids)), lengths)
    src = track_ptr[point_ids][row] + (np.arange(ptr[-1]) - ptr[row])
    return ptr, np.asarray(track_view, dtype=np.int64)[src]


def segment_text_points_arrays(xyz, track_ptr, track_view, cameras, masks, tau: int = 1) -> TextSegmentation:
    """Algorithm 1 on arrays (no Scene): a point is text when at least tau views of its track hold its projection
    in their text mask. Returns a `TextSegmentation`."""
    if tau < 0:
        raise StringsBenchError(f"text-point threshold tau must be >= 0, got {tau}", hint="the paper uses tau = 1")
    hits = count_mask_hits(xyz, track_ptr, track_view, cameras, masks)
    return TextSegmentation(is_text=hits >= tau, hits=hits, tau=int(tau))


def segment_text_points_loop(xyz, track_ptr, track_view, cameras, masks, tau: int = 1) -> TextSegmentation:
    """Algorithm 1 as written in the paper: one point, one image at a time (reference, slow)."""
    m = len(xyz)
    hits = np.zeros(m, dtype=np.int64)
    for i in range(m):
        count = 0
        for k in range(track_ptr[i], track_ptr[i + 1]):
            j = int(track_view[k])
            if j not in masks:
                continue
            cam = cameras[j]
            uv, z = cam.project(np.asarray(xyz[i], dtype=np.float64)[None])
            u, v = uv[0]
            if not (z[0] > 0 and np.isfinite(u) and np.isfinite(v)):
                continue
            px, py = int(np.floor(u)), int(np.floor(v))
            if 0 <= px < cam.width and 0 <= py < cam.height and masks[j][py, px]:
                count += 1
        hits[i] = count
    return TextSegmentation(is_text=hits >= tau, hits=hits, tau=int(tau))


def segment_text_points(scene: "Scene", masks: Mapping[int, np.ndarray], downscale: float = 1, tau: int = 1) -> TextSegmentation:
    """Algorithm 1 on a scene's SfM points with masks {view index: bool mask at `downscale`}.

    Only the views in `masks` vote (STRinGS passes the training views, so test views never
    influence training).
    """
    model = scene.model
    cameras = {j: scene.camera(j, downscale) for j in masks}
    return segment_text_points_arrays(model.xyz, model.track_ptr, model.track_view, cameras, masks, tau)
