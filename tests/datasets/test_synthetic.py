"""The synthetic benchmark: geometry of the GT text, determinism, split, SfM model, cache, CLI."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from strings_bench.cli import main as cli_main
from strings_bench.datasets.registry import get_dataset, resolve_scenes
from strings_bench.datasets.synthetic import SCENE_NAMES, build_scene, read_meta, scene_dir, settings_with
import strings_bench.datasets.synthetic.generate as generate
from strings_bench.datasets.synthetic.raycast import Cylinder, Disc, Quad, Sphere
from strings_bench.core.errors import DatasetError
from strings_bench.scene.scene import Scene


# ---- an independent parametrisation of the surfaces (not the generator's .point()) ------------
def surface_point(prim, u: float, v: float) -> np.ndarray:
    if isinstance(prim, Quad):
        return prim.p0 + u * prim.eu + v * prim.ev
    if isinstance(prim, Cylinder):
        phi = 2 * np.pi * u
        radial = np.cos(phi) * prim.e1 + np.sin(phi) * np.cross(prim.a, prim.e1)
        return prim.c + prim.r * radial + (1 - v) * prim.h * prim.a
    if isinstance(prim, Sphere):
        lon, colat = 2 * np.pi * u, np.pi * v
        e2 = np.cross(prim.a, prim.e1)
        return prim.c + prim.r * (np.sin(colat) * (np.cos(lon) * prim.e1 + np.sin(lon) * e2) + np.cos(colat) * prim.a)
    if isinstance(prim, Disc):
        e2 = np.cross(prim.n, prim.e1)
        return prim.c + (2 * u - 1) * prim.r * prim.e1 + (1 - 2 * v) * prim.r * e2
    raise TypeError(type(prim))


def _project(cam, pts):
    px, z = cam.project(np.asarray(pts, float).reshape(-1, 3))
    assert np.all(z > 0)
    return px


def test_annotations_match_independent_projection_and_masks(synthetic_books_small, synthetic_small_settings):
    scene = Scene.load(synthetic_books_small)
    spec = generate.make_spec("books", synthetic_small_settings.seed)
    n_checked = n_mask_ok = n_mask_total = 0
    for i in range(scene.num_views):
        cam = scene.camera(i)  # read back from the COLMAP model that pycolmap wrote
        mask = scene.load_mask(i)
        words = scene.known_words(i)
        for kw in words:
            # Find the scene word with this text whose corners project onto the annotation.
            best = np.inf
            best_word = None
            for w in spec.words:
                if w.text != kw.text:
                    continue
                prim = spec.world.primitives[w.prim]
                corners = np.array([surface_point(prim, *uv) for uv in w.uv])
                err = np.abs(_project(cam, corners) - kw.polygon).max()
                if err < best:
                    best, best_word = err, w
            assert best <= 0.5, f"{scene.names[i]} {kw.text}: annotation is {best:.3f} px from the projected corners"
            n_checked += 1
            # The GT mask must be on at the word's centre line (projected from the surface).
            prim = spec.world.primitives[best_word.prim]
            tl, tr, br, bl = best_word.uv
            for a in (0.25, 0.5, 0.75):
                uv = 0.5 * ((1 - a) * tl + a * tr) + 0.5 * ((1 - a) * bl + a * br)
                x, y = _project(cam, surface_point(prim, *uv))[0]
                on = bool(mask[int(y), int(x)])
                n_mask_total += 1
                n_mask_ok += on
                if a == 0.5:
                    assert on, f"{scene.names[i]} {kw.text}: text mask is off at the word centre ({x:.1f}, {y:.1f})"
    assert n_checked >= 20, f"too few annotated words ({n_checked})"
    assert n_mask_ok / n_mask_total >= 0.95


def test_word_corners_are_in_reading_order():
    # A horizontally printed word on a quad seen from the front: TL is left of TR and above BL.
    spec = generate.make_spec("extinguisher", 0)
    cams = generate.orbit_cameras(spec, settings_with(), np.random.default_rng([0, 2]))
    found = 0
    for cam in cams:
        for kw in generate.visible_words(spec, cam, settings_with()):
            tl, tr, br, bl = kw.polygon
            assert tr[0] > tl[0] and bl[1] > tl[1], kw
            found += 1
    assert found > 50


def test_vertical_spine_text_reads_top_to_bottom():
    from strings_bench.datasets.synthetic.scenes import BOOKS_A, BOOKS_B

    spec = generate.make_spec("books", 0)
    # Words that also occur in the lying books' (horizontal) titles are left out.
    title_words = {w for title, _ in BOOKS_A + BOOKS_B for w in title.split()} - {"THE", "OF", "TIME"}
    spine = [w for w in spec.words if w.text in title_words]
    assert len(spine) >= 10
    for w in spine:
        tl, tr, br, bl = w.uv
        assert tr[1] > tl[1] + 1e-3 and abs(tr[0] - tl[0]) < 1e-9  # reads down the spine


def test_render_is_deterministic_from_seed(synthetic_books_small, synthetic_small_settings):
    st = synthetic_small_settings
    a = list(zip(range(2), generate.render_views(generate.make_spec("books", st.seed), st)))
    b = list(zip(range(2), generate.render_views(generate.make_spec("books", st.seed), st)))
    for (_, (ca, ra, wa)), (_, (cb, rb, wb)) in zip(a, b):
        assert np.array_equal(ca.R, cb.R) and np.array_equal(ca.t, cb.t)
        assert np.array_equal(ra.rgb, rb.rgb) and np.array_equal(ra.text_mask, rb.text_mask)
        assert [w.text for w in wa] == [w.text for w in wb]
    # The cached scene holds exactly these pixels.
    cached = np.asarray(Image.open(synthetic_books_small / "images" / a[0][1][0].name))
    assert np.array_equal(cached, a[0][1][1].rgb)
    other = settings_with(**{**json.loads(json.dumps(st.__dict__)), "seed": st.seed + 1})
    c = next(generate.render_views(generate.make_spec("books", other.seed), other))
    assert not np.array_equal(c[1].rgb, a[0][1][1].rgb)
    assert other.key("books") != st.key("books")


def test_split_is_every_eighth_sorted_view(synthetic_books_small):
    scene = Scene.load(synthetic_books_small)
    assert scene.names == sorted(scene.names)
    assert scene.test_idx == list(range(0, scene.num_views, 8))
    assert sorted(scene.train_idx + scene.test_idx) == list(range(scene.num_views))


def test_small_books_is_a_real_sfm_model(synthetic_books_small, synthetic_small_settings):
    import pycolmap

    meta = read_meta(synthetic_books_small)
    assert meta["fallback"] is None, meta["sfm_attempts"]
    rec = pycolmap.Reconstruction(str(synthetic_books_small / "sparse" / "0"))
    assert rec.num_reg_images() == synthetic_small_settings.n_views
    assert rec.num_points3D() >= 100
    assert all(c.model.name == "PINHOLE" for c in rec.cameras.values())
    # Every point comes with a track of >= 2 observations (triangulated, not sampled).
    assert min(len(p.track.elements) for p in rec.points3D.values()) >= 2
    # Poses are the generator's orbit, unchanged by triangulation.
    spec = generate.make_spec("books", synthetic_small_settings.seed)
    cams = {c.name: c for c in generate.orbit_cameras(spec, synthetic_small_settings,
                                                          np.random.default_rng([synthetic_small_settings.seed, 2]))}
    for im in rec.images.values():
        pose = im.cam_from_world()
        assert np.allclose(pose.rotation.matrix(), cams[im.name].R, atol=1e-6)
        assert np.allclose(pose.translation, cams[im.name].t, atol=1e-6)
    # Some points project into a GT text mask of a view that observes them (counted here directly).
    scene = Scene.load(synthetic_books_small)
    name_to_view = {n: i for i, n in enumerate(scene.names)}
    text_points = 0
    for p in rec.points3D.values():
        for el in p.track.elements:
            v = name_to_view[rec.images[el.image_id].name]
            x, y = _project(scene.camera(v), p.xyz)[0]
            if 0 <= x < scene.camera(v).width and 0 <= y < scene.camera(v).height and scene.load_mask(v)[int(y), int(x)]:
                text_points += 1
                break
    assert text_points > 0
    assert text_points == meta["text_points"]
    assert text_points < rec.num_points3D()  # background points exist too


def test_cache_layout_and_reuse(synthetic_books_small, synthetic_small_settings):
    root = synthetic_books_small
    assert root == scene_dir("books", synthetic_small_settings)
    for sub in ("images", "masks", "sparse/0", "text_annotations.json", "scene_meta.json"):
        assert (root / sub).exists(), sub
    assert not (root / "_sfm").exists()
    # this scene's own build folders only: a test file on the other worker may be building another room now
    assert not list(root.parent.glob(f".build-{root.name}-*"))
    n_img = len(list((root / "images").glob("*.png")))
    assert n_img == len(list((root / "masks").glob("*.png"))) == synthetic_small_settings.n_views
    mtime = (root / "scene_meta.json").stat().st_mtime
    assert build_scene("books", synthetic_small_settings, progress=False) == root
    assert (root / "scene_meta.json").stat().st_mtime == mtime  # reused, not rebuilt


def test_interrupted_build_leaves_no_cache(monkeypatch):
    st = settings_with(width=64, height=48, n_views=8, seed=123)

    def boom(scene, settings, out, progress):
        (out / "images").mkdir()
        raise KeyboardInterrupt

    monkeypatch.setattr(generate, "_build_into", boom)
    with pytest.raises(KeyboardInterrupt):
        build_scene("globe", st, progress=False)
    assert not scene_dir("globe", st).exists()
    own = scene_dir("globe", st)
    assert not list(own.parent.glob(f".build-{own.name}-*"))  # its own only (another room may be building)


def test_fallback_is_flagged_when_sfm_gives_too_few_points(caplog, monkeypatch, tmp_path):
    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path))  # a build, not a cached scene (whose log is gone)
    st = settings_with(width=96, height=72, n_views=8, seed=5, min_points=10 ** 9)
    with caplog.at_level(logging.WARNING):
        path = build_scene("extinguisher", st, progress=False)
    meta = read_meta(path)
    assert meta["fallback"] == "depth_samples"
    assert len(meta["sfm_attempts"]) == 2 and meta["sfm_attempts"][1]["relaxed"] is True
    assert any("FALLING BACK" in r.message for r in caplog.records)
    assert Scene.load(path).model.num_points > 0


def test_unknown_scene_and_bad_settings_are_clear_errors():
    with pytest.raises(DatasetError, match="unknown synthetic scene"):
        scene_dir("teapot")
    with pytest.raises(DatasetError, match="n_views"):
        settings_with(n_views=2)


def test_card_registration():
    card = get_dataset("synthetic")
    assert [s.name for s in card.scenes] == list(SCENE_NAMES) == ["books", "extinguisher", "globe", "chemicals", "shelf"]
    assert all("n_max" not in s.settings for s in card.scenes)  # STRinGS' N_max is its spec's (default 15 here)
    assert card.locate is not None


def test_resolve_scene_builds_default_scene(monkeypatch, tmp_path):
    calls = []
    monkeypatch.setattr("strings_bench.datasets.synthetic.build_scene",
                        lambda scene, settings, progress=True: calls.append((scene, settings)) or tmp_path)
    refs = resolve_scenes(["synthetic/globe"])
    assert refs[0].path == tmp_path and refs[0].settings == {}
    assert calls[0][0] == "globe" and calls[0][1] == settings_with()


def test_cli_list_and_prepare(synthetic_books_small, capsys):
    assert cli_main(["datasets", "list"]) == 0
    out = capsys.readouterr().out
    assert "synthetic/books" in out and "synthetic/shelf" in out
    assert cli_main(["datasets", "prepare", "synthetic/books", "--width", "160", "--height", "120", "--views", "24"]) == 0
    out = capsys.readouterr().out
    assert str(synthetic_books_small) in out
    meta = read_meta(synthetic_books_small)
    assert f"points {meta['points']}, points in text masks {meta['text_points']}" in out
    assert cli_main(["datasets", "prepare"]) == 1  # nothing named: a clear error, not a traceback


def test_cli_extension_hook():
    import argparse

    import strings_bench.cli.datasets as dcli

    seen = []
    dcli.register_subcommand("demo-check", "a test subcommand",
                             lambda p: p.set_defaults(func=lambda args: seen.append(args) or 0))
    try:
        parser = argparse.ArgumentParser()
        dcli.add_parser(parser.add_subparsers())
        args = parser.parse_args(["datasets", "demo-check"])
        assert args.func(args) == 0 and seen
    finally:
        dcli.EXTRA_SUBCOMMANDS[:] = [s for s in dcli.EXTRA_SUBCOMMANDS if s.name != "demo-check"]


@pytest.mark.slow
@pytest.mark.parametrize("name", SCENE_NAMES)
def test_full_size_scene(name):
    path = build_scene(name, settings_with(), force=True, progress=False)
    meta = read_meta(path)
    import pycolmap

    rec = pycolmap.Reconstruction(str(Path(path) / "sparse" / "0"))
    assert rec.num_reg_images() >= 40
    assert rec.num_points3D() >= 2000, meta["sfm_attempts"]
    assert meta["fallback"] is None
    assert meta["text_points"] > 0
    assert meta["timings_s"]["total"] < 60, meta["timings_s"]


def test_viewing_angle_and_distance_of_words_match_their_corners():
    """Issue 30: each visible word records the angle between its surface normal and the direction to the camera
    at its centre, and the distance; checked here from the word's 3D corners (plane through them, their mean)
    on the planar (Quad) words, which is another route than the generator's (the primitive's normal there)."""
    from strings_bench.datasets.synthetic.raycast import Quad

    spec = generate.make_spec("books", 0)
    cams = generate.orbit_cameras(spec, settings_with(), np.random.default_rng([0, 2]))
    from collections import Counter

    unique = {t for t, n in Counter(w.text for w in spec.words).items() if n == 1}  # a visible word names its box
    corners = {w.text: c for w, c in zip(spec.words, generate.word_corners_3d(spec))
               if isinstance(spec.world.primitives[w.prim], Quad) and w.text in unique}
    checked = 0
    for cam in cams[:12]:
        for kw in generate.visible_words(spec, cam, settings_with()):
            assert 0 <= kw.angle_deg < 90 and kw.distance > 0
            c = corners.get(kw.text)
            if c is None:
                continue
            n = np.cross(c[1] - c[0], c[3] - c[0])
            centre = c.mean(axis=0)
            v = cam.center - centre
            want = np.degrees(np.arccos(abs(n @ v) / (np.linalg.norm(n) * np.linalg.norm(v))))
            assert kw.angle_deg == pytest.approx(want, abs=1e-6)
            assert kw.distance == pytest.approx(np.linalg.norm(v), rel=1e-9)
            checked += 1
    assert checked > 20
    angles = [kw.angle_deg for cam in cams[:12] for kw in generate.visible_words(spec, cam, settings_with())]
    assert max(angles) - min(angles) > 10  # the orbit sees words at different angles


def test_annotations_round_trip_angle_and_distance(tmp_path):
    from strings_bench.scene.scene import KnownWord, _read_annotations, write_annotations

    poly = np.array([[0, 0], [10, 0], [10, 4], [0, 4]], float)
    write_annotations(tmp_path / "a.json", {"v.png": [KnownWord("a", poly, 12.5, 3.0), KnownWord("b", poly)]})
    got = _read_annotations(tmp_path / "a.json")["v.png"]
    assert (got[0].angle_deg, got[0].distance, got[1].angle_deg, got[1].distance) == (12.5, 3.0, None, None)
    (tmp_path / "b.json").write_text('{"views": {"v.png": [{"text": "a", "polygon": [[0,0],[1,0],[1,1]], "angle_deg": "x"}]}}')
    from strings_bench.core.errors import StringsBenchError

    with pytest.raises(StringsBenchError, match="angle_deg"):
        _read_annotations(tmp_path / "b.json")
