"""Mip-Splatting (Yu et al., CVPR 2024; docs/sources.md §4): the 3D smoothing filter and the 2D mip filter.

3D smoothing filter. For each Gaussian, d = the smallest depth z at which a training camera sees its
centre (z > `near` and the projection inside the image enlarged by `frustum_margin` on each side, the
"tangent space" test of the public implementation); f = the largest focal length (fx) over all the
training cameras (docs/sources.md §4: "the largest focal length"; the public code also takes the maximum over
every training camera, seen or not). Then

    sigma = d / f * sqrt(0.2)

and the Gaussian is rendered with variances s^2 + sigma^2 on its three axes and opacity
o * sqrt(prod s^2 / prod(s^2 + sigma^2)). Gaussians no camera sees get the largest d of the seen ones
(as the public code). sigma is stored per Gaussian in `model.extras["mip_filter3d"]`, so clones and
splits inherit their parent's value until the next recomputation, which happens after every
densification step and every `filter_every` steps after densification ends.

The filter is applied differentiably in torch before rasterisation (`filtered_params`), so gradients
reach the raw scales and opacities. `fold_3d_filter(model)` bakes it into a plain GaussianModel for
PLY export. The 2D mip filter (Sigma_2D + 0.1 I with opacity x sqrt(det ratio), replacing the +0.3 px
dilation) lives in the rasterizer: `mip_filter=True`.

Opacity reset (public code): the *filtered* opacity is capped at `reset_value` and the raw opacity set
so that the filtered one equals it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.optim import GaussianAdam
from strings_bench.engine.strategies.default import DefaultStrategy

FILTER_KEY = "mip_filter3d"
SIGMA_SCALE = math.sqrt(0.2)


@torch.no_grad()
def filter_sigma(means: torch.Tensor, cameras: Sequence, near: float = 0.2, frustum_margin: float = 0.15,
                 sigma_scale: float = SIGMA_SCALE) -> torch.Tensor:
    """Per-Gaussian 3D filter standard deviation (N,) from the training cameras (see module docstring)."""
    if not cameras:
        raise StringsBenchError("the Mip-Splatting 3D filter needs at least one training camera",
                                hint="the scene has no training views; check its split")
    xyz = means.detach().to(torch.float64)
    n = xyz.shape[0]
    depth = torch.full((n,), math.inf, dtype=torch.float64, device=xyz.device)
    focal = 0.0
    for cam in cameras:
        R = torch.as_tensor(np.asarray(cam.R), dtype=torch.float64, device=xyz.device)
        t = torch.as_tensor(np.asarray(cam.t), dtype=torch.float64, device=xyz.device)
        pc = xyz @ R.T + t
        z = pc[:, 2]
        zc = z.clamp_min(1e-3)
        u = cam.fx * pc[:, 0] / zc + cam.cx
        v = cam.fy * pc[:, 1] / zc + cam.cy
        mw, mh = frustum_margin * cam.width, frustum_margin * cam.height
        seen = (z > near) & (u >= -mw) & (u <= cam.width + mw) & (v >= -mh) & (v <= cam.height + mh)
        depth = torch.where(seen, torch.minimum(depth, z), depth)
        focal = max(focal, float(cam.fx))
    seen_any = torch.isfinite(depth)
    if seen_any.any():
        depth[~seen_any] = depth[seen_any].max()
    else:  # no Gaussian in any frustum: nothing to band-limit against
        depth.zero_()
    return (depth / focal * sigma_scale).to(means.dtype)


def filtered_params(log_scales: torch.Tensor, opacity_logits: torch.Tensor,
                    sigma: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(log-scales, opacity logits) of the Gaussians after the 3D filter, differentiable.

    scale' = sqrt(s^2 + sigma^2); opacity' = o * c with c = sqrt(prod s^2 / prod(s^2 + sigma^2)).
    Computed in log space so that o close to 1 or c close to 1 stays finite:
    log c = -1/2 sum log1p(sigma^2 / s^2);  logit(o c) = log(o c) - log(1 - o c) with
    1 - o c = sigmoid(-l) + sigmoid(l) (1 - c).
    """
    var_ratio = (sigma[:, None] ** 2) * torch.exp(-2.0 * log_scales)        # sigma^2 / s^2
    log1p_ratio = torch.log1p(var_ratio)
    new_log_scales = log_scales + 0.5 * log1p_ratio
    log_c = -0.5 * log1p_ratio.sum(dim=1)
    one_minus_c = -torch.expm1(log_c)
    log_p = torch.nn.functional.logsigmoid(opacity_logits) + log_c
    log_1mp = torch.log(torch.sigmoid(-opacity_logits) + torch.sigmoid(opacity_logits) * one_minus_c)
    return new_log_scales, log_p - log_1mp


def model_sigma(model: GaussianModel) -> torch.Tensor:
    """The model's (N,) 3D filter sigma, in world units (`extras["mip_filter3d"]`); a clear error without one."""
    if FILTER_KEY not in model.extras:
        raise StringsBenchError("this model has no Mip-Splatting 3D filter (extras['mip_filter3d'])",
                                hint="compute it with strategies.mip.update_filter(model, cameras)")
    return model.extras[FILTER_KEY]


@torch.no_grad()
def update_filter(model: GaussianModel, cameras: Sequence, near: float = 0.2, frustum_margin: float = 0.15,
                  sigma_scale: float = SIGMA_SCALE) -> None:
    """Recompute the model's (N,) 3D filter sigma from the training `cameras` (`filter_sigma`) into
    `model.extras["mip_filter3d"]`."""
    model.extras[FILTER_KEY] = filter_sigma(model.means, cameras, near, frustum_margin, sigma_scale)


