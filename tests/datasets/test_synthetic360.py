"""The room-scale dataset `synthetic360` and the generator's difficulty controls.

Scenes build (SfM included), annotations and masks are correct (word boxes projected with an
independent surface parametrisation, rendered text pixels inside the polygons and on in the mask,
the recogniser reads the annotated strings), each control moves what it claims by the amount it
claims (measured on renders or on a flat patch), and the `synthetic` scenes are untouched.
"""

from __future__ import annotations

import strings_bench.bench as bench

import importlib.util
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import strings_bench.datasets.synthetic.generate as generate
from strings_bench.cli import main as cli_main
from strings_bench.core.errors import DatasetError, StringsBenchError
from strings_bench.datasets.registry import get_dataset, resolve_scenes
from strings_bench.datasets.synthetic import (SCENE_NAMES, SCENE_NAMES_360, SYNTHETIC360_DEFAULTS, build_scene, read_meta,
                                              settings_with)
from strings_bench.datasets.synthetic.photometric import (ViewPhotometry, apply_photometry, draw_view_photometry,
                                                          motion_kernel)
from strings_bench.scene.scene import Scene

from tests.datasets.test_synthetic import surface_point  # the independent surface parametrisation, one copy

REPO = Path(__file__).resolve().parents[2]


def box_height(polygon: np.ndarray) -> float:
    tl, tr, br, bl = np.asarray(polygon, float)
    return 0.5 * (np.linalg.norm(bl - tl) + np.linalg.norm(br - tr))


def annotated_heights(scene: str, settings) -> np.ndarray:
    """Heights of every annotated word over every view (no rendering needed)."""
    spec = generate.make_spec(scene, settings.seed, settings)
    cams = generate.orbit_cameras(spec, settings, np.random.default_rng([settings.seed, 2]))
    return np.array([box_height(w.polygon) for cam in cams for w in generate.visible_words(spec, cam, settings)])


def inside(poly: np.ndarray, pts: np.ndarray, tol: float) -> np.ndarray:
    """Points within `tol` px of the convex quadrilateral `poly` (either winding)."""
    poly = np.asarray(poly, float)
    ok = np.ones(len(pts), bool)
    area = sum(poly[i, 0] * poly[(i + 1) % 4, 1] - poly[(i + 1) % 4, 0] * poly[i, 1] for i in range(4))
    sign = 1.0 if area > 0 else -1.0
    for i in range(4):
        a, b = poly[i], poly[(i + 1) % 4]
        edge = b - a
        normal = sign * np.array([edge[1], -edge[0]]) / np.linalg.norm(edge)  # points out of the quad
        ok &= (pts - a) @ normal <= tol
    return ok


@pytest.fixture(scope="module")
def office_small():
    """synthetic360/office built in full (SfM included) at a small size, with the card's camera variation."""
    st = settings_with(width=160, height=120, n_views=12, min_points=100, **SYNTHETIC360_DEFAULTS)
    return build_scene("office", st, progress=False), st


def test_a_built_room_keeps_rho_measured_on_its_words_rendered_finer(office_small):
    """The build records rho from the words' crops rendered finer; a record removed (or of an older measurement) is
    measured the same way again when the room's folder is named directly (`run --datasets FOLDER`)."""
    from strings_bench.datasets.registry import resolve_scenes
    from strings_bench.scene.difficulty import DIFFICULTY_FILE, ON_IMAGES, read_difficulty

    path, _ = office_small
    first = read_difficulty(path)
    assert first is not None and first.rho is not None and first.measured_on != ON_IMAGES
    (path / DIFFICULTY_FILE).unlink()
    resolve_scenes([str(path)])
    again = read_difficulty(path)
    assert again == first


def test_no_word_is_copied_from_the_synthetic_scenes():
    easy = {w.text.upper() for s in SCENE_NAMES for w in generate.make_spec(s, 0).words}
    for scene in SCENE_NAMES_360:
        words = {w.text.upper() for w in generate.make_spec(scene, 0).words}
        assert len(words) >= 40, (scene, len(words))
        assert not words & easy, (scene, sorted(words & easy))


