"""The evaluation's faster paths give the figures of the paths they replace, to the bit.

- `metrics.view_metrics` (one pass per view, one SSIM map for both SSIMs, torch on one thread) against
  `image_metrics` + `text_region_metrics` as the evaluation called them before, on images whose heights
  are and are not multiples of the strip height, masks that are empty, absent, or cover a few rows.
- torch's thread count does not change SSIM's bits (`one_torch_thread` relies on it).
- The word-crop scoring from float32 probabilities (what `read_crops` now asks the recogniser for) against
  the float64 probabilities it used to take.
- `Evaluator.evaluate` of renders against a reference computed here from the old per-view functions, every
  metric compared by its bits.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import strings_bench.eval.metrics as metrics
from strings_bench.core.errors import StringsBenchError
import strings_bench.eval.readability as rd


def _pair(h, w, seed):
    """A render and its GT on the 8-bit grid, as the evaluation scores them (protocol.scored_image)."""
    rng = np.random.default_rng(seed)
    gt = (rng.integers(0, 256, (h, w, 3)) / 255).astype(np.float32)
    img = (np.clip(np.round(gt * 255 + rng.normal(0, 20, gt.shape)), 0, 255) / 255).astype(np.float32)
    return img, gt


def _bits(d: dict) -> dict:
    return {k: (float(v).hex() if not math.isnan(v) else "nan") for k, v in d.items()}


def _masks(h, w):
    m1 = np.zeros((h, w), bool)
    m1[h // 3: h // 3 + 7, 5: w - 9] = True  # a few rows inside one or two strips
    m2 = np.zeros((h, w), bool)
    m2[::5, ::3] = True  # every strip
    return [None, np.zeros((h, w), bool), m1, m2]


# Small images (a strip's sum is not split between threads); 1280 wide, where it is: the next test.
@pytest.mark.parametrize("h,w", [(64, 80), (75, 96), (33, 40)])
def test_view_metrics_equal_the_separate_metrics_bit_for_bit(h, w):
    img, gt = _pair(h, w, h * w)
    for mask in _masks(h, w):
        old = metrics.image_metrics(img, gt, with_lpips=False)
        old.update(metrics.text_region_metrics(img, gt, mask, with_lpips=False))
        new = metrics.view_metrics(img, gt, mask, with_lpips=False)
        assert list(new) == list(old)  # the same keys in the same order (result.json)
        assert _bits(new) == _bits(old)
        s, ms = metrics.ssim_and_masked_ssim(img, gt, mask, strip_rows=7)
        assert s.hex() == metrics.ssim(img, gt, strip_rows=7).hex()
        if mask is not None and mask.any():
            assert ms.hex() == metrics.masked_ssim(img, gt, mask, strip_rows=7).hex()
        else:
            assert math.isnan(ms)


def test_view_metrics_differ_when_the_render_does():
    """The comparison above can fail: one pixel changed changes the values."""
    img, gt = _pair(40, 48, 1)
    mask = _masks(40, 48)[3]
    other = img.copy()
    other[20, 20] = 1 - other[20, 20]
    a = _bits(metrics.view_metrics(img, gt, mask, with_lpips=False))
    b = _bits(metrics.view_metrics(other, gt, mask, with_lpips=False))
    assert a["psnr"] != b["psnr"] and a["ssim"] != b["ssim"] and a["text_ssim"] != b["text_ssim"]


def test_view_metrics_equal_the_separate_metrics_at_any_thread_count():
    """The one-pass metrics match the separate ones run with the same torch threads (2: a 32-row strip 1280 wide
    holds 122 880 values, above torch's grain size of 32 768, and its sum is split between them; 1: not split). On the AMD EPYC this was written on, this pair's PSNR differs in its
    last bit between 1 and 2 threads: a one-pass path that took the PSNR on one thread failed here."""
    img, gt = _pair(70, 1280, 0)
    mask = _masks(70, 1280)[3]
    before = torch.get_num_threads()
    try:
        for n in (2, 1):
            torch.set_num_threads(n)
            old = metrics.image_metrics(img, gt, with_lpips=False)
            old.update(metrics.text_region_metrics(img, gt, mask, with_lpips=False))
            assert _bits(metrics.view_metrics(img, gt, mask, with_lpips=False)) == _bits(old)
            assert torch.get_num_threads() == n
    finally:
        torch.set_num_threads(before)
    before = torch.get_num_threads()
    with metrics.one_torch_thread():
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before


def test_crop_scores_from_float32_probabilities_equal_float64():
    rng = np.random.default_rng(5)
    chars = ["<blank>"] + list("abcdefghABCDEFGH0123") + [" "]
    alphabet = rd.FoldedAlphabet(chars)
    for t in range(30):
        logits = rng.normal(0, 3, (12 + t % 7, len(chars))).astype(np.float32)
        p32 = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
        p64 = np.asarray(p32, dtype=np.float64)  # what probabilities() used to return
        for text in ("abc", "Aa b", "hhh", "zz9", "dEf0"):
            a, b = rd.score(p32, chars, alphabet, text), rd.score(p64, chars, alphabet, text)
            assert (a.read, a.errors, a.chars, a.nll_chars, a.oov_chars) == (b.read, b.errors, b.chars, b.nll_chars, b.oov_chars)
            assert (a.nll == b.nll) or (math.isnan(a.nll) and math.isnan(b.nll)), (a.nll, b.nll)


def _lpips_or_skip():
    import strings_bench.eval.lpips_net as lpips_net

    if not lpips_net.available():
        pytest.skip("LPIPS weights not installed: " + lpips_net.INSTALL_HINT)


@pytest.mark.parametrize("h,w", [(72, 96), (40, 48)])
def test_text_lpips_from_the_gt_crop_features_made_once_equals_the_separate_metrics(h, w):
    """text_lpips with the GT crop's features made once (`text_lpips_reference`, kept per view by the Evaluator)
    equals `text_region_metrics`' text_lpips, which makes them anew for each render, bit for bit: for a crop inside
    the image, a crop that is the whole image (text_lpips is then the image's LPIPS, not computed twice) and an
    empty mask (NaN); and LPIPS with the GT's features made once equals LPIPS made from both images."""
    _lpips_or_skip()
    img, gt = _pair(h, w, 11)
    inside = np.zeros((h, w), bool)
    inside[20:30, 10:40] = True  # grown to a 32 px crop
    whole = np.zeros((h, w), bool)
    whole[0, 3] = whole[h - 1, 0] = whole[5, w - 1] = True  # its bounding box spans the image
    whole_ref = metrics.lpips_reference(gt)
    for mask in (inside, whole, np.zeros((h, w), bool)):
        old = metrics.image_metrics(img, gt, with_lpips=True)
        old.update(metrics.text_region_metrics(img, gt, mask, with_lpips=True))
        text_ref = metrics.text_lpips_reference(gt, mask, whole=whole_ref)
        new = metrics.view_metrics(img, gt, mask, with_lpips=True, gt_reference=whole_ref, text_reference=text_ref)
        assert _bits(new) == _bits(old)
        if mask is inside:
            assert text_ref[0] == metrics.mask_bbox(inside, metrics.LPIPS_MIN_CROP) and text_ref[1] is not whole_ref
            assert 0 < new["text_lpips"] != new["lpips"] > 0
        elif mask is whole:
            assert text_ref[1] is whole_ref and new["text_lpips"] == new["lpips"]
        else:
            assert text_ref is None and math.isnan(new["text_lpips"])
    other = metrics.text_lpips_reference(gt, whole, whole=whole_ref)
    with pytest.raises(StringsBenchError, match="text crop's LPIPS reference"):
        metrics.masked_lpips(img, gt, inside, gt_reference=other)  # a reference made for another crop
