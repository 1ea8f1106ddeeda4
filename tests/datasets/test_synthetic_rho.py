"""rho of the synthetic rooms from their words rendered again finer (datasets/synthetic/rho.py): a crop is the
window of the finer full view, pixel for pixel, and the measurement no longer depends on the build's resolution."""

from __future__ import annotations

import numpy as np
import pytest

from strings_bench.datasets.synthetic.generate import (make_spec, orbit_cameras, settings_with, synthetic_difficulty,
                                                       visible_words)
from strings_bench.datasets.synthetic.rho import crop_camera, word_stroke
from strings_bench.scene.difficulty import stroke_width_px

ROOM = {"room_scale": 0.6, "n_views": 16}  # the CPU rooms' scale; 16 views keep the test short


def _settings(width: int):
    # text_px in pixels at the build's width: (10, 16) at 320 is the CPU rooms' text, the same world at any width
    return settings_with(width=width, height=width * 3 // 4, text_px=(10.0 * width / 320, 16.0 * width / 320), **ROOM)


def test_a_word_crop_is_the_window_of_the_finer_full_view():
    """Each word measured on its own crop reads exactly what it reads on the whole view rendered 4x finer (the same
    rays), so the crop camera's focal length and principal point are right."""
    st = _settings(160)
    spec = make_spec("storeroom", st.seed, st)
    seen = [(visible_words(spec, c, st), c) for c in orbit_cameras(spec, st, np.random.default_rng([st.seed, 2]))]
    words, cam = max(seen, key=lambda wc: len(wc[0]))  # the view with the most words
    assert len(words) >= 3
    full = spec.world.render(crop_camera(cam, 0, 0, cam.width * 4, cam.height * 4, 4), st.supersample)
    gray = np.asarray(full.rgb, np.float64) @ np.array([0.299, 0.587, 0.114])
    for w in words:
        on_full = stroke_width_px(gray, w.polygon * 4)
        assert on_full is not None
        assert word_stroke(spec, cam, w.polygon, st.supersample, 4) == pytest.approx(on_full / 4, rel=1e-12)


def test_rho_no_longer_depends_on_the_resolution_the_room_is_built_at():
    """The same room (text sized for the same world) built at 320x240 and at 640x480: re-rendered finer, the two
    give the same rho within 5 %, with the median stroke in each build's own pixels doubling with the resolution;
    measured on the 320x240 images, where the strokes are about 1.5 pixels, the strokes read wide and rho reads
    low."""
    from strings_bench.scene.difficulty import difficulty_from_strokes

    got = {w: synthetic_difficulty("storeroom", _settings(w), extent=1.0, views=range(0, 16, 2)) for w in (320, 640)}
    assert got[320].words >= 15 and got[640].words >= 15
    assert got[320].rho == pytest.approx(got[640].rho, rel=0.05)
    assert got[320].reliable and got[640].reliable
    assert got[640].stroke_px == pytest.approx(2 * got[320].stroke_px, rel=0.1)
    # the images' own measurement at 320x240 (every 4th view): thin strokes read wide, rho reads low
    images = {}
    for w in (320,):
        st = _settings(w)
        spec = make_spec("storeroom", st.seed, st)
        px, world = [], []
        for cam in orbit_cameras(spec, st, np.random.default_rng([st.seed, 2]))[::4]:
            res = spec.world.render(cam, st.supersample)
            gray = np.asarray(res.rgb, np.float64) @ np.array([0.299, 0.587, 0.114])
            for word in visible_words(spec, cam, st):
                s = stroke_width_px(gray, word.polygon)
                if s:
                    px.append(s)
                    world.append(s * word.distance / cam.fx)
        images[w] = difficulty_from_strokes(1.0, px, world)
    assert images[320].rho < 0.85 * got[320].rho
    assert images[320].reliable is False
