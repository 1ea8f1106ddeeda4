"""Photometric losses of training: L1, the 3DGS loss (1 - lambda) L1 + lambda (1 - SSIM), and STRinGS'
masked L1.

SSIM and PSNR are the suite's one implementation in `strings_bench.eval.image_quality` (the evaluation
scores renders with the same functions in float64); they are re-exported here for the engine's users.
"""

from __future__ import annotations

import torch

from strings_bench.eval.image_quality import SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW, psnr, ssim, ssim_map

__all__ = ["SSIM_C1", "SSIM_C2", "SSIM_SIGMA", "SSIM_WINDOW", "gs_loss", "l1_loss", "masked_l1", "psnr", "ssim",
           "ssim_map"]


def l1_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference over every element."""
    return (pred - target).abs().mean()


def gs_loss(pred: torch.Tensor, target: torch.Tensor, lambda_dssim: float = 0.2) -> torch.Tensor:
    """3DGS photometric loss: (1 - lambda) L1 + lambda (1 - SSIM)."""
    loss = l1_loss(pred, target)
    if lambda_dssim:
        loss = (1 - lambda_dssim) * loss + lambda_dssim * (1 - ssim(pred, target))
    return loss


def masked_l1(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """STRinGS phase-1 loss: L1 of (render x mask) vs (image x mask), mean over the whole image."""
    m = mask.to(pred.dtype)
    if m.ndim == pred.ndim - 1:
        m = m[..., None]
    return (pred * m - target * m).abs().mean()
