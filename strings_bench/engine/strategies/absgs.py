"""AbsGS (Ye et al., ACM MM 2024; REFERENCE §4): densification on the absolute screen-space gradient.

The ordinary densification statistic is |sum_p dL_p/dmean2d|: per-pixel gradients of opposite sign
cancel, so large Gaussians over fine detail are rarely split. AbsGS also accumulates
|| sum_p |dL_p/dmean2d| || (component-wise absolute values summed over the pixels, then the norm),
which the rasterizer's backward pass computes when called with `compute_absgrad=True`
(`RasterOutput.absgrad`, pixel units). Both statistics are converted to NDC units (x W/2, x H/2) and
averaged over the steps in which the Gaussian was visible, as in 3DGS.

Clone: ordinary gradient >= `grow_grad2d` (2e-4) and largest scale <= `grow_scale3d` x extent.
Split: absolute gradient >= `grow_grad2d_abs` (4e-4) and largest scale > `grow_scale3d` x extent.
Everything else (schedule, pruning, opacity reset) is vanilla 3DGS (DefaultStrategy).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from strings_bench.core.errors import StringsBenchError, TrainingError
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.optim import GaussianAdam
import strings_bench.engine.strategies.ops as ops
from strings_bench.engine.strategies.default import DefaultStrategy


def ndc_norm(grad_px: torch.Tensor, width: int, height: int, n_cameras: int = 1) -> torch.Tensor:
    """Norm of a (N, 2) screen-space gradient in pixel units, converted to NDC units (3DGS convention)."""
    g = grad_px.detach().clone()
    g[..., 0] *= width / 2.0 * n_cameras
    g[..., 1] *= height / 2.0 * n_cameras
    return g.norm(dim=-1)


def raster_absgrad(info: dict) -> torch.Tensor:
    out = info.get("raster")
    absgrad = getattr(out, "absgrad", None)
    if absgrad is None:
        raise StringsBenchError("the rasterizer returned no absolute gradient (RasterOutput.absgrad)",
                                hint="AbsGS-style strategies need rasterize(..., compute_absgrad=True); "
                                     "make sure get_raster_kwargs is passed to the render call")
    return absgrad


@dataclass
class AbsGSStrategy(DefaultStrategy):
    grow_grad2d: float = 2e-4       # clone threshold, ordinary gradient
    grow_grad2d_abs: float = 4e-4   # split threshold, absolute gradient

    def get_raster_kwargs(self, step: int) -> dict:
        return {"compute_absgrad": True}

    def initialize_state(self, scene_extent: float, steps_scale: float = 1.0) -> dict:
        state = super().initialize_state(scene_extent, steps_scale)
        state["grad2d_abs"] = None
        return state

    @torch.no_grad()
    def update_state(self, model: GaussianModel, state: dict, info: dict) -> None:
        super().update_state(model, state, info)  # ordinary gradient, counts, radii
        n = len(model)
        if state.get("grad2d_abs") is None or state["grad2d_abs"].shape[0] != n:
            state["grad2d_abs"] = torch.zeros(n, device=model.device)
        if info["means2d"].grad is None:  # no backward through this render
            return
        absgrad = raster_absgrad(info)
        visible = torch.as_tensor(info["radii"], device=model.device) > 0
        norms = ndc_norm(absgrad, info["width"], info["height"], info.get("n_cameras", 1))
        state["grad2d_abs"][visible] += norms[visible]

    def mean_grads(self, state: dict) -> tuple[torch.Tensor, torch.Tensor]:
        count = state["count"].clamp_min(1)
        return state["grad2d"] / count, state["grad2d_abs"] / count

    def select(self, model: GaussianModel, state: dict, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(clone mask, split mask)."""
        grads, grads_abs = self.mean_grads(state)
        is_small = model.scales.max(dim=-1).values <= self.grow_scale3d * state["scene_extent"]
        return (grads >= self.grow_grad2d) & is_small, (grads_abs >= self.grow_grad2d_abs) & ~is_small

    def grow(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
             clone: torch.Tensor, split: torch.Tensor) -> None:
        ops.duplicate(model, optimizer, clone, state=state)
        split = torch.cat([split, torch.zeros(int(clone.sum()), dtype=torch.bool, device=model.device)])
        ops.split(model, optimizer, split, n_children=self.n_split, state=state)

    def prune_mask(self, model: GaussianModel, state: dict, step: int) -> torch.Tensor:
        prune = model.opacities < self.prune_opa
        if step > self.at(state, self.screen_prune_after):
            prune |= model.scales.max(dim=-1).values > self.prune_scale3d * state["scene_extent"]
            if state.get("max_radii") is not None:
                prune |= state["max_radii"] > self.prune_screen_px
        return prune

    @torch.no_grad()
    def refine(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int) -> None:
        if state.get("grad2d") is not None and state.get("grad2d_abs") is not None:
            clone, split = self.select(model, state, step)
            n_new = int(clone.sum()) + int(split.sum()) * (self.n_split - 1)
            if len(model) + n_new > self.max_gaussians:
                raise TrainingError(f"densification at step {step} would make {len(model) + n_new} Gaussians "
                                    f"(more than max_gaussians={self.max_gaussians})",
                                    hint="raise max_gaussians or the gradient thresholds")
            self.grow(model, optimizer, state, step, clone, split)
            state["last_clone"], state["last_split"] = int(clone.sum()), int(split.sum())
        prune = self.prune_mask(model, state, step)
        if prune.all():
            raise TrainingError(f"pruning at step {step} would remove every Gaussian",
                                hint="training diverged or the scene is empty; check the input images and poses")
        ops.remove(model, optimizer, prune, state=state)
        state["last_prune"] = int(prune.sum())
        state["n_refine"] += 1
        state["grad2d"] = state["count"] = state["max_radii"] = state["grad2d_abs"] = None
