"""Word-crop readability (eval.readability) and the text-region image metrics (eval.metrics.text_region_metrics)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from _ssim_reference import brute_ssim_same
from PIL import Image, ImageDraw, ImageFilter, ImageFont

import strings_bench.eval.metrics as metrics
import strings_bench.eval.readability as rd
from strings_bench.eval.ocr.base import Word


# ---- CTC likelihood against an independent brute force ------------------------------------------------------
def _brute_ctc_prob(probs: np.ndarray, labels: list[int], blank: int = 0) -> float:
    """Sum over every path in C^T whose collapse (merge repeats, then drop blanks) is `labels`."""
    T, C = probs.shape
    total = 0.0
    for path in itertools.product(range(C), repeat=T):
        collapsed = [k for i, k in enumerate(path) if i == 0 or k != path[i - 1]]
        if [k for k in collapsed if k != blank] == labels:
            total += float(np.prod([probs[t, k] for t, k in enumerate(path)]))
    return total


@pytest.mark.parametrize("T,C,labels", [
    (1, 3, [1]), (3, 3, [1]), (4, 3, [1, 2]), (5, 3, [1, 1]), (6, 4, [1, 2, 1]), (6, 3, [2, 2, 1]),
    (5, 4, [3]), (6, 3, [1, 2, 2]), (4, 3, []),
])
def test_ctc_nll_matches_brute_force_sum_over_alignments(T, C, labels):
    rng = np.random.default_rng(T * 100 + C + len(labels))
    p = rng.random((T, C)) + 0.05
    p /= p.sum(axis=1, keepdims=True)
    want = -math.log(_brute_ctc_prob(p, labels))
    assert rd.ctc_nll(np.log(p), labels) == pytest.approx(want, rel=1e-10)


def test_ctc_nll_is_infinite_when_no_alignment_fits():
    p = np.full((2, 3), 1 / 3)
    assert _brute_ctc_prob(p, [1, 1]) == 0.0  # "aa" needs a blank between: 3 columns
    assert rd.ctc_nll(np.log(p), [1, 1]) == math.inf
    assert rd.ctc_min_columns([1, 1]) == 3 and rd.ctc_min_columns([1, 2]) == 2


def test_greedy_decode_collapses_repeats_and_drops_blanks():
    chars = ["<blank>", "a", "b", " "]
    idx = [1, 1, 0, 1, 2, 2, 3, 0]
    p = np.eye(4)[idx]
    assert rd.greedy_decode(p, chars) == "aab "


def test_folded_alphabet_adds_case_variants_and_space_to_blank_and_counts_oov():
    chars = ["<blank>", "A", "a", "B", " "]
    fa = rd.FoldedAlphabet(chars)
    rng = np.random.default_rng(3)
    p = rng.random((5, 5)) + 0.1
    p /= p.sum(axis=1, keepdims=True)
    folded = np.stack([p[:, 0] + p[:, 4], p[:, 1] + p[:, 2], p[:, 3]], axis=1)  # blank+space, a/A, b
    nll, scored, oov = fa.nll(p, "A b€")  # normalised: "ab€"; € is not in the dictionary
    assert (scored, oov) == (2, 1)
    assert nll == pytest.approx(-math.log(_brute_ctc_prob(folded, [1, 2])), rel=1e-10)
    assert math.isnan(fa.nll(p, "€")[0])


# ---- rectification and the recogniser on drawn words ---------------------------------------------------------
def _font(size=40):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def _word_image(text="MARKET", size=40, pad=30):
    """A white canvas with `text` drawn in black; returns (RGB array, its tight axis-aligned box)."""
    font = _font(size)
    x0, y0, x1, y1 = ImageDraw.Draw(Image.new("RGB", (1, 1))).textbbox((0, 0), text, font=font)
    img = Image.new("RGB", (x1 - x0 + 2 * pad, y1 - y0 + 2 * pad), "white")
    ImageDraw.Draw(img).text((pad - x0, pad - y0), text, fill="black", font=font)
    box = np.array([[pad, pad], [pad + x1 - x0, pad], [pad + x1 - x0, pad + y1 - y0], [pad, pad + y1 - y0]], float)
    return np.asarray(img), box


@pytest.fixture(scope="module")
def recognizer():
    pytest.importorskip("rapidocr")
    from strings_bench.eval.ocr.rapid import get_recognizer

    return get_recognizer()


def _read(recognizer, crop, text):
    return rd.read_crops(recognizer, rd.FoldedAlphabet(recognizer.characters), [crop], [text])[0]


def test_recognizer_reads_a_drawn_word_and_blur_or_emptiness_cost_likelihood(recognizer):
    img, box = _word_image("MARKET")
    sharp = _read(recognizer, rd.rectify(img, box), "MARKET")
    assert sharp.read == "MARKET" and sharp.errors == 0
    blur = {}
    for sigma in (6, 8):
        blurred = np.asarray(Image.fromarray(img).filter(ImageFilter.GaussianBlur(sigma)))
        blur[sigma] = _read(recognizer, rd.rectify(blurred, box), "MARKET")
    empty = _read(recognizer, rd.rectify(np.full_like(img, 255), box), "MARKET")
    # Blur of 6 px still reads (word_cer 0) but costs likelihood: the NLL sees what the CER cannot.
    assert sharp.nll < 0.01 and blur[6].errors == 0 and blur[6].nll > 10 * sharp.nll
    assert blur[6].nll < blur[8].nll < empty.nll
    assert blur[8].errors > 0 and empty.errors == 6 and empty.read == ""


def test_rectify_reads_a_rotated_word(recognizer):
    img, box = _word_image("GARDEN", pad=60)
    angle = 25.0  # counterclockwise, about the centre
    rot = np.asarray(Image.fromarray(img).rotate(angle, resample=Image.Resampling.BICUBIC, fillcolor="white"))
    c = np.array([img.shape[1] / 2, img.shape[0] / 2])
    a = math.radians(angle)
    R = np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])  # image y points down
    quad = (box - c) @ R.T + c
    assert _read(recognizer, rd.rectify(rot, quad), "GARDEN").read == "GARDEN"
    crop = rd.rectify(rot, quad)
    w, h = rd.box_size(quad)
    assert crop.shape[0] == rd.REC_HEIGHT
    assert crop.shape[1] == pytest.approx((w / h + 2 * rd.CROP_MARGIN) * rd.REC_HEIGHT / (1 + 2 * rd.CROP_MARGIN), abs=1)


@pytest.mark.parametrize("turn_image,expect_turn", [(-90, 90), (90, 270)])
def test_vertical_words_are_turned(recognizer, turn_image, expect_turn):
    """A word running top-to-bottom (image turned clockwise) or bottom-to-top, given by a box clockwise from
    the image's top-left (not reading order): the crop is turned, and the turn that reads the GT is kept."""
    img, box = _word_image("SPINE")
    vert = np.asarray(Image.fromarray(img).rotate(turn_image, expand=True))
    h, w = img.shape[:2]
    x0, y0 = box[0]
    x1, y1 = box[2]
    if turn_image == -90:  # clockwise: (x, y) -> (h - y, x)
        xs, ys = (h - y1, h - y0), (x0, x1)
    else:  # counterclockwise: (x, y) -> (y, w - x)
        xs, ys = (y0, y1), (w - x1, w - x0)
    quad = np.array([[xs[0], ys[0]], [xs[1], ys[0]], [xs[1], ys[1]], [xs[0], ys[1]]], float)
    assert rd.turn_candidates(quad, "SPINE") == [90, 270]
    assert rd.turn_candidates(quad, "I") == [0]  # a one-letter word is tall, never turned
    assert _read(recognizer, rd.rectify(vert, quad, turn=expect_turn), "SPINE").read == "SPINE"
    sr = rd.SceneReadability(recognizer)
    out = sr.evaluate({"v": (vert, vert, None, [Word("SPINE", quad)])})
    rec = out["views"]["v"][0]
    assert rec["turn"] == expect_turn and rec["gt"]["read"] == "SPINE" and rec["render"]["errors"] == 0
    assert out["render"]["word_acc"] == 1.0 and out["gt"]["word_cer"] == 0.0


