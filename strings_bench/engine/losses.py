"""Photometric losses of training: L1, the 3DGS loss (1 - lambda) L1 + lambda (1 - SSIM), and STRinGS'
masked L1.

SSIM and PSNR are the suite's one implementation in `strings_bench.eval.image_quality` (the evaluation
scores renders with the same functions in float64); they are re-exported here for the engine's users.
"""

from __future__ import annotations

import os

import torch

from strings_bench.eval.image_quality import SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW, psnr, ssim, ssim_map

__all__ = ["SSIM_C1", "SSIM_C2", "SSIM_SIGMA", "SSIM_WINDOW", "gs_loss", "l1_loss", "masked_l1", "psnr", "ssim",
           "ssim_map"]


# The CPU loss by numba (`engine.loss_kernels`): ~5x faster than torch's convolutions here and the same
# on any CPU; STRINGS_BENCH_TORCH_LOSS=1 computes it with torch's operations (the GPU always does).
FUSED_CPU_LOSS = os.environ.get("STRINGS_BENCH_TORCH_LOSS", "0") in ("", "0")


def l1_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference over every element."""
    return (pred - target).abs().mean()


class _FusedCpuGsLoss(torch.autograd.Function):
    """`gs_loss` of a float32 (H, W, C) CPU render by the numba kernels of `engine.loss_kernels` (one pass
    each way, the same order at any thread count and on any CPU); the target gets no gradient."""

    @staticmethod
    def forward(ctx, pred, target, lambda_dssim):
        from strings_bench.engine.loss_kernels import gs_loss_forward

        x = pred.detach().contiguous().numpy()
        y = target.detach().to(torch.float32).contiguous().numpy()
        loss, _, partial = gs_loss_forward(x, y, float(lambda_dssim), pred.requires_grad)
        ctx.saved = (x, y, partial, float(lambda_dssim))
        return torch.tensor(loss, dtype=torch.float32, device="cpu")  # (a caller's default device, e.g. meta, must not reach it)

    @staticmethod
    def backward(ctx, grad_out):
        from strings_bench.engine.loss_kernels import gs_loss_backward

        x, y, partial, lam = ctx.saved
        return torch.from_numpy(gs_loss_backward(x, y, partial, lam, float(grad_out))), None, None


def fused_cpu_loss_applies(pred: torch.Tensor, target: torch.Tensor) -> bool:
    """True where `gs_loss` runs the numba kernels: float32 (H, W, C) renders on the CPU, a target of the
    same shape on the CPU, and STRINGS_BENCH_TORCH_LOSS unset (=1: torch's operations instead)."""
    return (FUSED_CPU_LOSS and pred.device.type == "cpu" and target.device.type == "cpu"
            and pred.dtype == torch.float32 and pred.ndim == 3 and pred.shape == target.shape)


def gs_loss(pred: torch.Tensor, target: torch.Tensor, lambda_dssim: float = 0.2) -> torch.Tensor:
    """3DGS photometric loss: (1 - lambda) L1 + lambda (1 - SSIM)."""
    if fused_cpu_loss_applies(pred, target):
        return _FusedCpuGsLoss.apply(pred, target, lambda_dssim)
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
