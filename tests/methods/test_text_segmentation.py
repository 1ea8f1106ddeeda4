"""3D text segmentation (Algorithm 1): vectorised version vs the plain per-point loop."""

from __future__ import annotations

import numpy as np
import pytest

from strings_bench.scene.camera import Camera
from strings_bench.methods.strings.segmentation import (count_mask_hits, segment_text_points, segment_text_points_arrays,
                                             segment_text_points_loop)
from tests.eval.test_masks import look_at, make_scene


def random_case(seed, n_views=7, n_points=400):
    rng = np.random.default_rng(seed)
    cams = []
    for v in range(n_views):
        w, h = int(rng.integers(20, 60)), int(rng.integers(15, 50))
        center = rng.normal(size=3)
        center = 2.5 * center / np.linalg.norm(center)
        R, t = look_at(center, rng.normal(scale=0.2, size=3))
        cams.append(Camera(rng.uniform(20, 50), rng.uniform(20, 50), w / 2 + rng.normal(), h / 2 + rng.normal(),
                           w, h, R, t))
    # Points around the origin, some behind some cameras, some outside frames.
    xyz = rng.normal(scale=1.2, size=(n_points, 3))
    counts = rng.integers(0, n_views + 1, size=n_points)
    views = np.concatenate([rng.choice(n_views, size=c, replace=False) for c in counts]).astype(np.int32)
    ptr = np.concatenate([[0], np.cumsum(counts)])
    masks = {j: rng.random((c.height, c.width)) > 0.6 for j, c in enumerate(cams) if j != n_views - 1}
    return xyz, ptr, views, cams, masks


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("tau", [0, 1, 2, 3])
def test_vectorised_matches_plain_loop(seed, tau):
    xyz, ptr, views, cams, masks = random_case(seed)
    fast = segment_text_points_arrays(xyz, ptr, views, cams, masks, tau)
    slow = segment_text_points_loop(xyz, ptr, views, cams, masks, tau)
    assert np.array_equal(fast.hits, slow.hits)
    assert np.array_equal(fast.is_text, slow.is_text)
    # Non-trivial case: some hits, some misses, some points with several hits.
    assert 0 < (fast.hits > 0).sum() < len(xyz) and fast.hits.max() >= 2


def test_behind_camera_and_outside_frame_do_not_count():
    R, t = np.eye(3), np.zeros(3)
    cam = Camera(10.0, 10.0, 5.0, 5.0, 10, 10, R, t)
    mask = np.ones((10, 10), bool)
    xyz = np.array([[0.0, 0.0, 1.0],    # centre: hit
                    [0.0, 0.0, -1.0],   # behind
                    [10.0, 0.0, 1.0],   # far right, outside
                    [-0.5, -0.5, 1.0],  # exactly at (0, 0): pixel 0, inside
                    [0.5, 0.0, 1.0]])   # u = 10: outside (pixel 10 does not exist)
    ptr = np.arange(6)
    views = np.zeros(5, np.int32)
    hits = count_mask_hits(xyz, ptr, views, [cam], {0: mask})
    assert hits.tolist() == [1, 0, 0, 1, 0]


def test_pixel_lookup_is_floor_of_projection():
    cam = Camera(10.0, 10.0, 0.0, 0.0, 4, 4, np.eye(3), np.zeros(3))
    mask = np.zeros((4, 4), bool)
    mask[1, 2] = True  # pixel covering u in [2, 3), v in [1, 2)
    xyz = np.array([[0.299, 0.199, 1.0], [0.2, 0.1, 1.0], [0.301, 0.1, 1.0], [0.19, 0.15, 1.0]])
    hits = count_mask_hits(xyz, np.arange(5), np.zeros(4, np.int32), [cam], {0: mask})
    assert hits.tolist() == [1, 1, 0, 0]


def test_scene_segmentation_with_downscaled_masks(tmp_path):
    scene = make_scene(tmp_path, n_points=200)
    import strings_bench.eval.text_masks as M

    s = M.MaskSettings(dilation_fraction=0)
    full = {i: M.tight_text_mask(scene, i, 1, s) for i in scene.train_idx}
    seg = segment_text_points(scene, full, 1, tau=1)
    # Reference: project with the full-resolution cameras directly.
    ref = segment_text_points_loop(scene.model.xyz, scene.model.track_ptr, scene.model.track_view,
                                   scene.model.cameras, full, 1)
    assert np.array_equal(seg.hits, ref.hits) and 0 < seg.num_text < scene.model.num_points
    half = {i: M.tight_text_mask(scene, i, 2, s) for i in scene.train_idx}
    seg2 = segment_text_points(scene, half, 2, tau=1)
    # The box edges sit on even pixels, so half-resolution masks describe the same region.
    assert np.array_equal(seg.is_text, seg2.is_text)