def test_room_scene_builds_with_sfm_and_annotations(office_small):
    path, st = office_small
    meta = read_meta(path)
    assert meta["fallback"] is None and meta["points"] >= 100 and meta["text_points"] > 0, meta["sfm_attempts"]
    assert len(list((path / "images").glob("*.png"))) == st.n_views == meta["views"]
    scene = Scene.load(path)
    assert scene.num_views == st.n_views
    assert sum(len(scene.known_words(i)) for i in range(scene.num_views)) >= 3 * st.n_views
    # Each view's camera variation is recorded, drawn per view (no two exposures alike).
    stops = [v["exposure_stops"] for v in meta["photometry"].values()]
    assert len(stops) == st.n_views and len(set(stops)) == st.n_views
    # The images on disk are the degraded ones: re-rendering view 0 and applying its recorded draw gives them.
    spec = generate.make_spec("office", st.seed, st)
    cam, res, _ = next(generate.render_views(spec, st))
    assert np.array_equal(np.asarray(Image.open(path / "images" / cam.name)), res.rgb)
    assert ViewPhotometry(**{**meta["photometry"][cam.name], "wb_gains": tuple(meta["photometry"][cam.name]["wb_gains"])}) \
        == res.photometry


@pytest.mark.parametrize("scene", ["pantry", "office"])
def test_polygons_hold_the_rendered_text_pixels_and_the_mask(scene):
    st = settings_with(width=320, height=240, n_views=12)
    spec = generate.make_spec(scene, st.seed, st)
    views = []
    for i, view in enumerate(generate.render_views(spec, st)):  # renders lazily: stop after view 5
        if i in (0, 5):
            views.append(view)
        if i == 5:
            break
    n_words = n_in = n_mask = n_total = 0
    for cam, res, words in views:
        for kw in words:
            # The scene word behind the annotation: the one whose corners project onto its polygon.
            best, best_word = np.inf, None
            for w in spec.words:
                if w.text != kw.text:
                    continue
                corners = np.array([surface_point(spec.world.primitives[w.prim], *uv) for uv in w.uv])
                px, _ = cam.project(corners)
                err = np.abs(px - kw.polygon).max()
                if err < best:
                    best, best_word = err, w
            assert best <= 0.5, f"{cam.name} {kw.text}: polygon {best:.2f} px from the projected corners"
            # Points of the word's box on the surface (a 7x7 grid): inside the polygon, and in the mask.
            prim = spec.world.primitives[best_word.prim]
            tl, tr, br, bl = best_word.uv
            grid = [(1 - b) * ((1 - a) * tl + a * tr) + b * ((1 - a) * bl + a * br)
                    for a in np.linspace(0.05, 0.95, 7) for b in np.linspace(0.05, 0.95, 7)]
            pts3 = np.array([surface_point(prim, *uv) for uv in grid])
            px, _ = cam.project(pts3)
            n_words += 1
            n_in += inside(kw.polygon, px, tol=1.5).sum()
            n_total += len(px)
            n_mask += res.text_mask[px[:, 1].astype(int), px[:, 0].astype(int)].sum()
    assert n_words >= 15
    assert n_in / n_total >= 0.98, n_in / n_total
    assert n_mask / n_total >= 0.9, n_mask / n_total


