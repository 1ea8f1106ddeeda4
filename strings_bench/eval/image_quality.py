"""Image-quality measures: a differentiable SSIM (3DGS: 11x11 Gaussian window, sigma 1.5) and PSNR.

This module holds the suite's only SSIM and PSNR. `strings_bench.eval.metrics` calls them on float64
tensors to score renders; training uses the same functions as loss terms (float32, with autograd)
through `strings_bench.engine.losses`, which imports them from here: the engine sits above eval in the
layers (docs/architecture.md), so both share one implementation without an upward import. This module
imports only torch.

Images are (H, W, C) or (B, C, H, W) tensors in [0, 1]. SSIM borders:
- padding="same" (training default, as 3DGS, and the evaluation convention): the local statistics are
  computed with the window zero-padded at the border, giving an SSIM map the size of the image; its
  mean is the loss term and the reported metric.
- padding="valid": only positions where the whole window fits; the mean over those positions equals
  skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
  data_range=1), which crops the same 5-pixel border (tests/engine/test_losses.py checks this).
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
import torch.nn.functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


@lru_cache(maxsize=8)
def _gaussian_1d(size: int, sigma: float, dtype: torch.dtype, device: str) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float64, device="cpu") - (size - 1) / 2  # built on the CPU, then moved
    g = torch.exp(-(x ** 2) / (2 * sigma ** 2))
    return (g / g.sum()).to(dtype=dtype, device=device)


def _to_bchw(img: torch.Tensor) -> torch.Tensor:
    if img.ndim == 3:  # (H, W, C)
        return img.permute(2, 0, 1)[None]
    if img.ndim == 4:
        return img
    if img.ndim == 2:
        return img[None, None]
    raise ValueError(f"expected an (H, W, C) or (B, C, H, W) image, got shape {tuple(img.shape)}")


def _filter(x: torch.Tensor, g: torch.Tensor, pad: int) -> torch.Tensor:
    """Separable Gaussian filter per channel (depthwise), zero padding `pad`."""
    c = x.shape[1]
    k = g.numel()
    x = F.conv2d(x, g.view(1, 1, k, 1).expand(c, 1, k, 1), padding=(pad, 0), groups=c)
    return F.conv2d(x, g.view(1, 1, 1, k).expand(c, 1, 1, k), padding=(0, pad), groups=c)


def ssim_map(img1: torch.Tensor, img2: torch.Tensor, window: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA,
             padding: str = "same", c1: float = SSIM_C1, c2: float = SSIM_C2) -> torch.Tensor:
    """Per-pixel, per-channel SSIM map, computed in the inputs' dtype and device.

    img1, img2: (H, W, C), (B, C, H, W) or (H, W) tensors of the same shape, values in [0, 1].
    padding: "same" (zero padding, output (B, C, H, W)) or "valid" (output (B, C, H - window + 1,
    W - window + 1)). Differentiable in both images.
    """
    x, y = _to_bchw(img1), _to_bchw(img2)
    if x.shape != y.shape:
        raise ValueError(f"SSIM of images with different shapes {tuple(x.shape)} and {tuple(y.shape)}")
    if padding not in ("same", "valid"):
        raise ValueError(f"padding must be 'same' or 'valid', not {padding!r}")
    pad = window // 2 if padding == "same" else 0
    g = _gaussian_1d(window, float(sigma), x.dtype, str(x.device))
    c = x.shape[1]
    # One depthwise filter pass over all five statistics (fewer, larger convolutions are faster).
    stats = _filter(torch.cat([x, y, x * x, y * y, x * y], dim=1), g, pad)
    mu_x, mu_y, exx, eyy, exy = stats.split(c, dim=1)
    sxx = exx - mu_x * mu_x
    syy = eyy - mu_y * mu_y
    sxy = exy - mu_x * mu_y
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (sxx + syy + c2)
    return num / den


def ssim(img1: torch.Tensor, img2: torch.Tensor, padding: str = "same", **kw) -> torch.Tensor:
    """Mean of `ssim_map` over every pixel and channel (a 0-d tensor); `kw` goes to `ssim_map`."""
    return ssim_map(img1, img2, padding=padding, **kw).mean()


def psnr(pred: torch.Tensor, target: torch.Tensor) -> float:
    """PSNR in dB for a data range of 1: -10 log10(MSE), the MSE in the inputs' dtype; inf when equal."""
    mse = float(((pred - target) ** 2).mean())
    return float("inf") if mse == 0 else -10 * math.log10(mse)