def test_scene_readability_scores_render_against_gt_ceiling(recognizer):
    img, box = _word_image("MARKET")
    blurred = np.asarray(Image.fromarray(img).filter(ImageFilter.GaussianBlur(6)))
    sr = rd.SceneReadability(recognizer)
    out = sr.evaluate({"v": (blurred, img, [("MARKET", box)], [Word("MARKET", box + 1.0)])})
    # The GT-OCR word overlaps the known one: it is kept under its source, not in the headline.
    assert out["render"]["words"] == 1 and out["by_source"]["gt_ocr"]["render"]["words"] == 1
    assert out["gt"]["word_cer"] == 0.0 and out["gt"]["word_acc"] == 1.0
    assert out["render"]["text_nll"] > out["gt"]["text_nll"]
    assert out["render"]["word_cer"] == out["views"]["v"][0]["render"]["errors"] / 6


def test_reference_words_filter_and_deduplicate():
    big = np.array([[0, 0], [60, 0], [60, 20], [0, 20]], float)
    tiny = np.array([[100, 0], [130, 0], [130, 4], [100, 4]], float)  # 4 px high: illegible
    far = big + [0, 100]
    refs, left = rd.reference_words([("BIG", big), ("tiny", tiny), ("  ", far)],
                                    [Word("BIG", big + 2), Word("tiny", tiny), Word("FAR", far)])
    got = [(r.text, r.source, r.headline) for r in refs]
    assert got == [("BIG", "known", True), ("BIG", "gt_ocr", False), ("tiny", "gt_ocr", True), ("FAR", "gt_ocr", True)]
    assert left == {"known_illegible": 1, "unusable_box": 0, "empty_text": 1}
    refs, _ = rd.reference_words(None, None)
    assert refs == []


