"""The rasterizer's result and error types (shared by every backend)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from strings_bench.core.errors import StringsBenchError


class RasterInputError(StringsBenchError):
    """Bad tensors or settings given to rasterize()."""


@dataclass
class RasterOutput:
    color: torch.Tensor  # (H, W, 3), background composited
    alpha: torch.Tensor  # (H, W) = 1 - final transmittance
    depth: torch.Tensor  # (H, W) expected camera depth sum(w z) / alpha, 0 where alpha == 0
    radii: torch.Tensor  # (N,) int32 pixel radius, 0 = culled
    means2d: torch.Tensor  # (N, 2) pixels, in the autograd graph (retain_grad() to read .grad)
    absgrad: torch.Tensor | None  # (N, 2), filled by backward when compute_absgrad=True
    visible: torch.Tensor  # (N,) bool, radii > 0
    backend: str

    @property
    def n_visible(self) -> int:
        return int(self.visible.sum())
