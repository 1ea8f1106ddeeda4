"""RapidOCR rotations and upscaling (coordinates mapped back, duplicates merged), word boxes of
upside-down lines, and the legibility filter of the known-text CER."""

from __future__ import annotations

import math

import numpy as np
import pytest

from strings_bench.eval.cer import (
    KNOWN_TEXT_MIN_HEIGHT_PX,
    known_scene_cer,
    known_text_cer,
    split_legible,
    text_height_px,
)
from strings_bench.core.errors import OCRError, StringsBenchError
from strings_bench.eval.ocr import Word
from strings_bench.eval.ocr.rapid import (
    DEFAULTS,
    RapidOCRBackend,
    merge_rotated_reads,
    rotate_image,
    unrotate_points,
    upscale_factor,
)


def _word_image(text: str, font_size: int = 16, angle: int = 0, pad: int = 12):
    """White image with `text` in black, turned `angle` degrees counterclockwise (PIL), and the
    known words (their ink boxes, turned the same way) in the final image's pixels."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default(size=font_size)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    width = int(probe.textlength(text, font=font)) + 2 * pad
    height = 3 * font_size
    im = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(im)
    x = pad
    y = font_size
    draw.text((x, y), text, fill="black", font=font)
    words = []
    for k, part in enumerate(text.split()):
        x0 = x + draw.textlength(text[: _offset(text, k)], font=font)
        words.append(Word.from_box(part, *draw.textbbox((x0, y), part, font=font)))
    turned = np.asarray(im.rotate(angle, expand=True))
    if angle % 360:
        # PIL turns counterclockwise about the centre and expands; np.rot90 is the same for multiples of 90.
        assert np.array_equal(turned, rotate_image(np.asarray(im), angle % 360))
        words = [Word(w.text, _rotate_points(w.polygon, angle % 360, width, height)) for w in words]
    return turned, words


def _offset(text: str, index: int) -> int:
    """Character offset of the index-th space-separated word of text."""
    pos = 0
    for k, w in enumerate(text.split()):
        pos = text.index(w, pos)
        if k == index:
            return pos
        pos += len(w)
    raise IndexError(index)


def _rotate_points(points: np.ndarray, degrees: int, width: int, height: int) -> np.ndarray:
    """Forward map of points when the image is turned counterclockwise (inverse of unrotate_points)."""
    p = np.asarray(points, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    k = degrees // 90 % 4
    if k == 0:
        return p.copy()
    if k == 1:
        return np.stack([y, width - x], axis=1)
    if k == 2:
        return np.stack([width - x, height - y], axis=1)
    return np.stack([height - y, x], axis=1)


# --------------------------------------------------------------------------- geometry, no engine
@pytest.mark.parametrize("degrees", [0, 90, 180, 270])
def test_unrotate_points_matches_np_rot90_pixel_centres(degrees):
    rng = np.random.default_rng(degrees)
    h, w = 7, 11
    img = rng.integers(0, 255, (h, w)).astype(np.int64)
    turned = np.rot90(img, degrees // 90)
    for _ in range(20):
        r, c = rng.integers(0, turned.shape[0]), rng.integers(0, turned.shape[1])
        x, y = unrotate_points([[c + 0.5, r + 0.5]], degrees, w, h)[0]  # pixel centre back in the original
        assert img[int(math.floor(y)), int(math.floor(x))] == turned[r, c]
        assert x % 1 == pytest.approx(0.5) and y % 1 == pytest.approx(0.5)
    pts = rng.uniform(0, 5, (6, 2))
    assert np.allclose(unrotate_points(_rotate_points(pts, degrees, w, h), degrees, w, h), pts)


class _BoxFinder(RapidOCRBackend):
    """RapidOCR's wrapper with the engine replaced: one word covering the red pixels of what it is given."""

    def __init__(self, **settings):
        super().__init__(cache=None, **settings)
        self.shapes = []

    def _read_once(self, rgb):
        self.shapes.append(rgb.shape)
        red = (rgb[:, :, 0] > 160) & (rgb[:, :, 1] < 90) & (rgb[:, :, 2] < 90)
        ys, xs = np.nonzero(red)
        return [Word.from_box("box", xs.min(), ys.min(), xs.max() + 1, ys.max() + 1, 0.9)]


@pytest.mark.parametrize("degrees,upscale", [(0, 1.0), (90, 2.0), (270, 3.0), (180, 2.5), (90, 1.5)])
def test_polygon_maps_back_under_rotation_and_upscale(degrees, upscale):
    img = np.full((60, 80, 3), 255, np.uint8)
    img[20:30, 50:70] = (230, 20, 20)  # known box: x 50..70, y 20..30
    b = _BoxFinder(rotations=[degrees], upscale=upscale)
    (word,) = b.read(img)
    turned_shape = (60, 80) if degrees in (0, 180) else (80, 60)
    assert b.shapes[0][:2] == (round(turned_shape[0] * upscale), round(turned_shape[1] * upscale))
    x0, y0 = word.polygon.min(axis=0)
    x1, y1 = word.polygon.max(axis=0)
    tol = 1.0  # bicubic ringing may add or remove a pixel of the enlarged edge
    assert (x0, y0, x1, y1) == pytest.approx((50, 20, 70, 30), abs=tol)