def test_the_recogniser_reads_the_annotated_strings():
    from rapidfuzz.distance import Levenshtein

    import strings_bench.eval.readability as rd
    from strings_bench.eval.ocr.rapid import get_recognizer

    recognizer = get_recognizer()
    alphabet = rd.FoldedAlphabet(recognizer.characters)
    st = settings_with(width=320, height=240, n_views=12, text_px=(8.0, 20.0))  # large print: most words legible
    errors = chars = words = 0
    for scene in ("pantry", "storeroom", "office"):
        spec = generate.make_spec(scene, st.seed, st)
        cam, res, known = next(generate.render_views(spec, st))
        legible = [kw for kw in known if box_height(kw.polygon) >= 9]
        for kw in legible:
            # Best of the turns the suite's readability metric tries (spines read top to bottom).
            crops = [rd.rectify(res.rgb, kw.polygon, turn=t) for t in rd.turn_candidates(kw.polygon, kw.text)]
            reads = rd.read_crops(recognizer, alphabet, crops, [kw.text] * len(crops))
            best = min(reads, key=lambda r: r.errors)
            errors += Levenshtein.distance(rd.normalize(best.read), rd.normalize(kw.text))
            chars += len(rd.normalize(kw.text))
            words += 1
    assert words >= 12, words
    assert errors / chars <= 0.1, (errors / chars, words)


# ---- the controls ----------------------------------------------------------------------------
def test_noise_sigma_measured_on_a_flat_patch():
    flat = np.full((120, 160, 3), 0.5)
    for sigma in (2.0, 6.0):
        out = apply_photometry(flat, ViewPhotometry(noise_sigma=sigma), np.random.default_rng(0)).astype(float)
        assert abs(out.std() - sigma) < 0.05 * sigma + 0.1, (sigma, out.std())
        assert abs(out.mean() - 127.5) < 0.3


def test_exposure_and_white_balance_ratios_on_a_render():
    st = settings_with(width=96, height=72, n_views=8)
    spec = generate.make_spec("storeroom", 0, st)
    clean = next(generate.render_views(spec, st))[1].rgb.astype(float)
    varied = replace(st, exposure_sd=0.5, white_balance_sd=0.1)
    _, res, _ = next(generate.render_views(spec, varied))
    view = res.photometry
    assert view.exposure_stops != 0 and view.wb_gains[0] != 1
    out = res.rgb.astype(float)
    ok = (clean > 20).all(-1) & (out < 250).all(-1) & (clean < 250).all(-1)  # no clipped or dark pixels
    gains = [out[ok, c].sum() / clean[ok, c].sum() for c in range(3)]
    expected = [2 ** view.exposure_stops * g for g in view.wb_gains]
    assert np.allclose(gains, expected, rtol=0.02), (gains, expected)
    # The draws over many views have the asked spread (log2 exposure sd, log gain sd).
    draws = [draw_view_photometry(varied, np.random.default_rng([0, 4, i])) for i in range(400)]
    assert np.std([d.exposure_stops for d in draws]) == pytest.approx(0.5, rel=0.12)
    assert np.std([np.log(d.wb_gains[2]) for d in draws]) == pytest.approx(0.1, rel=0.12)


def test_vignetting_defocus_and_motion_blur_on_test_patterns():
    flat = np.full((90, 120, 3), 0.6)
    out = apply_photometry(flat, ViewPhotometry(vignetting=0.3), np.random.default_rng(0)).astype(float)
    assert out[45, 60, 0] == pytest.approx(153, abs=1)  # the centre keeps its level
    assert out[0, 0, 0] / out[45, 60, 0] == pytest.approx(0.7, abs=0.02)  # the corner is 30 % darker
    # Defocus: an impulse spreads with the asked standard deviation.
    imp = np.zeros((61, 61, 3))
    imp[30, 30] = 1.0
    # Scaled so the blurred peak is ~200 levels: bright enough for the tails, below clipping.
    blurred = apply_photometry(imp * 30, ViewPhotometry(defocus_px=2.5), np.random.default_rng(0))
    psf = np.asarray(blurred, float)[..., 0]
    y, x = np.mgrid[:61, :61]
    var_x = (psf * (x - 30) ** 2).sum() / psf.sum()
    assert np.sqrt(var_x) == pytest.approx(2.5, rel=0.1)
    # Motion blur: a line of the asked length, horizontal at 0 degrees.
    k = motion_kernel(9.0, 0.0)
    cols = np.nonzero(k.sum(0) > 1e-6)[0]
    assert 9 <= cols.max() - cols.min() + 1 <= 11 and np.count_nonzero(k.sum(1) > 1e-6) == 1
    assert k.sum() == pytest.approx(1.0)


