"""rho, the scene's position step in text strokes: the stroke-width measure on drawn strokes of known
width (anti-aliased, sub-pixel), and the scene figure from known words or text masks against the formula
rho = 1.6e-4 x extent / (stroke px x depth / fx) worked out by hand."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image, ImageDraw

from strings_bench.scene.difficulty import mask_regions, scene_difficulty, stroke_width_px

SUPER = 8  # supersampling of the drawn strokes: their edges are anti-aliased as a renderer's are


def strokes_image(width_px: float, size=(60, 30)) -> np.ndarray:
    """Four vertical bars and one horizontal one, `width_px` wide, dark on light, box-filtered from 8x."""
    W, H = size
    im = Image.new("L", (W * SUPER, H * SUPER), 230)
    d = ImageDraw.Draw(im)
    w = round(width_px * SUPER)
    for x in (8, 22, 36, 50):
        d.rectangle([x * SUPER, 5 * SUPER, x * SUPER + w - 1, 25 * SUPER - 1], fill=20)
    d.rectangle([8 * SUPER, 14 * SUPER, 50 * SUPER, 14 * SUPER + w - 1], fill=20)
    return np.asarray(im.resize((W, H), Image.BOX), np.float64)


BOX = np.array([[2, 2], [58, 2], [58, 28], [2, 28]], float)


@pytest.mark.parametrize("width", [1.0, 1.5, 2.0, 3.0, 5.0])
def test_stroke_width_reads_drawn_strokes(width):
    assert stroke_width_px(strokes_image(width), BOX) == pytest.approx(width, rel=0.08)
    # light ink on a dark ground reads the same
    assert stroke_width_px(250 - strokes_image(width), BOX) == pytest.approx(width, rel=0.08)


def text_image(font_px: int, text: str, style: str, offset: tuple[int, int], factor: int = SUPER):
    """`text` drawn at `factor` times the size and box-filtered down (anti-aliased as a renderer's), and the same
    drawing at full size: (small image, large image)."""
    from strings_bench.datasets.synthetic.textures import load_font

    font = load_font(style, font_px * factor)
    w = int(font.getlength(text)) + 8 * factor
    w -= w % factor
    h = 2 * font_px * factor
    im = Image.new("L", (w, h), 225)
    ImageDraw.Draw(im).text((2 * factor + offset[0], factor // 2 + offset[1]), text, font=font, fill=25)
    return (np.asarray(im.resize((w // factor, h // factor), Image.BOX), np.float64), np.asarray(im, np.float64))


def _box(img):
    h, w = img.shape
    return np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float)


def test_thin_strokes_read_wide_and_thick_ones_true():
    """The measurement's limit, on words drawn 8x larger and box-filtered down (their true width: the same drawing
    measured at 8x, 7-35 pixels there): 2.2-pixel strokes read 7 % wide, 3-pixel ones within 3 %, 1.5-pixel ones
    1.2x and 0.9-pixel ones 1.6x wide (no pixel of a thin stroke is all ink), which is why the suite's synthetic
    scenes are measured on their words rendered again finer (datasets/synthetic/rho.py)."""
    rng = np.random.default_rng(0)
    ratios = {}
    for font_px in (10, 16, 24, 32):
        r = []
        for text in ("STORAGE", "Handle with care", "Flour 2kg", "batteries"):
            for style in ("sans", "sans-bold", "serif"):
                small, large = text_image(font_px, text, style, tuple(int(v) for v in rng.integers(0, SUPER, 2)))
                r.append(stroke_width_px(small, _box(small)) / (stroke_width_px(large, _box(large)) / SUPER))
        ratios[font_px] = float(np.median(r))
    assert ratios[32] == pytest.approx(1.0, abs=0.03) and ratios[24] == pytest.approx(1.0, abs=0.1)
    assert ratios[16] > 1.15 and ratios[10] > 1.4


def test_reliable_says_whether_the_median_stroke_is_thick_enough():
    from strings_bench.scene.difficulty import MIN_RELIABLE_STROKE_PX, difficulty_from_strokes

    thin = difficulty_from_strokes(2.0, [1.5, 1.8, 2.0], [0.01, 0.012, 0.013])
    assert thin.reliable is False and thin.measured_on == "images"
    assert thin.rho == pytest.approx(1.6e-4 * 2.0 / 0.012)
    # the same strokes measured 2x finer (re-rendered): reliable, the pixels still those of the images
    fine = difficulty_from_strokes(2.0, [1.5, 1.8, 2.0], [0.01, 0.012, 0.013], [3.0, 3.6, 4.0], "crops x2")
    assert fine.reliable is True and fine.stroke_px == pytest.approx(1.8) and MIN_RELIABLE_STROKE_PX <= 3.6
    assert difficulty_from_strokes(2.0, [], []).rho is None


def test_stroke_width_refuses_what_it_cannot_measure():
    assert stroke_width_px(np.full((30, 60), 128.0), BOX) is None  # one grey level: no ink
    assert stroke_width_px(strokes_image(2.0), np.array([[2, 2], [5, 2], [5, 5], [2, 5]], float)) is None  # tiny box


def fake_scene(tmp_path: Path, width_px: float, distance: float | None, fx: float = 100.0, extent: float = 3.0,
               with_mask: bool = False):
    img = strokes_image(width_px)
    path = tmp_path / "view.png"
    Image.fromarray(img.astype(np.uint8)).save(path)
    word = SimpleNamespace(polygon=BOX, distance=distance)
    mask = np.zeros(img.shape, np.uint8)
    mask[3:28, 4:57] = 255
    return SimpleNamespace(
        extent=extent, num_views=1, image_path=lambda i: path,
        model=SimpleNamespace(cameras=[SimpleNamespace(fx=fx)]),
        known_text=None if with_mask else {"view.png": [word]},
        known_words=lambda i: None if with_mask else [word],
        load_mask=lambda i: mask if with_mask else None)


def test_rho_from_known_words_follows_the_formula(tmp_path):
    d = scene_difficulty(fake_scene(tmp_path, 3.0, distance=2.0))
    assert d.words == 1
    stroke = d.stroke_px * 2.0 / 100.0  # pixels x depth / fx
    assert d.stroke_world == pytest.approx(stroke)
    assert d.rho == pytest.approx(1.6e-4 * 3.0 / stroke)
    assert d.stroke_px == pytest.approx(3.0, rel=0.08)
    # the same text twice as far is twice as wide in the world (same pixels): rho halves
    far = scene_difficulty(fake_scene(tmp_path, 3.0, distance=4.0))
    assert far.rho == pytest.approx(d.rho / 2)


def test_rho_from_text_masks_where_no_word_is_known(tmp_path, monkeypatch):
    import strings_bench.scene.difficulty as D

    monkeypatch.setattr(D, "_sfm_depth", lambda scene, view, polygon, points=None: 2.0)
    monkeypatch.setattr(D, "_view_points", lambda scene, view: (np.zeros(0, int), np.zeros((0, 2))))
    d = scene_difficulty(fake_scene(tmp_path, 2.0, distance=None, with_mask=True))
    assert d.words == 1 and d.stroke_px == pytest.approx(2.0, rel=0.1)
    assert d.rho == pytest.approx(1.6e-4 * 3.0 / (d.stroke_px * 2.0 / 100.0))


def test_mask_regions_are_the_components_boxes():
    m = np.zeros((20, 30), np.uint8)
    m[2:5, 3:9] = 1
    m[10:18, 20:25] = 1
    boxes = sorted(mask_regions(m), key=lambda b: b[0, 0])
    assert [b.min(0).tolist() + b.max(0).tolist() for b in boxes] == [[3, 2, 8, 4], [20, 10, 24, 17]]


def test_sfm_depth_is_the_median_depth_of_the_points_seen_inside(tmp_path):
    """On a tiny SfM scene (tests/_engine_helpers.py): against the points' depths computed directly."""
    import sys

    from _engine_helpers import make_tiny_scene
    import strings_bench.scene.difficulty as D

    scene = make_tiny_scene(tmp_path / "scene", n_views=3, n_points=80)
    cam = scene.model.cameras[1]
    box = np.array([[4, 4], [28, 4], [28, 20], [4, 20]], float)
    z = []
    for p in range(scene.model.num_points):
        lo, hi = scene.model.track_ptr[p], scene.model.track_ptr[p + 1]
        for k in range(lo, hi):
            x, y = scene.model.track_xy[k]
            if scene.model.track_view[k] == 1 and 4 < x < 28 and 4 < y < 20:
                z.append((np.asarray(cam.R) @ scene.model.xyz[p] + np.asarray(cam.t))[2])
    assert len(z) > 3
    assert D._sfm_depth(scene, 1, box) == pytest.approx(float(np.median(z)))
