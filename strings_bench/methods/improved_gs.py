"""Improved-GS (Deng et al., arXiv 2508.12313, 2025; the EDC authors' successor) on the suite's engine:
edge-aware score, growth control to a Gaussian budget, long-axis split, recovery-aware pruning
(engine/strategies/improved.py) and the multi-step update (here: `MultiStepAdam`); docs/baselines.md.

Learning rates of the release (arguments/__init__.py; the spec's defaults): position 4e-5 -> 2e-6
(x extent), opacity 0.025, higher SH orders 0.005 / 20 = 2.5e-4; the others as 3DGS.

Settings: as 3dgs, plus ImprovedGSStrategy fields (budget, budget_multiple,
grow_grad2d_abs, score_views, split_distance, opacity_reduction, reset_value, recovery_*, ...) and
ImprovedGSSettings (multi_step_update and its intervals).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.optim import GaussianAdam
from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.engine.strategies.improved import ImprovedGSStrategy, edge_map


@dataclass(frozen=True)
class ImprovedGSSettings:
    multi_step_update: bool = True  # after multi_step_from, one optimizer step per several iterations (summed gradients)
    multi_step_from: int = 15_000  # every iteration steps up to this one (nominal)
    multi_step_mid_every: int = 5  # then one step per this many iterations ...
    multi_step_late_from: int = 22_500  # ... until this one (nominal),
    multi_step_late_every: int = 20  # then one step per this many iterations

    def __post_init__(self):
        if self.multi_step_mid_every < 1 or self.multi_step_late_every < 1:
            raise StringsBenchError("improved-gs multi_step_*_every must be >= 1")


class MultiStepAdam(GaussianAdam):
    """`GaussianAdam` that, where `interval()` says k > 1, adds each iteration's gradients to a pending
    sum and takes one Adam step on that sum at iterations divisible by k (the release's train.py calls
    optimizer.step() and zero_grad() only then, so the gradients of the iterations between add up)."""

    def __init__(self, params, lrs, interval, **kw):
        super().__init__(params, lrs, **kw)
        self.interval = interval  # () -> (iteration, k)
        self.pending: dict[str, torch.Tensor] = {}

    @torch.no_grad()
    def step(self, row_scale=None) -> None:
        iteration, k = self.interval()
        if k <= 1 and not self.pending:
            return super().step(row_scale)
        for name, p in self.params.items():
            if p.grad is None:
                continue
            held = self.pending.get(name)
            self.pending[name] = p.grad.clone() if held is None or held.shape != p.grad.shape else held + p.grad
        if k > 1 and iteration % k:
            return
        for name, p in self.params.items():
            if name in self.pending:
                p.grad = self.pending.pop(name)
        self.pending.clear()
        super().step(row_scale)

    def state_dict(self) -> dict:
        out = super().state_dict()
        out["pending"] = {k: v.clone() for k, v in self.pending.items()}
        return out

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.pending = {k: v.to(self.params[k].device).clone() for k, v in (state.get("pending") or {}).items()
                        if k in self.params and v.shape == self.params[k].shape}


class ImprovedGS(GaussianSplatting):
    """Improved-GS: the edge maps of the training views are made in `prepare` and attached to the strategy."""

    strategy_cls = ImprovedGSStrategy
    method_settings_cls = ImprovedGSSettings

    def prepare(self, scene) -> None:
        views = self.train_views()
        cameras = {v: self.camera(v) for v in views}
        edges = {v: edge_map(self.target(v).cpu().numpy()) for v in views}
        self.strategy.attach_views(cameras, edges, backend=self.config.backend)

    def update_interval(self) -> tuple[int, int]:
        """(this iteration, k): one optimizer step per k iterations (1 before multi_step_from)."""
        s = self.method_settings
        if not s.multi_step_update or self.step <= self.at(s.multi_step_from):
            return self.step, 1
        if self.step <= self.at(s.multi_step_late_from):
            return self.step, self.every(s.multi_step_mid_every)
        return self.step, self.every(s.multi_step_late_every)

    def make_optimizer(self, model) -> GaussianAdam:
        return MultiStepAdam(model.params, self.config.lrs.group_lrs(self.extent), self.update_interval)