def test_text_px_sets_the_measured_text_heights():
    base = settings_with(width=320, height=240, n_views=16, min_word_px=1.0)
    heights = {tp: annotated_heights("storeroom", replace(base, text_px=tp)) for tp in ((6.0, 16.0), (3.0, 8.0))}
    big, small = heights[(6.0, 16.0)], heights[(3.0, 8.0)]
    # Most annotated words lie in the asked range (views see words from farther or obliquely too).
    assert 6.0 <= np.median(big) <= 16.0 and np.percentile(big, 90) <= 16.0 * 1.2
    assert np.percentile(big, 90) >= 16.0 * 0.7
    # Halving the setting halves the heights.
    assert np.median(small) / np.median(big) == pytest.approx(0.5, rel=0.12)
    assert np.percentile(small, 90) / np.percentile(big, 90) == pytest.approx(0.5, rel=0.12)


def test_room_scale_moves_the_cameras_out_and_shrinks_the_text():
    base = settings_with(width=320, height=240, n_views=16, min_word_px=1.0)
    h1 = annotated_heights("pantry", base)
    h2 = annotated_heights("pantry", replace(base, room_scale=2.0))
    assert 0.4 <= np.median(h2) / np.median(h1) <= 0.75
    for scale in (1.0, 2.0):
        st = replace(base, room_scale=scale)
        spec = generate.make_spec("pantry", 0, st)
        cams = generate.orbit_cameras(spec, st, np.random.default_rng([0, 2]))
        dist = np.mean([np.linalg.norm(c.center - spec.target) for c in cams])
        assert dist == pytest.approx(1.8 * scale, rel=0.05)


def test_background_frequency_and_clutter():
    st = settings_with(width=320, height=240, n_views=8)

    def background_gradient(settings) -> float:
        spec = generate.make_spec("office", 0, settings)
        _, res, _ = next(generate.render_views(spec, settings))
        img = res.rgb.astype(float).mean(-1)
        gy, gx = np.gradient(img)
        far = np.isfinite(res.depth) & (res.depth > 2.5) & ~res.text_mask  # the room behind the desk
        return float(np.abs(np.hypot(gx, gy)[far]).mean())

    # (Far above 1 the pattern gets finer than a pixel and averages out: docs/synthetic.md.)
    low, high = background_gradient(replace(st, bg_frequency=0.25)), background_gradient(replace(st, bg_frequency=1.0))
    assert high > 1.5 * low, (low, high)
    n0 = len(generate.make_spec("office", 0, replace(st, clutter=0)).world.primitives)
    n20 = len(generate.make_spec("office", 0, replace(st, clutter=20)).world.primitives)
    assert n20 >= n0 + 20


def test_synthetic_scenes_are_untouched_and_reject_room_controls():
    st = settings_with(width=64, height=48, n_views=8)
    assert not st.photometric()
    spec = generate.make_spec("globe", 0, st)
    cam, res, _ = next(generate.render_views(spec, st))
    assert np.array_equal(res.rgb, spec.world.render(cam, st.supersample).rgb) and res.photometry is None
    # Difficulty controls at their defaults leave the cache key as it was before they existed.
    assert settings_with().key("books") == "65ae8fddd661"
    with pytest.raises(DatasetError, match="synthetic/globe has no setting room_scale"):
        generate.make_spec("globe", 0, settings_with(room_scale=2.0))
    # Photometric controls apply to every scene.
    noisy = next(generate.render_views(spec, replace(st, noise_sigma=3.0)))[1]
    assert np.abs(noisy.rgb.astype(float) - res.rgb).std() > 1.5


def test_bad_settings_are_clear_errors():
    for bad, match in (({"room_scale": 0.1}, "room_scale"), ({"text_px": (20, 10)}, "text_px"),
                       ({"noise_sigma": -1}, "noise_sigma"), ({"vignetting": 1.5}, "vignetting"),
                       ({"clutter": -2}, "clutter")):
        with pytest.raises(DatasetError, match=match):
            settings_with(**bad)


