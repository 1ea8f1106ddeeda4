"""Image metrics of a render against its ground truth: PSNR, SSIM and LPIPS-VGG.

Conventions follow the 3DGS evaluation script the paper's numbers come from:
- images are float RGB in [0, 1], compared at the resolution the method was trained at;
- PSNR = -10 log10(MSE) with a data range of 1, per image; a scene's value is the mean over views;
- SSIM: 11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, per channel, the window applied
  with zero padding ("same" output size) and the map averaged over every pixel and channel (the
  3DGS `ssim` function). skimage's `structural_similarity(gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False)` computes the same map in the interior; it differs only at borders
  (reflect padding, cropped mean), which is why the tests compare the interior;
- LPIPS: VGG, v0.1 linear layers, inputs scaled to [-1, 1] (see lpips_net.py). NaN when the
  weights are not installed (tables then show "n/a", never 0).
"""

from __future__ import annotations

import logging
import math

import numpy as np
from scipy.ndimage import correlate1d

from strings_bench.core.errors import StringsBenchError

log = logging.getLogger(__name__)

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def _check_pair(img: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(img, dtype=np.float64)
    b = np.asarray(gt, dtype=np.float64)
    if a.shape != b.shape:
        raise StringsBenchError(f"render is {a.shape} but the ground truth is {b.shape}",
                                hint="the method must render test views at the scene's size for the chosen downscale")
    if a.ndim != 3 or a.shape[2] != 3:
        raise StringsBenchError(f"expected HxWx3 images, got shape {a.shape}", hint="pass RGB images")
    return a, b


def psnr(img: np.ndarray, gt: np.ndarray) -> float:
    a, b = _check_pair(img, gt)
    mse = float(np.mean((a - b) ** 2))
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def gaussian_window_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def _filter(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    # Separable Gaussian, zero padding, same-size output: conv2d(padding=5) of 3DGS.
    y = correlate1d(x, w, axis=0, mode="constant", cval=0.0)
    return correlate1d(y, w, axis=1, mode="constant", cval=0.0)


def ssim_map(img: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-pixel, per-channel SSIM (H, W, 3) in float64, 3DGS convention."""
    a, b = _check_pair(img, gt)
    w = gaussian_window_1d()
    out = np.empty_like(a)
    for c in range(3):
        x, y = a[..., c], b[..., c]
        mu_x, mu_y = _filter(x, w), _filter(y, w)
        sxx = _filter(x * x, w) - mu_x**2
        syy = _filter(y * y, w) - mu_y**2
        sxy = _filter(x * y, w) - mu_x * mu_y
        out[..., c] = ((2 * mu_x * mu_y + SSIM_C1) * (2 * sxy + SSIM_C2)) / (
            (mu_x**2 + mu_y**2 + SSIM_C1) * (sxx + syy + SSIM_C2))
    return out


def ssim(img: np.ndarray, gt: np.ndarray) -> float:
    return float(ssim_map(img, gt).mean())


def lpips(img: np.ndarray, gt: np.ndarray, gt_reference=None, device: str = "cpu") -> float:
    """LPIPS-VGG, or NaN when the weights are not installed (logged once).

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
    if gt_reference is not None:
        return net.distance_to(np.asarray(img, dtype=np.float32), gt_reference)
    return float(net(np.asarray(img, dtype=np.float32), np.asarray(gt, dtype=np.float32)))


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
    """PSNR, SSIM and (unless with_lpips is False: NaN) LPIPS of `img` against `gt`; LPIPS runs on `device`."""
    out = {"psnr": psnr(img, gt), "ssim": ssim(img, gt)}
    out["lpips"] = lpips(img, gt, gt_reference, device=device) if with_lpips else math.nan
    return out


def describe() -> dict:
    """What the metric numbers mean: stored with every result."""
    import strings_bench.eval.lpips_net as lpips_net

    vgg, lin = lpips_net.default_weight_paths()
    return {
        "psnr": "per view, data range 1, mean over test views",
        "ssim": f"3DGS convention: {SSIM_WINDOW}x{SSIM_WINDOW} Gaussian sigma {SSIM_SIGMA}, zero padding, mean over pixels",
        "lpips": {"net": "vgg", "version": "0.1", "available": vgg is not None,
                  "vgg_weights": str(vgg) if vgg else None, "lin_weights": str(lin) if lin else None},
    }