def test_upscale_is_capped_by_max_side_len():
    assert upscale_factor(320, 240, 2.0, 2000) == 2.0
    assert upscale_factor(1600, 1200, 2.0, 2000) == pytest.approx(1.25)
    assert upscale_factor(4000, 3000, 2.0, 2000) == 1.0  # never shrinks here (RapidOCR does that itself)


def test_merge_keeps_the_more_confident_of_a_word_read_twice():
    a0 = Word.from_box("B0OK", 10, 10, 50, 20, 0.6)  # read 0
    other0 = Word.from_box("SHELF", 100, 10, 150, 20, 0.9)
    a1 = Word.from_box("BOOK", 11, 9, 49, 21, 0.95)  # the same place, read 1
    inside1 = Word.from_box("OO", 20, 10, 30, 20, 0.97)  # inside a0/a1: the smaller one is covered
    far1 = Word.from_box("LAMP", 10, 100, 50, 110, 0.5)
    same_read = Word.from_box("BOOKS", 12, 10, 52, 20, 0.99)  # read 0 again: never merged within a read
    out = merge_rotated_reads([[a0, other0], [a1, far1]], overlap=0.5)
    assert [w.text for w in out] == ["SHELF", "BOOK", "LAMP"]
    out = merge_rotated_reads([[a0, other0], [inside1, a1]], overlap=0.5)
    # "OO" (0.97) lies inside B0OK, so it drops it; BOOK is in OO's own read, so it stays.
    assert [w.text for w in out] == ["SHELF", "OO", "BOOK"]
    out = merge_rotated_reads([[a0, same_read], [a1]], overlap=0.5)
    assert sorted(w.text for w in out) == ["B0OK", "BOOKS"]  # BOOKS (0.99) drops BOOK (read 1); B0OK stays
    assert merge_rotated_reads([[a0]], 0.5) == [a0] and merge_rotated_reads([], 0.5) == []


def test_rapidocr_settings_are_checked_and_recorded():
    b = RapidOCRBackend(cache=None)
    s = b.describe()["settings"]
    assert s["upscale"] == DEFAULTS["upscale"] and s["rotations"] == DEFAULTS["rotations"]
    assert s["merge_overlap"] == DEFAULTS["merge_overlap"]
    assert b.threads == 1  # runtime, not a setting: read_many runs one read per core
    from strings_bench.eval.ocr.cache import OCRCache

    d1 = RapidOCRBackend(cache=None, rotations=[0]).describe()
    assert OCRCache.key(d1, "img", None) != OCRCache.key(b.describe(), "img", None)
    for bad in ({"upscale": 0.5}, {"upscale": "big"}, {"rotations": [45]}, {"rotations": []},
                {"rotations": [0, 0]}, {"merge_overlap": 0}):
        with pytest.raises(OCRError):
            RapidOCRBackend(cache=None, **bad)


# --------------------------------------------------------------------------- RapidOCR itself
@pytest.fixture(scope="module")
def upright_only():
    return RapidOCRBackend(cache=None, rotations=[0], upscale=2.0)


@pytest.fixture(scope="module")
def with_rotations():
    return RapidOCRBackend(cache=None, rotations=[0, 90, 270], upscale=2.0)


@pytest.mark.parametrize("word,angle", [("GO", -90), ("GO", 90), ("OX", -90), ("OX", 90)])
def test_vertical_words_need_rotations(upright_only, with_rotations, word, angle):
    # A short word turned by 90 degrees: its box is too squat for RapidOCR to turn the crop
    # (it does so only when height >= 1.5 x width), so upright the recogniser sees sideways
    # letters; turning the image makes it ordinary horizontal text.
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default(size=20)
    im = Image.new("RGB", (20 * len(word) + 20, 60), (120, 30, 30))
    d = ImageDraw.Draw(im)
    d.text((10, 20), word, fill=(240, 230, 200), font=font)
    known = [Word.from_box(word, *d.textbbox((10, 20), word, font=font))]
    img = np.asarray(im.rotate(angle, expand=True))
    known = [Word(k.text, _rotate_points(k.polygon, angle % 360, *im.size)) for k in known]
    upright = known_text_cer(known, upright_only.read(img))
    turned = known_text_cer(known, with_rotations.read(img))
    assert upright.cer >= 0.5, upright
    assert turned.errors == 0, turned


@pytest.mark.parametrize("angle", [90, 180, 270])
def test_words_of_turned_lines_keep_their_places(upright_only, with_rotations, angle):
    # RapidOCR 3.10 mirrors the word boxes of lines its classifier turned by 180 degrees; ours must not.
    img, known = _word_image("MOBY DICK", font_size=16, angle=angle)
    proportional = RapidOCRBackend(cache=None, rotations=[0, 90, 270], upscale=2.0, word_boxes="proportional")
    for backend in (upright_only, with_rotations, proportional):
        words = backend.read(img)
        assert sorted(w.text for w in words) == ["DICK", "MOBY"], words
        r = known_text_cer(known, words)
        assert r.errors == 0 and all(len(c.gt) == 1 for c in r.components), r


