"""EDC on AbsGS ("EDC-AbsGS", Deng et al. 2025, the implementation the STRinGS paper used;
docs/sources.md §4).

Differences from AbsGS:
- selection on the absolute gradient alone (>= `grow_grad2d_abs`, 3.5e-4), whatever the size: no
  cloning; every selected Gaussian is replaced by a long-axis split;
- long-axis split: 2 children at mean +- `split_offset` (1.5) x s_max along the Gaussian's longest
  axis (R e_long), with scale s_max / 2 on that axis and x `other_axes_factor` (0.85) on the others,
  and opacity x `opacity_factor` (0.6) applied to the activated opacity; rotation and colour copied;
- recovery-aware pruning: `recovery_delay` (300) iterations after each opacity reset (while
  densifying), prune opacity < `recovery_prune_opa` (0.05); in scaled (quick) schedules the delay is
  at least `recovery_min_steps` (100) actual steps, see the field's comment;
- no screen-size pruning (the public code prunes only on opacity and, after 3 000 iterations, on
  world size > 0.1 x extent);
- position learning rate 4e-5 -> 2e-6 (set in methods/edc_absgs.py).

`release_schedule=True` adds what the public code does beyond the above: the threshold is x2 before
iteration 3 500, x1.5 until 6 500, x1.2 until 9 500; the mean gradient is multiplied by
(1 + 0.3 count / 100) (count = visible steps since the last densification); and Gaussians with
opacity < 0.02 are pruned once at iteration 300.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from strings_bench.engine.gaussians import GaussianModel, quat_to_rotmat
from strings_bench.engine.optim import GaussianAdam
import strings_bench.engine.strategies.ops as ops
from strings_bench.engine.strategies.absgs import AbsGSStrategy


@torch.no_grad()
def long_axis_split_params(params: dict[str, torch.Tensor], parents: torch.Tensor, offset: float = 1.5,
                           other_axes_factor: float = 0.85, opacity_factor: float = 0.6) -> dict[str, torch.Tensor]:
    """New parameter rows for the 2 children of each parent: first all '+' children, then all '-'."""
    p = {k: v.detach()[parents] for k, v in params.items()}
    scales = torch.exp(p["log_scales"])
    s_max, axis = scales.max(dim=1)
    R = quat_to_rotmat(p["quats"])
    direction = R[torch.arange(len(parents), device=R.device), :, axis]   # column = the longest axis in world
    step = direction * (offset * s_max)[:, None]
    new_scales = scales * other_axes_factor
    new_scales[torch.arange(len(parents), device=R.device), axis] = s_max / 2.0
    opacity = torch.sigmoid(p["opacity_logits"]) * opacity_factor
    new = {k: torch.cat([v, v]) for k, v in p.items()}
    new["means"] = torch.cat([p["means"] + step, p["means"] - step])
    new["log_scales"] = torch.log(torch.cat([new_scales, new_scales]))
    new["opacity_logits"] = torch.cat([torch.logit(opacity), torch.logit(opacity)])
    return new


def long_axis_split(model: GaussianModel, optimizer: GaussianAdam | None, mask: torch.Tensor, state: dict | None = None,
                    offset: float = 1.5, other_axes_factor: float = 0.85, opacity_factor: float = 0.6) -> None:
    """Replace each selected Gaussian by its 2 long-axis children (fresh Adam moments, extras copied)."""
    mask = torch.as_tensor(mask, device=model.device)
    parents = mask.nonzero().squeeze(1)
    new = long_axis_split_params(model.params, parents, offset, other_axes_factor, opacity_factor)
    ops.rebuild(model, optimizer, (~mask).nonzero().squeeze(1), new_params=new, parents=torch.cat([parents, parents]),
                state=state)


@dataclass
class EDCStrategy(AbsGSStrategy):
    """EDC on AbsGS: selection on the absolute gradient alone, every candidate replaced by a long-axis split
    (`long_axis_split`), and recovery-aware pruning below `recovery_prune_opa` `recovery_delay` steps after each opacity
    reset (the module docstring). State: `AbsGSStrategy`'s plus n_recovery_prune, int."""
    grow_grad2d_abs: float = 3.5e-4
    prune_screen_px: float = math.inf  # no screen-size pruning
    split_offset: float = 1.5  # children at +-this x s_max along the longest axis
    other_axes_factor: float = 0.85  # children's other axes x this
    opacity_factor: float = 0.6  # children's opacity x this
    recovery_delay: int = 300  # steps after an opacity reset before recovery-aware pruning
    recovery_prune_opa: float = 0.05  # recovery-aware pruning threshold
    # Scaled schedules shrink the 300-iteration recovery window (to 15 steps at steps_scale 0.05), too
    # short for opacities reset to 0.01 to climb back above 0.05 at the unscaled opacity LR: the window
    # is at least this many actual steps (and ends before the next reset). No effect at steps_scale 1.
    recovery_min_steps: int = 100  # minimum recovery window at scaled schedules
    release_schedule: bool = False  # use the public code's schedule instead of the paper's
    def _abs_score(self, state: dict) -> torch.Tensor:
        """The mean absolute gradient `_select` compares with its threshold (x the release's count factor)."""
        count = state["count"]
        grads_abs = state["grad2d_abs"] / count.clamp_min(1)
        return grads_abs * (1 + count / 100.0 * 0.3) if self.release_schedule else grads_abs

    def _grow_scores(self, model: GaussianModel, state: dict, step: int) -> torch.Tensor:
        """Budget ranking: the absolute-gradient statistic the selection uses (every candidate is a split)."""
        return self._abs_score(state)

    def _split_cost(self) -> int:
        return 1  # a long-axis split: 2 children replace the parent, whatever n_split says

    def _select(self, model: GaussianModel, state: dict, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        count = state["count"]
        grads_abs = state["grad2d_abs"] / count.clamp_min(1)
        threshold = self.grow_grad2d_abs
        if self.release_schedule:
            grads_abs = grads_abs * (1 + count / 100.0 * 0.3)
            for until, factor in ((3_500, 2.0), (6_500, 1.5), (9_500, 1.2)):
                if step < self.at(until):
                    threshold *= factor
                    break
        split = grads_abs >= threshold
        return torch.zeros_like(split), split

    def _grow(self, model, optimizer, state, clone, split) -> None:
        long_axis_split(model, optimizer, split, state, self.split_offset, self.other_axes_factor, self.opacity_factor)

    def step_post_backward(self, model, optimizer, state, step, info) -> None:
        """`DefaultStrategy.step_post_backward`, with the release's early prune (opacity < 0.02 at 300, `release_schedule`)
        before it and the recovery-aware prune (`recovery_step`) after it."""
        if self.release_schedule and step == self.at(300):
            self._prune_below(model, optimizer, state, 0.02)
        super().step_post_backward(model, optimizer, state, step, info)
        reset = self.reset_interval(self.reset_every)
        if reset < step < self.at(self.refine_stop_iter) and step % reset == self.recovery_step():
            self._prune_below(model, optimizer, state, self.recovery_prune_opa)

    def recovery_step(self) -> int:
        """Steps after each opacity reset at which the recovery-aware pruning runs."""
        reset = self.reset_interval(self.reset_every)
        delay = max(self.at(self.recovery_delay), self.recovery_min_steps)
        return min(delay, reset - 1) % reset

    @torch.no_grad()
    def _prune_below(self, model, optimizer, state, opacity: float) -> None:
        prune = model.opacities < opacity
        if prune.all() or not prune.any():
            return
        ops.remove(model, optimizer, prune, state=state)
        state["n_recovery_prune"] = state.get("n_recovery_prune", 0) + int(prune.sum())
