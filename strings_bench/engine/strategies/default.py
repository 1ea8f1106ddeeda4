"""Vanilla 3DGS adaptive density control (Kerbl et al. 2023; docs/sources.md §1).

Every step from the start until `refine_stop_iter`: accumulate, for each Gaussian visible in the view
(radius > 0), the norm of the gradient of the loss w.r.t. its projected centre in NDC units
(pixel-gradient x (W/2, H/2)), a visibility count, and the largest screen radius.
Every `refine_every` steps after `refine_start_iter`: clone Gaussians whose mean gradient
>= grow_grad2d and largest scale <= grow_scale3d x extent; split the larger ones into `n_split`
children (scales / (0.8 n)); prune opacity < prune_opa and, after `screen_prune_after`, world scale
> prune_scale3d x extent (and screen radius > prune_screen_px, off by default); then clear the statistics.
Every `reset_every` steps (before refine_stop_iter): opacity <- min(opacity, reset_value).

With a Gaussian budget (run --budget, `StrategyContext.budget`): when the clones and splits of a round would pass it, the ones with
the largest mean gradient grow and the rest wait (Taming-3DGS' rule: stop densifying at the budget); pruning is
unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from strings_bench.core.errors import TrainingError
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.optim import GaussianAdam
import strings_bench.engine.strategies.ops as ops
from strings_bench.engine.strategies.base import Strategy, keep_within_budget


@dataclass
class DefaultStrategy(Strategy):
    """Vanilla 3DGS adaptive density control (clone, split, prune, opacity reset); see the module
    docstring for the rules and `Strategy` for the interface. Fields are nominal settings.

    A round of densification (`densify`) is made of small steps that a variant overrides alone, as in
    gsplat's strategies: `_update_state` (the statistics), `_select` (which Gaussians grow), `_grow`
    (how: clone + split here, EDC's long-axis split), `_prune_mask` (which go), `_reset_opacity`.

    State entries added to `Strategy.initialize_state`'s:
        grad2d: (N,) float or None, sum over steps of the screen-space mean-gradient norm (NDC);
        count: (N,) float or None, steps in which each Gaussian was visible;
        max_radii: (N,) float or None, largest screen radius in pixels;
        n_refine: int, refinement rounds so far;
        last_clone, last_split, last_prune: int, what the last round did (after the first round).
    The statistics are None right after a refinement and re-created at the next step.

    Example:
        >>> from strings_bench.engine.strategies import DefaultStrategy
        >>> strategy = DefaultStrategy(grow_grad2d=4e-4)
        >>> from strings_bench.engine.strategies import StrategyContext
        >>> strategy = DefaultStrategy(grow_grad2d=4e-4, context=StrategyContext(steps_scale=0.01))
        >>> state = strategy.initialize_state(scene_extent=2.0)
        >>> sorted(state)
        ['count', 'grad2d', 'max_radii', 'n_refine', 'scene_extent']
        >>> strategy.at(strategy.refine_stop_iter), strategy.every(strategy.refine_every)
        (150, 50)
    """

    prune_opa: float = 0.005  # prune Gaussians below this opacity
    grow_grad2d: float = 2e-4  # densify when the mean screen-space gradient norm (NDC) exceeds this
    grow_scale3d: float = 0.01  # clone if largest scale <= this x extent, else split
    prune_scale3d: float = 0.1  # after screen_prune_after, prune world scale > this x extent
    # off by default: the authors' code never applies the paper's 20 px rule (why: docs/engine.md, "DefaultStrategy")
    prune_screen_px: float = math.inf  # prune screen radius > this px after 3K (inf = off: the reference never applies it)
    refine_start_iter: int = 500  # first densification step (nominal)
    refine_stop_iter: int = 15_000  # last densification step (nominal)
    refine_every: int = 100  # densification interval (nominal)
    reset_every: int = 3_000  # opacity reset interval (nominal)
    reset_value: float = 0.01  # opacity after a reset: min(opacity, this)
    screen_prune_after: int = 3_000  # big-Gaussian prunes start after this step (nominal)
    n_split: int = 2  # children of a split
    # a memory guard, not the budget: growth past it fails clearly, where the budget stops growth quietly
    memory_limit_gaussians: int = 20_000_000  # refuse to grow past this (memory); a run that hits it fails clearly

    def initialize_state(self, scene_extent: float, cameras=None) -> dict:
        """`Strategy.initialize_state` plus empty statistics (grad2d, count, max_radii) and n_refine.

        Args:
            scene_extent: the scene's extent in world units.
            cameras: the training cameras (unused here).
        """
        state = super().initialize_state(scene_extent, cameras)
        state.update(grad2d=None, count=None, max_radii=None, n_refine=0)
        self.dropped_for_budget = 0  # candidates the budget held back since this state began (`budget_holds`)
        return state

    def budget_holds(self, model: GaussianModel) -> bool:
        """At the budget now in force, or growth already cut by it (a round that prunes too may end a little under it).

        Args:
            model: the model (its current size is read).
        """
        return super().budget_holds(model) or (self.context.budget is not None and self.dropped_for_budget > 0)

    # ---- hooks ------------------------------------------------------------------------------
    def step_pre_backward(self, model, optimizer, state, step, info) -> None:
        """Keep the gradient of `info["means2d"]` (when it is in the graph) for `_update_state`.

        Args:
            model: unused.
            optimizer: unused.
            state: unused.
            step: unused.
            info: this step's info dict.
        """
        if info["means2d"].requires_grad:
            info["means2d"].retain_grad()

    def step_post_backward(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
                           info: dict) -> None:
        """Before `refine_stop_iter`: accumulate statistics; every `refine_every` steps after
        `refine_start_iter` densify; every `reset_every` steps reset opacities.

        Args:
            model: the model (changed in place).
            optimizer: its optimizer (kept in step by the ops).
            state: this strategy's state.
            step: the step the strategy sees.
            info: this step's info dict.
        """
        if step >= self.at(self.refine_stop_iter):
            return
        self._update_state(model, state, info)
        if step > self.at(self.refine_start_iter) and step % self.every(self.refine_every) == 0:
            self.densify(model, optimizer, state, step)
        if step % self.reset_interval(self.reset_every) == 0:
            self._reset_opacity(model, optimizer, state)

    @torch.no_grad()
    def densify(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int) -> None:
        """One densification round: `_grow_gs` (when statistics were gathered), `_prune_gs`, then the
        statistics start again.

        Args:
            model: the model (changed in place).
            optimizer: its optimizer.
            state: this strategy's state.
            step: the step the strategy sees (for the prune schedule and messages).

        Raises:
            TrainingError: growth past `memory_limit_gaussians`, or a prune that would remove every Gaussian.
        """
        if self._has_statistics(state):
            self._grow_gs(model, optimizer, state, step)
        self._prune_gs(model, optimizer, state, step)
        state["n_refine"] += 1
        self._clear_statistics(state)

    # ---- the steps (overridable) -------------------------------------------------------------
    def screen_grad(self, info: dict) -> torch.Tensor | None:
        """(N, 2) gradient w.r.t. the projected centres, in pixels, or None (no backward through it).

        Args:
            info: this step's info dict.
        """
        return info["means2d"].grad

    @torch.no_grad()
    def _update_state(self, model: GaussianModel, state: dict, info: dict) -> None:
        """Add this step's statistics: for Gaussians with radius > 0, the norm of `screen_grad`
        converted to NDC (x W/2, x H/2), one to count, and the running maximum radius.

        Args:
            model: the model (only its size and device are read).
            state: this strategy's state (grad2d, count, max_radii are created if missing).
            info: this step's info dict.
        """
        n = len(model)
        if state["grad2d"] is None or state["grad2d"].shape[0] != n:
            state["grad2d"] = torch.zeros(n, device=model.device)
            state["count"] = torch.zeros(n, device=model.device)
            state["max_radii"] = torch.zeros(n, device=model.device)
        grad = self.screen_grad(info)
        if grad is None:
            return
        radii = torch.as_tensor(info["radii"], device=model.device)
        if _fused_stats(grad, radii, info, state):
            return
        visible = radii > 0
        # Whole-array updates: adding 0 (or taking the maximum with 0) leaves an entry's bits as they are, since
        # every entry is >= +0, and they skip the gathers and scatters of boolean indexing.
        norm = ndc_norm(grad, info["width"], info["height"], info.get("n_cameras", 1))
        zero = torch.zeros((), dtype=norm.dtype, device=norm.device)
        state["grad2d"].add_(torch.where(visible, norm, zero))
        state["count"].add_(visible.to(state["count"].dtype))
        torch.maximum(state["max_radii"], torch.where(visible, radii.float(), zero), out=state["max_radii"])

    def _has_statistics(self, state: dict) -> bool:
        return state["grad2d"] is not None

    def _clear_statistics(self, state: dict) -> None:
        state["grad2d"] = state["count"] = state["max_radii"] = None

    def _select(self, model: GaussianModel, state: dict, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(clone mask, split mask): mean gradient >= grow_grad2d, small ones cloned, large ones split."""
        grads = state["grad2d"] / state["count"].clamp_min(1)
        is_grad_high = grads >= self.grow_grad2d
        is_small = model.scales.max(dim=-1).values <= self.grow_scale3d * state["scene_extent"]
        return is_grad_high & is_small, is_grad_high & ~is_small

    def _grow(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, clone: torch.Tensor,
              split: torch.Tensor) -> None:
        """Clone, then split into `n_split` children (scales / (0.8 n)); clones are never split in the same round."""
        ops.duplicate(model, optimizer, clone, state=state)
        # Clones are appended after the originals.
        split = torch.cat([split, torch.zeros(int(clone.sum()), dtype=torch.bool, device=model.device)])
        ops.split(model, optimizer, split, n_children=self.n_split, state=state)

    def _grow_scores(self, model: GaussianModel, state: dict, step: int) -> torch.Tensor:
        """(N,) the score that decides which candidates grow first when they do not all fit in the budget: here the
        mean screen-space gradient (NDC) that `_select` compares with grow_grad2d, for clones and splits alike."""
        return state["grad2d"] / state["count"].clamp_min(1)

    def _split_cost(self) -> int:
        """Gaussians one split adds (n_split children replace the parent)."""
        return self.n_split - 1

    def _fit_budget(self, model: GaussianModel, state: dict, step: int, clone: torch.Tensor,
                    split: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(clone, split) cut to the headroom the budget leaves (`Strategy.headroom`), highest `_grow_scores` first."""
        headroom = self.headroom(model)
        if headroom is None:
            return clone, split
        cost = torch.where(split, self._split_cost(), 1)
        keep = keep_within_budget(clone | split, self._grow_scores(model, state, step), cost, headroom)
        self.dropped_for_budget = getattr(self, "dropped_for_budget", 0) + int((clone | split).sum() - keep.sum())
        return clone & keep, split & keep

    @torch.no_grad()
    def _grow_gs(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int) -> None:
        """`_select`, cut to the budget (`_fit_budget`), refuse growth past `memory_limit_gaussians`, `_grow`, and
        record what was done."""
        clone, split = self._fit_budget(model, state, step, *self._select(model, state, step))
        grow = int(clone.sum()) + int(split.sum()) * self._split_cost()
        if len(model) + grow > self.memory_limit_gaussians:
            raise TrainingError(f"densification at step {step} would make {len(model) + grow} Gaussians "
                                f"(more than memory_limit_gaussians={self.memory_limit_gaussians})",
                                hint="raise memory_limit_gaussians or the gradient threshold(s), or set a budget "
                                     "(run --budget)")
        self._grow(model, optimizer, state, clone, split)
        state["last_clone"], state["last_split"] = int(clone.sum()), int(split.sum())

    def _prune_mask(self, model: GaussianModel, state: dict, step: int) -> torch.Tensor:
        """Opacity < prune_opa; after screen_prune_after also world scale > prune_scale3d x extent and
        screen radius > prune_screen_px."""
        prune = model.opacities < self.prune_opa
        if step > self.at(self.screen_prune_after):
            prune |= model.scales.max(dim=-1).values > self.prune_scale3d * state["scene_extent"]
            if state["max_radii"] is not None:
                prune |= state["max_radii"] > self.prune_screen_px
        return prune

    @torch.no_grad()
    def _prune_gs(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int) -> None:
        prune = self._prune_mask(model, state, step)
        if prune.all():
            raise TrainingError(f"pruning at step {step} would remove every Gaussian",
                                hint="training diverged or the scene is empty; check the input images and poses")
        ops.remove(model, optimizer, prune, state=state)
        state["last_prune"] = int(prune.sum())

    def _reset_opacity(self, model: GaussianModel, optimizer: GaussianAdam, state: dict) -> None:
        """Every `reset_every` steps before refine_stop_iter: opacity <- min(opacity, reset_value) (Adam's moments of
        the opacities are zeroed with it)."""
        ops.reset_opacity(model, optimizer, self.reset_value)


def _fused_stats(grad: torch.Tensor, radii: torch.Tensor, info: dict, state: dict) -> bool:
    """`_update_state`'s torch ops in one numba pass (stats_kernels.py, the same bits) where every array is a
    contiguous CPU tensor of the kernel's dtype (float32; int32 radii); False (nothing done) elsewhere."""
    arrays = (grad, state["grad2d"], state["count"], state["max_radii"])
    if not (all(t.device.type == "cpu" and t.dtype == torch.float32 and t.is_contiguous() for t in arrays)
            and radii.device.type == "cpu" and radii.dtype == torch.int32 and radii.is_contiguous()
            and grad.ndim == 2 and grad.shape[1] == 2 and radii.ndim == 1
            and len({grad.shape[0], radii.shape[0], *(t.shape[0] for t in arrays[1:])}) == 1):
        return False
    from strings_bench.engine.strategies.stats_kernels import accumulate_screen_stats

    n_cameras = info.get("n_cameras", 1)
    accumulate_screen_stats(grad.detach().numpy(), radii.numpy(),
                            np.float32(info["width"] / 2.0 * n_cameras), np.float32(info["height"] / 2.0 * n_cameras),
                            state["grad2d"].numpy(), state["count"].numpy(), state["max_radii"].numpy())
    return True


def ndc_norm(grad_px: torch.Tensor, width: int, height: int, n_cameras: int = 1) -> torch.Tensor:
    """Norm of a (N, 2) screen-space gradient in pixel units, converted to NDC units (3DGS convention)."""
    g = grad_px.detach().clone()
    g[..., 0] *= width / 2.0 * n_cameras
    g[..., 1] *= height / 2.0 * n_cameras
    return g.norm(dim=-1)
