"""The densification-strategy interface (gsplat style).

A strategy is a dataclass whose fields are its settings. The trainer calls, every step:

    state = strategy.initialize_state(scene_extent, steps_scale)      # once
    kwargs = strategy.get_raster_kwargs(step)                          # extra rasterize() arguments
    out = model.render(camera, ..., **kwargs)
    info = {"raster": out, "means2d": out.means2d, "radii": out.radii, "width": W, "height": H,
            "n_cameras": 1, "view_idx": i, "camera": camera}
    strategy.step_pre_backward(model, optimizer, state, step, info)    # e.g. retain_grad on means2d
    loss = trainer.loss(...) + strategy.loss_terms(model, info, step)  # extra regularisers
    loss.backward(); optimizer.step()
    strategy.step_post_backward(model, optimizer, state, step, info)   # statistics, grow, prune, reset

Iteration numbers in settings are nominal (for a 30 000-step run); `self.at(state, n)` gives the
actual step for the run's `steps_scale`, `self.every(state, n)` the actual interval (>= 1).
Strategies change the Gaussians only through `strategies.ops`, which keeps the optimizer state,
`model.extras` and the tensors of `state` in step.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..gaussians import GaussianModel
from ..optim import GaussianAdam


def scaled_step(nominal: float, steps_scale: float) -> int:
    """A nominal iteration number in a run scaled by steps_scale (rounded)."""
    return int(round(nominal * steps_scale))


# Shortest interval (refinement, opacity reset, SH increase, relocation) in a scaled-down run.
# Scaling 3DGS's every-100-steps refinement by 0.05 would refine every 5 steps on 5 steps of
# gradient statistics, before new Gaussians settle: measured on synthetic/books, 3DGS grew from
# 2.9k to 131k Gaussians in 150 steps. Quick runs keep at least this many steps between rounds.
MIN_SCALED_INTERVAL = 50


def scaled_interval(nominal: float, steps_scale: float) -> int:
    floor = min(nominal, MIN_SCALED_INTERVAL) if steps_scale < 1 else 1
    return int(max(1, scaled_step(nominal, steps_scale), floor))


@dataclass
class Strategy:
    """Base strategy: no densification. Subclasses override what they need."""

    raster_kwargs = {}  # class attribute (not a setting); subclasses may make it a field

    def initialize_state(self, scene_extent: float, steps_scale: float = 1.0) -> dict:
        return {"scene_extent": float(scene_extent), "steps_scale": float(steps_scale)}

    def get_raster_kwargs(self, step: int) -> dict:
        return dict(getattr(self, "raster_kwargs", None) or {})

    def step_pre_backward(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
                          info: dict) -> None:
        pass

    def loss_terms(self, model: GaussianModel, info: dict, step: int) -> torch.Tensor | float:
        return 0.0

    def step_post_backward(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
                           info: dict) -> None:
        pass

    # ---- helpers ----------------------------------------------------------------------------
    @staticmethod
    def at(state: dict, nominal: float) -> int:
        return scaled_step(nominal, state.get("steps_scale", 1.0))

    @staticmethod
    def every(state: dict, nominal: float) -> int:
        return scaled_interval(nominal, state.get("steps_scale", 1.0))
