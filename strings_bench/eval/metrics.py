"""Image metrics of a render against its ground truth: PSNR, SSIM and LPIPS-VGG.

Conventions follow the 3DGS evaluation script the paper's numbers come from:
- images are float RGB in [0, 1], compared at the resolution the method was trained at;
- PSNR = -10 log10(MSE) with a data range of 1, per image; a scene's value is the mean over views;
- SSIM: 11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, per channel, the window applied
  with zero padding ("same" output size) and the map averaged over every pixel and channel (the
  3DGS `ssim` function);
- LPIPS: VGG, v0.1 linear layers, inputs scaled to [-1, 1] (see lpips_net.py). NaN when the
  weights are not installed (tables then show "n/a", never 0).

PSNR and SSIM are the suite's only implementation (`strings_bench.eval.image_quality`), which the
training loss uses too (`strings_bench.engine.losses` imports it), evaluated here in float64.
"""

from __future__ import annotations

import logging
import math
from contextlib import contextmanager

import numpy as np
import torch
import torch.nn.functional as F

from strings_bench.core.errors import StringsBenchError
from strings_bench.eval import image_quality
from strings_bench.eval.image_quality import SSIM_SIGMA, SSIM_WINDOW

log = logging.getLogger(__name__)

# SSIM is evaluated in strips of this many map rows. torch's float64 convolution on the CPU unfolds
# its input (11x the image), which runs out of cache on large views: at 1080x1620 the whole image took
# 3.4 s against 0.35 s in 32-row strips (one thread, CPU time; the SciPy code this replaced: 0.32 s).
SSIM_STRIP_ROWS = 32


