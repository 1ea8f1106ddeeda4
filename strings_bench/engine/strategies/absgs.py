"""AbsGS (Ye et al., ACM MM 2024; docs/sources.md §4): densification on the absolute screen-space gradient.

The ordinary densification statistic is |sum_p dL_p/dmean2d|: per-pixel gradients of opposite sign
cancel, so large Gaussians over fine detail are rarely split. AbsGS also accumulates
|| sum_p |dL_p/dmean2d| || (component-wise absolute values summed over the pixels, then the norm),
which the rasterizer's backward pass computes when called with `compute_absgrad=True`
(`RasterOutput.absgrad`, pixel units). Both statistics are converted to NDC units (x W/2, x H/2) and
averaged over the steps in which the Gaussian was visible, as in 3DGS.

Clone: ordinary gradient >= `grow_grad2d` (2e-4) and largest scale <= `grow_scale3d` x extent.
Split: absolute gradient >= `grow_grad2d_abs` (4e-4) and largest scale > `grow_scale3d` x extent.
Everything else (schedule, pruning, opacity reset) is vanilla 3DGS (DefaultStrategy).
With a Gaussian budget (run --budget), candidates grow in order of their statistic over its threshold (`_grow_scores`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.strategies.default import DefaultStrategy, ndc_norm  # noqa: F401 (ndc_norm: public here too)


def raster_absgrad(info: dict) -> torch.Tensor:
    """The step's (N, 2) absolute screen-space gradient in pixels, after backward (`info["raster"].absgrad`); a clear
    error when the render was not asked for it (`get_raster_kwargs`)."""
    out = info.get("raster")
    absgrad = getattr(out, "absgrad", None)
    if absgrad is None:
        raise StringsBenchError("the rasterizer returned no absolute gradient (RasterOutput.absgrad)",
                                hint="AbsGS-style strategies need rasterize(..., compute_absgrad=True); "
                                     "make sure get_raster_kwargs is passed to the render call")
    return absgrad


@dataclass
class AbsGSStrategy(DefaultStrategy):
    """AbsGS: 3DGS densification that clones on the ordinary screen-space gradient and splits on the absolute one
    (the module docstring). State: `DefaultStrategy`'s plus grad2d_abs, (N,) float or None, the sum
    over steps of the absolute-gradient norm (NDC)."""
    grow_grad2d: float = 2e-4       # clone threshold, ordinary gradient
    grow_grad2d_abs: float = 4e-4   # split threshold, absolute gradient

    def get_raster_kwargs(self, step: int) -> dict:
        """{"compute_absgrad": True} at every step: the rasterizer's absolute gradient feeds `_update_state`."""
        return {"compute_absgrad": True}

    def initialize_state(self, scene_extent: float, cameras=None) -> dict:
        """`DefaultStrategy.initialize_state` plus grad2d_abs = None (made at the first step)."""
        state = super().initialize_state(scene_extent, cameras)
        state["grad2d_abs"] = None
        return state

    @torch.no_grad()
    def _update_state(self, model: GaussianModel, state: dict, info: dict) -> None:
        super()._update_state(model, state, info)  # ordinary gradient, counts, radii
        n = len(model)
        if state.get("grad2d_abs") is None or state["grad2d_abs"].shape[0] != n:
            state["grad2d_abs"] = torch.zeros(n, device=model.device)
        if info["means2d"].grad is None:  # no backward through this render
            return
        absgrad = raster_absgrad(info)
        visible = torch.as_tensor(info["radii"], device=model.device) > 0
        norms = ndc_norm(absgrad, info["width"], info["height"], info.get("n_cameras", 1))
        state["grad2d_abs"][visible] += norms[visible]

    def _has_statistics(self, state: dict) -> bool:
        return state.get("grad2d") is not None and state.get("grad2d_abs") is not None

    def _clear_statistics(self, state: dict) -> None:
        super()._clear_statistics(state)
        state["grad2d_abs"] = None

    def mean_grads(self, state: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean ordinary gradient, mean absolute gradient) over the steps each Gaussian was visible (NDC)."""
        count = state["count"].clamp_min(1)
        return state["grad2d"] / count, state["grad2d_abs"] / count

    def _grow_scores(self, model: GaussianModel, state: dict, step: int) -> torch.Tensor:
        """Budget ranking: each candidate's selection statistic over its threshold (small Gaussians: the ordinary
        gradient / grow_grad2d, large ones: the absolute gradient / grow_grad2d_abs), so clones and splits
        compete on how far past their own threshold they are."""
        grads, grads_abs = self.mean_grads(state)
        is_small = model.scales.max(dim=-1).values <= self.grow_scale3d * state["scene_extent"]
        return torch.where(is_small, grads / self.grow_grad2d, grads_abs / self.grow_grad2d_abs)

    def _select(self, model: GaussianModel, state: dict, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(clone mask, split mask): clone on the ordinary gradient, split on the absolute one."""
        grads, grads_abs = self.mean_grads(state)
        is_small = model.scales.max(dim=-1).values <= self.grow_scale3d * state["scene_extent"]
        return (grads >= self.grow_grad2d) & is_small, (grads_abs >= self.grow_grad2d_abs) & ~is_small