# --------------------------------------------------------------------------- legibility filter
def test_text_height_is_across_the_reading_direction():
    assert text_height_px([[0, 0], [40, 0], [40, 8], [0, 8]]) == pytest.approx(8)
    # Sheared by perspective: left/right edges long and slanted, glyph height still 5.
    sheared = np.array([[0, 0], [40, 0], [52, 5], [12, 5]], float)
    assert text_height_px(sheared) == pytest.approx(5)
    # A vertical word in reading order (top-left as read = top-right of the box).
    spine = np.array([[10, 0], [10, 50], [4, 50], [4, 0]], float)
    assert text_height_px(spine) == pytest.approx(6)
    # A single tall letter: height is the reading-direction-independent box height, not its width.
    assert text_height_px([[0, 0], [4, 0], [4, 9], [0, 9]]) == pytest.approx(9)
    hexagon = np.array([[0, 0], [30, 0], [34, 3], [30, 6], [0, 6], [-4, 3]], float)
    assert text_height_px(hexagon) == pytest.approx(6)
    assert math.isnan(text_height_px([[0, 0], [1, 1], [2, 2], [3, 3]]))


def test_known_text_cer_legibility_filter_counts_what_it_excludes():
    big = Word.from_box("TITLE", 0, 0, 60, 12)  # 12 px
    small = Word.from_box("author name", 0, 20, 40, 24)  # 4 px, 10 chars (space removed)
    read = [Word.from_box("TITLE", 1, 0, 59, 12, 0.9)]
    assert known_text_cer([big, small], read).cer == pytest.approx(10 / 15)
    assert known_text_cer([big, small], read, min_text_height_px=6).cer == 0
    legible, excluded = split_legible([big, small], 6)
    assert legible == [big] and excluded == [small]
    per_image = {
        "a": ([big, small], read),
        "b": ([small], []),  # nothing legible: left out as an empty view, its characters counted as excluded
        "c": ([big], None),  # OCR failed: left out as failed
    }
    r = known_scene_cer(per_image, min_text_height_px=6)
    assert (r.errors, r.chars, r.cer) == (0, 5, 0.0)
    assert r.legibility["excluded_words"] == 2 and r.legibility["excluded_chars"] == 20
    assert r.legibility["min_text_height_px"] == 6.0
    assert r.ignored_empty_gt == ("b",) and r.ignored_failed == ("c",)
    d = r.to_dict()
    assert d["legibility"]["excluded_chars"] == 20
    r0 = known_scene_cer(per_image, min_text_height_px=0)
    assert (r0.errors, r0.chars) == (20, 25) and r0.legibility["excluded_chars"] == 0
    assert known_scene_cer({"a": ([big], read)}).legibility["min_text_height_px"] == KNOWN_TEXT_MIN_HEIGHT_PX
    with pytest.raises(StringsBenchError):
        known_scene_cer(per_image, min_text_height_px=-1)


class _Recorder(RapidOCRBackend):
    def _recognize(self, rgb):
        self.seen = rgb.copy()
        return []


@pytest.mark.parametrize("fill", [0, 128, 255])
def test_mask_fill_sets_the_pixels_outside_the_mask(fill):
    rgb = np.full((20, 30, 3), 200, np.uint8)
    mask = np.zeros((20, 30), bool)
    mask[5:10, 5:25] = True
    b = _Recorder(cache=None, mask_fill=fill)
    b.read(rgb, mask=mask)
    assert np.all(b.seen[mask] == 200) and np.all(b.seen[~mask] == fill)
    assert RapidOCRBackend(cache=None).settings["mask_fill"] == 128
    with pytest.raises(OCRError, match="mask_fill"):
        RapidOCRBackend(cache=None, mask_fill=300)


@pytest.mark.slow
def test_default_backend_reads_synthetic_books_ground_truth():
    """Full-size synthetic books (320x240; built on first use, ~30 s): known-text CER of the GT test
    views with the default backend and legibility filter <= 0.10, unmasked and masked as the runner does."""
    from strings_bench.datasets import resolve_scenes
    from strings_bench.eval.ocr import get_backend
    from strings_bench.eval.text_masks import eval_mask, eval_mask_settings
    from strings_bench.scene.scene import Scene

    scene = Scene.load(resolve_scenes(["synthetic/books"])[0].path)
    ocr = get_backend("rapidocr", cache=False)
    settings = eval_mask_settings(scene)
    plain, masked = {}, {}
    for i in scene.test_idx:
        img = (np.clip(scene.load_image(i), 0, 1) * 255).round().astype(np.uint8)
        known = [(k.text, k.polygon) for k in scene.known_words(i) or []]
        plain[str(i)] = (known, ocr.read(img))
        masked[str(i)] = (known, ocr.read(img, mask=eval_mask(scene, i, 1, settings)))
    r = known_scene_cer(plain)
    assert r.chars >= 60 and r.cer <= 0.10, r.to_dict()
    rm = known_scene_cer(masked)
    assert rm.cer <= 0.25, rm.to_dict()  # masked reads lose some cover text at grazing angles (docs/ocr.md)