def render_filtered(model: GaussianModel, camera, background=(0.0, 0.0, 0.0), sh_degree: int | None = None,
                    **raster_kwargs):
    """GaussianModel.render with the 3D filter applied to scales and opacities first."""
    from strings_bench.raster import rasterize

    degree = model.sh_degree if sh_degree is None else min(int(sh_degree), model.sh_degree)
    bg = torch.as_tensor(background, dtype=torch.float32, device=model.device)
    log_scales, logits = filtered_params(model.params["log_scales"], model.params["opacity_logits"],
                                         model_sigma(model))
    return rasterize(model.params["means"], model.params["quats"], log_scales, logits, model.sh, camera, bg,
                     sh_degree=degree, **raster_kwargs)


@torch.no_grad()
def fold_3d_filter(model: GaussianModel) -> GaussianModel:
    """A plain GaussianModel whose scales and opacities have the 3D filter baked in (exportable PLY);
    the filter itself is dropped from the extras."""
    log_scales, logits = filtered_params(model.params["log_scales"], model.params["opacity_logits"],
                                         model_sigma(model))
    params = {k: v.detach().clone() for k, v in model.params.items()}
    params["log_scales"] = log_scales.detach().clone()
    params["opacity_logits"] = logits.detach().clone()
    extras = {k: v.clone() for k, v in model.extras.items() if k != FILTER_KEY}
    return GaussianModel(params, extras=extras, sh_degree=model.sh_degree)


@torch.no_grad()
def reset_filtered_opacity(model: GaussianModel, optimizer: GaussianAdam | None, value: float = 0.01) -> None:
    """Cap the filtered opacity o*c at `value` by lowering the raw opacity; zero the opacity moments."""
    sigma = model_sigma(model)
    _, eff_logits = filtered_params(model.params["log_scales"], model.params["opacity_logits"], sigma)
    cap = math.log(value / (1 - value))
    over = eff_logits > cap
    # raw opacity o' with o' c = value:  o' = value / c
    log_c = -0.5 * torch.log1p((sigma[:, None] ** 2) * torch.exp(-2.0 * model.params["log_scales"])).sum(dim=1)
    raw = (value * torch.exp(-log_c)).clamp(max=1 - 1e-6)
    new_logits = torch.where(over, torch.log(raw) - torch.log1p(-raw), model.params["opacity_logits"])
    model.params["opacity_logits"].data.copy_(new_logits)
    if optimizer is not None:
        st = optimizer.state["opacity_logits"]
        st["exp_avg"].zero_()
        st["exp_avg_sq"].zero_()


@dataclass
class MipStrategy(DefaultStrategy):
    """Vanilla 3DGS densification plus the 3D filter's upkeep and the 2D mip filter.

    The training cameras come through `initialize_state(..., cameras)` and are kept in the state
    (`state["train_cameras"]`); the method (`methods.mip_splatting.MipSplatting`) renders through
    `render_filtered`.
    """

    mip_2d: bool = True           # the rasterizer's 2D mip filter instead of the +0.3 px dilation
    filter_every: int = 100       # recomputation interval after densification stops
    near: float = 0.2             # world units, as the public code
    frustum_margin: float = 0.15  # fraction of the image size added on each side
    sigma_scale: float = SIGMA_SCALE  # 3D filter variance factor (sqrt(0.2) in the paper)
    def get_raster_kwargs(self, step: int) -> dict:
        """{"mip_filter": True} with `mip_2d` (the rasterizer's 2D mip filter), else {}."""
        return {"mip_filter": True} if self.mip_2d else {}

    def initialize_state(self, scene_extent: float, cameras=None) -> dict:
        """`DefaultStrategy.initialize_state` plus train_cameras, the training cameras the 3D filter is computed from."""
        state = super().initialize_state(scene_extent, cameras)
        state["train_cameras"] = list(cameras or [])
        return state

    def update_filter(self, model: GaussianModel, state: dict) -> None:
        """`update_filter` over the state's training cameras, with this strategy's near plane, margin and scale."""
        cams = state.get("train_cameras")
        if not cams:
            raise StringsBenchError("MipStrategy has no training cameras in its state",
                                    hint="pass the training cameras to initialize_state (GaussianSplatting.set_model does)")
        update_filter(model, cams, self.near, self.frustum_margin, self.sigma_scale)

    def step_post_backward(self, model, optimizer, state, step, info) -> None:
        """3DGS' refinement until `refine_stop_iter`; after it the 3D filter is recomputed every `filter_every` steps."""
        if step >= self.at(self.refine_stop_iter):  # after densification: the 3D filter's upkeep only
            if step % self.every(self.filter_every) == 0:
                self.update_filter(model, state)
            return
        super().step_post_backward(model, optimizer, state, step, info)

    @torch.no_grad()
    def densify(self, model, optimizer, state, step) -> None:
        """A 3DGS round, then the 3D filter recomputed (new Gaussians need theirs)."""
        super().densify(model, optimizer, state, step)
        self.update_filter(model, state)  # at every densification step (docs/sources.md §4)

    def _reset_opacity(self, model, optimizer, state) -> None:
        reset_filtered_opacity(model, optimizer, self.reset_value)  # the filtered opacity is what is reset
