"""COLMAP write -> read round trip on a model COLMAP itself wrote (the mouse capture)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from strings_bench.scene.colmap import read_model, write_model

# The capture sits in ../shared/data beside the repository (as for tests/integration/test_realdata_slow.py);
# STRINGS_BENCH_MOUSE_COLMAP=DIR points elsewhere.
MOUSE = Path(os.environ.get("STRINGS_BENCH_MOUSE_COLMAP",
                            Path(__file__).resolve().parents[3] / "shared" / "data" / "mouse_colmap"))
pytestmark = pytest.mark.skipif(not (MOUSE / "sparse" / "0").is_dir(),
                                reason=f"shared mouse_colmap data not present at {MOUSE}")


def _assert_same(a, b, tol=1e-6):
    assert a.names == b.names
    for ca, cb in zip(a.cameras, b.cameras):
        assert (ca.width, ca.height) == (cb.width, cb.height)
        np.testing.assert_allclose([ca.fx, ca.fy, ca.cx, ca.cy], [cb.fx, cb.fy, cb.cx, cb.cy], atol=tol, rtol=0)
        np.testing.assert_allclose(ca.R, cb.R, atol=tol, rtol=0)
        np.testing.assert_allclose(ca.t, cb.t, atol=tol, rtol=0)
    # write_model keeps the points that registered images observe.
    keep = a.visibility_counts() > 0
    np.testing.assert_allclose(a.xyz[keep], b.xyz, atol=tol, rtol=0)
    np.testing.assert_array_equal(a.rgb[keep], b.rgb)
    np.testing.assert_array_equal(a.visibility_counts()[keep], b.visibility_counts())
    # Same observations per point (views and pixels), order-independent within a track.
    ia = np.flatnonzero(keep)
    for j, i in enumerate(ia):
        sa = sorted(zip(a.track_view[a.track_ptr[i]:a.track_ptr[i + 1]].tolist(),
                        map(tuple, a.track_xy[a.track_ptr[i]:a.track_ptr[i + 1]].round(9).tolist())))
        sb = sorted(zip(b.track_view[b.track_ptr[j]:b.track_ptr[j + 1]].tolist(),
                        map(tuple, b.track_xy[b.track_ptr[j]:b.track_ptr[j + 1]].round(9).tolist())))
        assert len(sa) == len(sb)
        for (va, xa), (vb, xb) in zip(sa, sb):
            assert va == vb
            assert np.allclose(xa, xb, atol=tol)


@pytest.mark.parametrize("binary", [True, False])
def test_round_trip_mouse_model(tmp_path, binary):
    original = read_model(MOUSE)
    assert len(original.cameras) == 56 and original.num_points > 4000  # as COLMAP wrote it (README)
    out = write_model(original, tmp_path / "sparse" / "0", binary=binary)
    ext = ".bin" if binary else ".txt"
    assert all((out / f"{n}{ext}").exists() for n in ("cameras", "images", "points3D"))
    again = read_model(tmp_path)
    _assert_same(original, again)
    # And a second generation stays identical (no drift from the conversion).
    write_model(again, tmp_path / "gen2", binary=binary)
    _assert_same(again, read_model(tmp_path / "gen2"))


def test_projection_agrees_with_colmap_observations():
    """Independent check of the pose/intrinsics convention: projecting a point with the read
    camera lands on the pixel COLMAP stored for that observation (sub-pixel for a bundle-adjusted model)."""
    model = read_model(MOUSE)
    errs = []
    for i in range(0, model.num_points, 50):
        for k in range(model.track_ptr[i], model.track_ptr[i + 1]):
            cam = model.cameras[model.track_view[k]]
            px, depth = cam.project(model.xyz[i:i + 1])
            assert depth[0] > 0
            errs.append(np.linalg.norm(px[0] - model.track_xy[k]))
    errs = np.asarray(errs)
    assert len(errs) > 100
    assert np.median(errs) < 1.0 and np.percentile(errs, 95) < 4.0