def test_summarize_counts():
    r = [rd.Reading("ab", 2.0, 2, 2, 0, 0), rd.Reading("x", 6.0, 3, 2, 1, 2), rd.Reading("", math.inf, 4, 4, 0, 4)]
    s = rd.summarize(r)
    assert s["word_cer"] == pytest.approx(6 / 9)
    assert s["word_acc"] == pytest.approx(1 / 3)
    assert s["text_nll"] == pytest.approx(8 / 4)  # the infeasible word is left out, and counted
    assert (s["infeasible_words"], s["oov_chars"], s["words"]) == (1, 1, 3)
    assert math.isnan(rd.summarize([])["word_cer"])


# ---- text-region image metrics ----------------------------------------------------------------------------
def _pair(seed, h=30, w=34):
    rng = np.random.default_rng(seed)
    gt = rng.random((h, w, 3))
    img = np.clip(gt + rng.normal(0, 0.1, gt.shape), 0, 1)
    return img, gt


def test_masked_psnr_hand_value():
    gt = np.full((8, 10, 3), 0.5)
    img = gt.copy()
    img[2:4, 3:5] += 0.1  # inside the mask: MSE 0.01 there
    img[7, 9] = 0.0  # outside the mask: ignored
    mask = np.zeros((8, 10), bool)
    mask[2:4, 3:7] = True  # 8 pixels, 4 of them off by 0.1 -> MSE 0.005
    assert metrics.masked_psnr(img, gt, mask) == pytest.approx(-10 * math.log10(0.005), abs=1e-9)
    assert math.isnan(metrics.masked_psnr(img, gt, np.zeros((8, 10), bool)))
    assert metrics.masked_psnr(gt, gt, mask) == math.inf


@pytest.mark.parametrize("strip_rows", [32, 5])
def test_masked_ssim_is_the_masked_mean_of_the_brute_force_map(strip_rows):
    img, gt = _pair(1)
    mask = np.zeros(gt.shape[:2], bool)
    mask[3:12, 2:30] = True
    mask[20:29, 25:33] = True  # touches the border: zero padding as the full-image SSIM
    want = brute_ssim_same(img, gt)[mask].mean()
    assert metrics.masked_ssim(img, gt, mask, strip_rows=strip_rows) == pytest.approx(want, abs=1e-12)
    full = np.ones(gt.shape[:2], bool)
    assert metrics.masked_ssim(img, gt, full) == pytest.approx(metrics.ssim(img, gt), abs=1e-12)


def test_mask_bbox_and_masked_lpips_crop(monkeypatch):
    mask = np.zeros((50, 60), bool)
    mask[10:14, 3:9] = True
    assert metrics.mask_bbox(mask) == (10, 14, 3, 9)
    assert metrics.mask_bbox(mask, 32) == (0, 32, 0, 32)  # grown about the box, kept inside the image
    mask2 = np.zeros((50, 60), bool)
    mask2[30:34, 40:60] = True
    assert metrics.mask_bbox(mask2, 32) == (16, 48, 28, 60)
    assert metrics.mask_bbox(np.zeros((5, 5), bool)) is None
    seen = {}

    def fake_lpips(a, b, gt_reference=None, device="cpu"):
        seen["shape"] = a.shape
        seen["same"] = np.array_equal(b, gt[16:48, 28:60])
        return 0.25

    monkeypatch.setattr(metrics, "lpips", fake_lpips)
    img, gt = _pair(2, 50, 60)
    out = metrics.text_region_metrics(img, gt, mask2)
    assert out["text_lpips"] == 0.25 and seen == {"shape": (32, 32, 3), "same": True}
    assert math.isnan(metrics.text_region_metrics(img, gt, mask2, with_lpips=False)["text_lpips"])
    assert all(math.isnan(v) for v in metrics.text_region_metrics(img, gt, None).values())
