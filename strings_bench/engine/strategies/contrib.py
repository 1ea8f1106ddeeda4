"""Per-Gaussian contributions to a render: sum over pixels of (a pixel weight x) the blending weight.

Improved-GS' edge-aware score and Perceptual-GS' "trans" statistic both read, for every Gaussian i,

    S_i = sum_p w(p) alpha_i(p) T_i(p)

(alpha_i T_i: the Gaussian's front-to-back blending weight at pixel p; w: a per-pixel weight, 1 for
Perceptual-GS, an edge map for Improved-GS). Their CUDA rasterizers add it up in the forward kernel
(an atomicAdd per pixel and Gaussian). Here it is exact without a kernel of its own: render every
Gaussian with the same grey colour c_i = 0.5 (degree-0 SH coefficient 0, so the colour max(SH_C0 k +
0.5, 0) is not clamped); the colour of pixel p is sum_i c_i alpha_i(p) T_i(p), hence

    d/dk_i sum_p w(p) C(p)[red] = SH_C0 sum_p w(p) alpha_i(p) T_i(p) = SH_C0 S_i,

with the same alpha >= 1/255 and T >= 1e-4 cut-offs as the forward pass (one render and one backward
on whatever backend trains). Gaussians not drawn get 0.
"""

from __future__ import annotations

import torch

from strings_bench.engine.gaussians import GaussianModel
from strings_bench.raster.sh import SH_C0


def blend_weight_sums(model: GaussianModel, camera, pixel_weights: torch.Tensor | None = None,
                      backend: str = "auto") -> torch.Tensor:
    """S_i = sum_p w(p) alpha_i(p) T_i(p) for every Gaussian of `model` seen from `camera` (see module docstring).

    Args:
        model: the Gaussians (their parameters are read, not changed; no gradient reaches them).
        camera: a `Camera` (the image size sets the pixels summed over).
        pixel_weights: (H, W) float weights w(p), or None for w = 1 (the blending weights' sum, in pixels).
        backend: the rasterizer backend ("auto", "cpu", "cpu-f64", "gsplat").

    Returns:
        (N,) float tensor on the model's device, >= 0.

    Example:
        >>> import numpy as np
        >>> from strings_bench.engine.gaussians import GaussianModel
        >>> from strings_bench.scene.camera import Camera
        >>> cam = Camera(fx=40.0, fy=40.0, cx=24.0, cy=16.0, width=48, height=32, R=np.eye(3), t=np.zeros(3))
        >>> model = GaussianModel.from_points([[0.0, 0.0, 2.0], [0.0, 0.0, -2.0]], [[255, 0, 0], [0, 0, 255]])
        >>> s = blend_weight_sums(model, cam, backend="cpu")
        >>> bool(s[0] > 0), float(s[1])  # the second one is behind the camera
        (True, 0.0)
    """
    from strings_bench.raster import rasterize

    p = {k: v.detach() for k, v in model.params.items()}
    n = len(model)
    grey = torch.zeros((n, 1, 3), dtype=p["sh0"].dtype, device=model.device, requires_grad=True)
    out = rasterize(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], grey, camera,
                    torch.zeros(3, dtype=p["means"].dtype, device=model.device), sh_degree=0, backend=backend)
    red = out.color[..., 0]
    if pixel_weights is not None:
        w = torch.as_tensor(pixel_weights, dtype=red.dtype, device=red.device)
        if w.shape != red.shape:
            raise ValueError(f"pixel weights have shape {tuple(w.shape)}, the render {tuple(red.shape)}")
        red = red * w
    (grad,) = torch.autograd.grad(red.sum(), grey)
    return (grad[:, 0, 0] / SH_C0).clamp_min(0.0).detach()
