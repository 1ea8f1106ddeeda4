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

from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.optim import GaussianAdam


def scaled_step(nominal: float, steps_scale: float) -> int:
    """A nominal iteration number in a run scaled by steps_scale (rounded)."""
    return int(round(nominal * steps_scale))


# Shortest interval (refinement, opacity reset, SH increase, relocation) in a scaled-down run.
# Scaling 3DGS's every-100-steps refinement by 0.05 would refine every 5 steps on 5 steps of
# gradient statistics, before new Gaussians settle: measured on synthetic/books, 3DGS grew from
# 2.9k to 131k Gaussians in 150 steps. Quick runs keep at least this many steps between rounds.
MIN_SCALED_INTERVAL = 50

# Opacity resets need a longer floor: recovering from opacity 0.01 takes a roughly fixed number of
# Adam steps (~100-150 at the 0.05 opacity LR), not a fixed fraction of the run. Scaled by 0.02, 3DGS
# reset every 60 steps and reached 11.2 dB at its 7K checkpoint vs 16.5 dB without resets (books).
MIN_SCALED_RESET_INTERVAL = 200


def scaled_interval(nominal: float, steps_scale: float, floor: int = MIN_SCALED_INTERVAL) -> int:
    """A nominal interval in a run scaled by steps_scale: scaled, but in scaled-down runs never
    shorter than `floor` steps (nor than the nominal interval itself)."""
    lower = min(nominal, floor) if steps_scale < 1 else 1
    return int(max(1, scaled_step(nominal, steps_scale), lower))


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
    def every(state: dict, nominal: float, floor: int = MIN_SCALED_INTERVAL) -> int:
        return scaled_interval(nominal, state.get("steps_scale", 1.0), floor)

    @staticmethod
    def reset_interval(state: dict, nominal: float) -> int:
        """Opacity-reset interval (longer floor in scaled runs, see MIN_SCALED_RESET_INTERVAL)."""
        return scaled_interval(nominal, state.get("steps_scale", 1.0), MIN_SCALED_RESET_INTERVAL)