@contextmanager
def one_torch_thread():
    """torch on one thread inside the block (restored after). The SSIM map's float64 operations on
    32-row strips are too small to share between threads: with torch's two threads (2 cores) the SSIM
    of a 320x240 view took 7.9-9.9 s on a loaded 2-core AMD EPYC against 0.27-0.31 s on one (the
    threads wait for each other at every operation). Only operations whose every output is computed
    by one thread (the map's convolutions and element-wise arithmetic) run inside it; a sum or a mean
    splits its terms between threads above torch's grain size, and the thread count then changes its
    last bits, so the sums stay outside, on the caller's threads (tests/eval/test_eval_speed.py)."""
    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def _check_pair(img: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.ascontiguousarray(img, dtype=np.float64)
    b = np.ascontiguousarray(gt, dtype=np.float64)
    if a.shape != b.shape:
        raise StringsBenchError(f"render is {a.shape} but the ground truth is {b.shape}",
                                hint="the method must render test views at the scene's size for the chosen downscale")
    if a.ndim != 3 or a.shape[2] != 3:
        raise StringsBenchError(f"expected HxWx3 images, got shape {a.shape}", hint="pass RGB images")
    return a, b


def psnr(img: np.ndarray, gt: np.ndarray) -> float:
    """PSNR in dB (data range 1) of an (H, W, 3) render against its ground truth, in float64; inf when equal."""
    a, b = _check_pair(img, gt)
    return image_quality.psnr(torch.from_numpy(a), torch.from_numpy(b))


def ssim(img: np.ndarray, gt: np.ndarray, strip_rows: int = SSIM_STRIP_ROWS) -> float:
    """SSIM (3DGS convention, zero padding) of an (H, W, 3) render against its ground truth, in float64.

    The map is `image_quality.ssim_map` over the image zero-padded once, taken `strip_rows` rows at a time
    with padding "valid": each strip sees the same window contents as the whole-image "same" map, so
    the result is that map's mean (to float rounding) at a fraction of the memory traffic.
    """
    a, b = _check_pair(img, gt)
    if strip_rows < 1:
        raise StringsBenchError(f"strip_rows must be at least 1, not {strip_rows}", hint="use the default")
    h = a.shape[0]
    half = SSIM_WINDOW // 2
    x = F.pad(torch.from_numpy(a).permute(2, 0, 1)[None], (half, half, half, half))
    y = F.pad(torch.from_numpy(b).permute(2, 0, 1)[None], (half, half, half, half))
    total = 0.0
    with torch.no_grad():
        for r0 in range(0, h, strip_rows):
            r1 = min(h, r0 + strip_rows) + 2 * half
            total += float(image_quality.ssim_map(x[:, :, r0:r1], y[:, :, r0:r1], padding="valid").sum())
    return total / a.size


def lpips(img: np.ndarray, gt: np.ndarray, gt_reference=None, device: str = "cpu") -> float:
    """LPIPS-VGG, or NaN when the weights are not installed (logged once).

    Each image's VGG features come from a pass of their own, as the lpips package computes them (lpips 0.1.4,
    lpips/lpips.py:119, `outs0, outs1 = self.net.forward(in0_input), self.net.forward(in1_input)`): a batch of
    two changed the last bits of small images' LPIPS (32-64 px, torch 2.13's oneDNN:
    docs/results/data/evaluation-speed/arena-lpips/batch-bits.txt).
    `gt_reference` (from `lpips_reference(gt, device)`) skips recomputing the ground truth's features;
    `device` is where the network runs (cpu, cuda, cuda:N).
    """
    import strings_bench.eval.lpips_net as lpips_net

    _check_pair(img, gt)
    try:
        net = lpips_net.get_lpips(device)
    except lpips_net.LPIPSUnavailable as exc:
        _warn_lpips_once(exc)
        return math.nan
    if gt_reference is None:
        gt_reference = net.reference(np.asarray(gt, dtype=np.float32))
    return net.distance_to(np.asarray(img, dtype=np.float32), gt_reference)


def lpips_reference(gt: np.ndarray, device: str = "cpu"):
    """The ground truth's LPIPS features (on `device`), reused for every render of that view; None if unavailable."""
    import strings_bench.eval.lpips_net as lpips_net

    try:
        return lpips_net.get_lpips(device).reference(np.asarray(gt, dtype=np.float32))
    except lpips_net.LPIPSUnavailable as exc:
        _warn_lpips_once(exc)
        return None


_warned = False


def _warn_lpips_once(exc: Exception) -> None:
    global _warned
    if not _warned:
        log.warning("LPIPS is reported as n/a: %s", exc)
        _warned = True


def lpips_available() -> bool:
    import strings_bench.eval.lpips_net as lpips_net

    return lpips_net.available()


def image_metrics(img: np.ndarray, gt: np.ndarray, with_lpips: bool = True, gt_reference=None,
                  device: str = "cpu") -> dict[str, float]:
    """{"psnr", "ssim", "lpips"} of one view; lpips is NaN when `with_lpips` is False or unavailable,
    and runs on `device`."""
    out = {"psnr": psnr(img, gt), "ssim": ssim(img, gt)}
    out["lpips"] = lpips(img, gt, gt_reference, device=device) if with_lpips else math.nan
    return out


# ---- text-region metrics (inside the dilated text mask) -----------------------------------------------
LPIPS_MIN_CROP = 32  # the bounding crop is grown to at least this side (VGG16 pools it 4 times)


def _check_mask(mask: np.ndarray, shape: tuple) -> np.ndarray:
    m = np.asarray(mask).astype(bool)
    if m.shape != tuple(shape[:2]):
        raise StringsBenchError(f"text mask is {m.shape}, the image is {shape[:2]}", hint="build the mask at the evaluated size")
    return m


def masked_psnr(img: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    """PSNR in dB (data range 1) over the mask's pixels only (all 3 channels), float64; NaN for an empty mask."""
    a, b = _check_pair(img, gt)
    m = _check_mask(mask, a.shape)
    if not m.any():
        return math.nan
    mse = float(((a[m] - b[m]) ** 2).mean())
    return math.inf if mse == 0 else -10 * math.log10(mse)


def masked_ssim(img: np.ndarray, gt: np.ndarray, mask: np.ndarray, strip_rows: int = SSIM_STRIP_ROWS) -> float:
    """Masked mean of the SSIM map: the whole image's map (same convention as `ssim`, zero padding,
    float64) averaged over the mask's pixels and the 3 channels; NaN for an empty mask."""
    a, b = _check_pair(img, gt)
    m = _check_mask(mask, a.shape)
    if not m.any():
        return math.nan
    h = a.shape[0]
    half = SSIM_WINDOW // 2
    x = F.pad(torch.from_numpy(a).permute(2, 0, 1)[None], (half, half, half, half))
    y = F.pad(torch.from_numpy(b).permute(2, 0, 1)[None], (half, half, half, half))
    mt = torch.from_numpy(m)
    total = 0.0
    with torch.no_grad():
        for r0 in range(0, h, strip_rows):
            r1 = min(h, r0 + strip_rows)
            rows = mt[r0:r1]
            if not bool(rows.any()):
                continue
            smap = image_quality.ssim_map(x[:, :, r0:r1 + 2 * half], y[:, :, r0:r1 + 2 * half], padding="valid")[0]
            total += float(smap[:, rows].sum())
    return total / (3 * int(m.sum()))


def ssim_and_masked_ssim(img: np.ndarray, gt: np.ndarray, mask: np.ndarray | None,
                         strip_rows: int = SSIM_STRIP_ROWS) -> tuple[float, float]:
    """(`ssim`, `masked_ssim`) from one SSIM map: each strip of the map is computed once and summed twice,
    over all its pixels and over the mask's; the strips, and the order of the sums, are those of the two
    functions, so both values are theirs to the bit (tests/eval/test_eval_speed.py). masked_ssim is NaN for no
    mask or an empty one."""
    a, b = _check_pair(img, gt)
    m = None if mask is None else _check_mask(mask, a.shape)
    if m is not None and not m.any():
        m = None
    masked = math.nan
    if strip_rows < 1:
        raise StringsBenchError(f"strip_rows must be at least 1, not {strip_rows}", hint="use the default")
    h = a.shape[0]
    half = SSIM_WINDOW // 2
    x = F.pad(torch.from_numpy(a).permute(2, 0, 1)[None], (half, half, half, half))
    y = F.pad(torch.from_numpy(b).permute(2, 0, 1)[None], (half, half, half, half))
    mt = None if m is None else torch.from_numpy(m)
    total = masked_total = 0.0
    with torch.no_grad():
        for r0 in range(0, h, strip_rows):
            r1 = min(h, r0 + strip_rows)
            with one_torch_thread():  # the map on one thread; its sums below on the caller's, as in `ssim`
                smap = image_quality.ssim_map(x[:, :, r0:r1 + 2 * half], y[:, :, r0:r1 + 2 * half], padding="valid")
            total += float(smap.sum())
            if mt is not None:
                rows = mt[r0:r1]
                if bool(rows.any()):
                    masked_total += float(smap[0][:, rows].sum())
    if m is not None:
        masked = masked_total / (3 * int(m.sum()))
    return total / a.size, masked


def view_metrics(img: np.ndarray, gt: np.ndarray, mask: np.ndarray | None, with_lpips: bool = True,
                 gt_reference=None, device: str = "cpu", text_reference=None) -> dict[str, float]:
    """`image_metrics` and `text_region_metrics` of one view in one pass (the same keys, in the same order,
    and the same values to the bit): the images are converted once, the SSIM map is made once for
    both SSIMs (`ssim_and_masked_ssim`), and the SSIM map runs on one torch thread (`one_torch_thread`).
    `text_reference` (`text_lpips_reference`, made once per view) holds the GT text crop's LPIPS features;
    where that crop is the whole image, text_lpips is the image's LPIPS (the same two images)."""
    a, b = _check_pair(img, gt)
    out = {"psnr": image_quality.psnr(torch.from_numpy(a), torch.from_numpy(b))}
    out["ssim"], text_ssim = ssim_and_masked_ssim(a, b, mask)
    out["lpips"] = lpips(img, gt, gt_reference, device=device) if with_lpips else math.nan
    if mask is None:
        out.update({k: math.nan for k in TEXT_METRICS})
        return out
    out["text_psnr"] = masked_psnr(a, b, mask)
    out["text_ssim"] = text_ssim
    if not with_lpips:
        out["text_lpips"] = math.nan
    elif text_reference is not None and _whole_image(text_reference[0], a.shape):
        out["text_lpips"] = out["lpips"]
    else:
        out["text_lpips"] = masked_lpips(img, gt, mask, device=device, gt_reference=text_reference)
    return out


def mask_bbox(mask: np.ndarray, min_side: int = 0) -> tuple[int, int, int, int] | None:
    """(y0, y1, x0, x1) of the mask's bounding box (ends exclusive), each side grown to at least
    `min_side` (within the image); None for an empty mask."""
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return None
    ys, xs = np.nonzero(m)
    box = []
    for lo, hi, size in ((int(ys.min()), int(ys.max()) + 1, m.shape[0]), (int(xs.min()), int(xs.max()) + 1, m.shape[1])):
        want = min(size, max(hi - lo, min_side))
        lo = min(max(0, (lo + hi - want) // 2), size - want)  # centred on the mask's box, inside the image
        hi = lo + want
        box += [lo, hi]
    return box[0], box[1], box[2], box[3]


def masked_lpips(img: np.ndarray, gt: np.ndarray, mask: np.ndarray, device: str = "cpu",
                 gt_reference=None) -> float:
    """LPIPS-VGG of the mask's bounding crop (grown to >= 32 px a side); NaN for an empty mask or
    without the weights. Pixels of the crop outside the mask are kept (context, as the SSIM window).
    `gt_reference`: `text_lpips_reference(gt, mask)`, the ground truth crop's features made once."""
    _check_pair(img, gt)
    box = mask_bbox(_check_mask(mask, np.shape(img)), LPIPS_MIN_CROP)
    if box is None:
        return math.nan
    y0, y1, x0, x1 = box
    if gt_reference is not None and tuple(gt_reference[0]) != box:
        raise StringsBenchError(f"the text crop's LPIPS reference is of box {gt_reference[0]}, the mask's crop is {box}",
                                hint="make it with text_lpips_reference(gt, mask) of the same view")
    return lpips(np.asarray(img)[y0:y1, x0:x1], np.asarray(gt)[y0:y1, x0:x1],
                 gt_reference=None if gt_reference is None else gt_reference[1], device=device)


def _whole_image(box, shape) -> bool:
    """Whether a crop box (y0, y1, x0, x1) is the whole image of `shape`."""
    return tuple(box) == (0, shape[0], 0, shape[1])


def text_lpips_reference(gt: np.ndarray, mask: np.ndarray | None, device: str = "cpu", whole=None):
    """(box, features) of the ground truth's text crop (`masked_lpips`' crop), for every render of the view;
    None without a mask, for an empty one, or without the weights. `whole`: the view's `lpips_reference`,
    taken as it is where the crop is the whole image."""
    if mask is None:
        return None
    box = mask_bbox(_check_mask(mask, np.shape(gt)), LPIPS_MIN_CROP)
    if box is None:
        return None
    if whole is not None and _whole_image(box, np.shape(gt)):
        return box, whole
    y0, y1, x0, x1 = box
    ref = lpips_reference(np.asarray(gt)[y0:y1, x0:x1], device=device)
    return None if ref is None else (box, ref)


TEXT_METRICS = ("text_psnr", "text_ssim", "text_lpips")


def text_region_metrics(img: np.ndarray, gt: np.ndarray, mask: np.ndarray | None, with_lpips: bool = True,
                        device: str = "cpu") -> dict:
    """{"text_psnr", "text_ssim", "text_lpips"} inside the (dilated) text mask; NaN without a mask
    (or an empty one), and text_lpips NaN when `with_lpips` is False or the weights are absent.
    LPIPS runs on `device`."""
    if mask is None:
        return {k: math.nan for k in TEXT_METRICS}
    return {"text_psnr": masked_psnr(img, gt, mask), "text_ssim": masked_ssim(img, gt, mask),
            "text_lpips": masked_lpips(img, gt, mask, device=device) if with_lpips else math.nan}


def describe() -> dict:
    """What the metric numbers mean: stored with every result."""
    import strings_bench.eval.lpips_net as lpips_net

    vgg, lin = lpips_net.default_weight_paths()
    return {
        "psnr": "per view, data range 1, mean over test views",
        "ssim": f"3DGS convention: {SSIM_WINDOW}x{SSIM_WINDOW} Gaussian sigma {SSIM_SIGMA}, zero padding, mean over pixels",
        "lpips": {"net": "vgg", "version": "0.1", "available": vgg is not None,
                  "vgg_weights": str(vgg) if vgg else None, "lin_weights": str(lin) if lin else None},
        "text_psnr": "PSNR over the dilated text mask's pixels only, per view, mean over views with a mask",
        "text_ssim": "the SSIM map (as ssim) averaged over the dilated text mask's pixels, per view",
        "text_lpips": f"LPIPS-VGG of the text mask's bounding crop (at least {LPIPS_MIN_CROP} px a side), per view",
    }