def test_card_registration_and_resolution(monkeypatch, tmp_path):
    card = get_dataset("synthetic360")
    assert [s.name for s in card.scenes] == list(SCENE_NAMES_360) == ["pantry", "office", "storeroom"]
    calls = []
    monkeypatch.setattr("strings_bench.datasets.synthetic.build_scene",
                        lambda scene, settings, progress=True: calls.append((scene, settings)) or tmp_path)
    refs = resolve_scenes(["synthetic360/office"])
    assert refs[0].path == tmp_path and refs[0].dataset == "synthetic360"
    assert calls[0] == ("office", settings_with(**SYNTHETIC360_DEFAULTS))


def test_cpu_configuration_is_a_card_with_pinned_cache_keys(monkeypatch, tmp_path, capsys):
    """synthetic360-cpu (issue 27): the settings frozen by the CPU calibration, registered as a dataset whose scenes
    (runner and `datasets prepare`) build with exactly them; the cache keys are the ones docs/synthetic.md lists
    (the calibration's run folder trained on these scenes), so a changed setting or generator fails here."""
    from strings_bench.datasets.synthetic import SYNTHETIC360_CPU, default_settings

    card = get_dataset("synthetic360-cpu")
    assert [s.name for s in card.scenes] == list(SCENE_NAMES_360)
    st = settings_with(**SYNTHETIC360_CPU)
    assert (st.width, st.height, st.n_views, st.room_scale, st.text_px) == (320, 240, 48, 0.6, (10.0, 16.0))
    assert all(getattr(st, k) == v for k, v in SYNTHETIC360_DEFAULTS.items())  # the card's camera variation
    assert {s: st.key(s) for s in SCENE_NAMES_360} == {"pantry": "5ddc335574f8", "office": "7231c35af058",
                                                         "storeroom": "f49a673bafe6"}
    assert default_settings("office", "synthetic360-cpu") == st
    assert default_settings("office") == settings_with(**SYNTHETIC360_DEFAULTS) != st  # synthetic360 is unchanged
    calls = []
    fake = lambda scene, settings, progress=True, force=False: calls.append((scene, settings)) or tmp_path  # noqa: E731
    monkeypatch.setattr("strings_bench.datasets.synthetic.build_scene", fake)
    refs = resolve_scenes(["synthetic360-cpu/office"])
    assert refs[0].dataset == "synthetic360-cpu" and calls == [("office", st)]
    monkeypatch.setattr("strings_bench.cli.datasets._stats", lambda scene_id, path, seconds: {})
    monkeypatch.setattr("strings_bench.cli.datasets._format", lambda row: "")
    assert cli_main(["datasets", "prepare", "synthetic360-cpu/storeroom"]) == 0
    assert calls[-1] == ("storeroom", st)


def test_cli_prepare_rejects_room_controls_on_synthetic_scenes(capsys):
    assert cli_main(["datasets", "prepare", "synthetic/books", "--room-scale", "2"]) == 1  # clear error, no traceback
    assert "has no setting room_scale" in capsys.readouterr().err


def _calibrate():
    """`strings-bench calibrate` (strings_bench/cli/calibrate.py)."""
    import strings_bench.cli.calibrate as mod

    return mod


