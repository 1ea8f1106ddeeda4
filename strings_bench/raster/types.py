"""The rasterizer's result and error types (shared by every backend)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from strings_bench.core.errors import StringsBenchError


class RasterInputError(StringsBenchError):
    """Bad tensors or settings given to rasterize()."""


@dataclass
class RasterOutput:
    """What `rasterize` returns (every backend; H, W = camera.height, camera.width; N Gaussians).

    Attributes:
        color: (H, W, 3) float, sum_i w_i c_i + (1 - alpha) * background, w_i = alpha_i T_i
            (front-to-back blending weights). Differentiable.
        alpha: (H, W) float, 1 - final transmittance (accumulated opacity). Differentiable.
        depth: (H, W) float, expected camera-space z in world units, sum_i w_i z_i / alpha; 0 where
            alpha == 0. Differentiable.
        radii: (N,) int32, screen-space radius in pixels (3 sigma of the projected Gaussian);
            0 = culled (behind the near plane, beyond far, or off the image).
        means2d: (N, 2) float, projected centres (u, v) in pixels (pixel centres at integer + 0.5),
            in the autograd graph. Call `means2d.retain_grad()` before backward to read
            dL/d(u, v) in `means2d.grad` (pixels; NDC = grad * 0.5 * [W, H]). Culled Gaussians
            hold a placeholder (0, 0) and get zero gradient.
        absgrad: (N, 2) float, or None unless `rasterize(..., compute_absgrad=True)`: written
            during backward with sum over pixels of |dL_pixel / d means2d| per component (AbsGS),
            in the same pixel units as `means2d.grad`. Read it after backward.
        visible: (N,) bool, radii > 0.
        backend: "cpu", "cpu-f64" or "gsplat": the backend that produced this output.

    Example:
        >>> import torch
        >>> from strings_bench.raster import RasterOutput
        >>> out = RasterOutput(color=torch.zeros(2, 3, 3), alpha=torch.zeros(2, 3), depth=torch.zeros(2, 3),
        ...                    radii=torch.tensor([0, 4], dtype=torch.int32), means2d=torch.zeros(2, 2),
        ...                    absgrad=None, visible=torch.tensor([False, True]), backend="cpu")
        >>> out.n_visible
        1
    """

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
        """Number of Gaussians not culled (visible.sum())."""
        return int(self.visible.sum())