def test_calibrate_grid_and_regime_checks():
    cal = _calibrate()
    points = cal.parse_grid(["room_scale=1,2", "text_px=6:16,3:8"])
    assert points == [{"room_scale": 1.0, "text_px": (6.0, 16.0)}, {"room_scale": 1.0, "text_px": (3.0, 8.0)},
                      {"room_scale": 2.0, "text_px": (6.0, 16.0)}, {"room_scale": 2.0, "text_px": (3.0, 8.0)}]
    assert cal.point_label(points[3]) == "s360-r2-t3_8"
    with pytest.raises(StringsBenchError, match="not KEY=V1,V2"):
        cal.parse_grid(["roomscale=1"])
    with pytest.raises(StringsBenchError, match="small scale"):
        cal.check_regime("cpu", 1600, 0.05)
    with pytest.raises(StringsBenchError, match="small scale"):
        cal.check_regime("cpu", 320, None)
    assert cal.check_regime("cpu", 320, 0.05) == "cpu"
    import torch

    if not torch.cuda.is_available():
        with pytest.raises(StringsBenchError, match="needs a CUDA GPU"):
            cal.check_regime("auto", 1600, None)
    rows = [{"setting": "s360-r1", "scene": s, "label": "7K", "iteration": 7000, "cer": c, "cer_known": c,
             "word_cer": c, "text_nll": 1.0, "psnr": 20.0, "gaussians": 10, "train_seconds": 1.0}
            for s, c in (("pantry", 0.7), ("office", 0.8))]
    md = cal.tables(rows, ["pantry", "office"])
    assert "| s360-r1 | 7K | 2/2 | 0.750 |" in md and md.rstrip().endswith("| 0.736 | yes |")
    json.dumps(points)  # grid points are plain data


def test_calibrate_cpu_regime_defaults_and_overrides(tmp_path, capsys):
    """--regime cpu fills 320x240, 48 views, x0.05, cpu, its grid, run folder and target; explicit options win;
    --report-only rebuilds the tables without training (and refuses a missing run folder)."""
    cal = _calibrate()
    import argparse

    args = argparse.Namespace(regime="cpu", device=None, width=None, height=None, views=64, steps_scale=None,
                              grid=None, out=None, target=None)
    cal.apply_regime(args)
    assert (args.device, args.width, args.height, args.views, args.steps_scale) == ("cpu", 320, 240, 64, 0.05)
    assert args.grid == ["room_scale=0.7,1"] and args.out == "runs/calibrate-cpu" and args.target == "cer_known"
    assert cal.check_regime(args.device, args.width, args.steps_scale) == "cpu"
    assert cal.parse_grid(args.grid) == [{"room_scale": 0.7}, {"room_scale": 1.0}]
    paper = argparse.Namespace(regime="paper", device=None, width=None, height=None, views=None, steps_scale=None,
                               grid=None, out=None, target=None)
    cal.apply_regime(paper)
    assert (paper.width, paper.views, paper.steps_scale, paper.target) == (1600, 150, None, "cer")
    # the CPU target: known-text CER's mean is held against 0.736 (OCR-CER 1.0 here would say "no")
    rows = [{"setting": "s360-r1", "scene": s, "label": "7K", "iteration": 7000, "cer": 1.0, "cer_known": c,
             "word_cer": 0.9, "word_cer_gt": 0.2, "text_nll": 1.0, "psnr": 20.0, "gaussians": 10, "train_seconds": 1.0}
            for s, c in (("pantry", 0.7), ("office", 0.8))]
    md = cal.tables(rows, ["pantry", "office"], "cer_known")
    assert "| s360-r1 | 7K | 2/2 | 1.000 | 0.750 |" in md and md.rstrip().endswith("| 0.736 | yes |")
    assert cal.tables(rows, ["pantry", "office"], "cer").rstrip().endswith("| 0.736 | no |")
    assert cli_main(["calibrate", "--regime", "cpu", "--report-only", "--out", str(tmp_path / "none")]) == 1
    assert "no run folder" in capsys.readouterr().err
    (tmp_path / "run").mkdir()
    assert cli_main(["calibrate", "--regime", "cpu", "--report-only", "--out", str(tmp_path / "run"), "--scenes", "pantry"]) == 0
    assert (tmp_path / "run" / "calibration.md").read_text().startswith("# synthetic360 calibration: 3dgs, schedule x0.05")


def test_calibrate_seed_and_dense_checkpoints_reach_the_runner(tmp_path, monkeypatch):
    """--seed N becomes every method's seed (seed 0 records no override, so older folders resume) and the
    default folder gets -seed<N>; every:N reaches the runner as dense_every, apart from the checkpoints."""
    cal = _calibrate()
    import argparse

    import strings_bench.bench.runner as runner

    args = argparse.Namespace(regime="cpu", device=None, width=None, height=None, views=None, steps_scale=None,
                              grid=None, out=None, target=None, seed=2)
    cal.apply_regime(args)
    assert args.out == "runs/calibrate-cpu-seed2"
    calls = []
    monkeypatch.setattr(bench, "run", lambda methods, specs, **kw: calls.append((methods, specs, kw)))
    (tmp_path / "run").mkdir()
    base = ["--regime", "cpu", "--dataset", "synthetic360-cpu", "--scenes", "pantry", "--out", str(tmp_path / "run")]
    assert cli_main(["calibrate", *base, "--seed", "2", "--checkpoints", "30K,3K,every:5K"]) == 0
    assert cli_main(["calibrate", *base]) == 0
    (m1, s1, k1), (_, _, k0) = calls
    assert m1 == ["3dgs"] and s1 == ["synthetic360-cpu/pantry"]
    assert k1["checkpoints"] == [3000, 30000] and k1["dense_every"] == 5000
    assert k1["method_overrides"] == {"*": {"seed": 2}} and k0["method_overrides"] == {}
    assert k0["checkpoints"] == [3000, 7000, 30000] and k0["dense_every"] is None


def test_views_rendered_in_worker_processes_equal_the_one_process_render(monkeypatch):
    """render_views(workers=2): each worker rebuilds the scene from its name and settings; every view
    (pixels, mask, depth, camera effects drawn, words) must equal the one-process render, in order."""
    st = settings_with(width=96, height=72, n_views=8, **SYNTHETIC360_DEFAULTS)
    spec = generate.make_spec("office", st.seed, st)
    one = list(generate.render_views(spec, st))
    two = list(generate.render_views(spec, st, workers=2))
    assert [c.name for c, _, _ in two] == [c.name for c, _, _ in one]
    for (_, a, wa), (_, b, wb) in zip(one, two):
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.text_mask, b.text_mask)
        assert np.array_equal(a.depth, b.depth) and a.photometry == b.photometry
        assert [(w.text, w.polygon.tolist()) for w in wa] == [(w.text, w.polygon.tolist()) for w in wb]
    # The build's choice: every core for large views, one process for small ones; the variable wins.
    monkeypatch.delenv(generate.RENDER_WORKERS_ENV, raising=False)
    assert generate.render_workers(settings_with(width=320, height=240)) == 1
    from strings_bench.core.cpus import usable_cores
    assert generate.render_workers(settings_with(width=1600, height=1200)) == usable_cores()
    monkeypatch.setenv(generate.RENDER_WORKERS_ENV, "3")
    assert generate.render_workers(st) == 3
    monkeypatch.setenv(generate.RENDER_WORKERS_ENV, "0")
    with pytest.raises(DatasetError, match="positive whole number"):
        generate.render_workers(st)


def test_sfm_gives_the_same_points_to_the_bit_from_build_to_build(tmp_path):
    """The cache key leaves the machine out, so two SfM runs on the same images must give the same points, tracks
    and colours to the bit (features, matching and triangulation each on one thread: on two, matching gave an idle
    machine other points than a loaded one)."""
    st = settings_with(width=320, height=240, n_views=16, **SYNTHETIC360_DEFAULTS)
    spec = generate.make_spec("pantry", st.seed, st)
    (tmp_path / "images").mkdir()
    cams = []
    for cam, res, _ in generate.render_views(spec, st):
        Image.fromarray(res.rgb).save(tmp_path / "images" / cam.name)
        cams.append(cam)

    def points(run):
        m = generate.triangulate_with_known_poses(tmp_path / "images", tmp_path / f"sfm{run}", cams, st)[0]
        return (m.xyz.tobytes(), m.rgb.tobytes(), m.track_ptr.tobytes(), m.track_view.tobytes(), m.track_xy.tobytes(),
                m.num_points)

    first, second = points(1), points(2)
    assert first[-1] > 300 and first == second
