"""Improved-GS (Deng, Diao, Li, Yu, Xu: "Improving Densification in 3D Gaussian Splatting for
High-Fidelity Rendering", arXiv 2508.12313, 2025), the EDC authors' successor, built on Taming-3DGS.

Facts from the paper's components (Edge-Aware Score, Long-Axis Split, Recovery-Aware Pruning,
Multi-step Update, Growth Control) and their values from the authors' release
(github.com/XiaoBin2001/Imporved-GS: train.py, scene/gaussian_model.py, arguments/__init__.py,
budget.txt). Every iteration number is nominal (x steps_scale; `Strategy.at` / `every`).

Statistics: from iteration 500 to 15 000, the AbsGS absolute screen-space gradient of every visible
Gaussian (NDC units, averaged over the steps it was visible; the release's `add_densification_stats_abs`).

Every 100 iterations in (500, 15 000):
1. Edge-aware score (release train.py `compute_edge_score`): for each of `score_views` (10) training
   views, taken in turn from a stack of all of them (every view at 3 400 and 6 400), the per-Gaussian
   sum over pixels of edge(p) alpha T (`contrib.blend_weight_sums`), where edge is the view's
   grey-level image through PIL's FIND_EDGES filter, min-max normalised (`edge_map`); per view, the
   non-zero sums are divided by their mean; the score is their mean over the views. After 14 500 the
   score is the mean absolute gradient instead.
2. Growth control (the budget): the count may reach B sqrt((it - 500) / (14 500 - 500)), B from
   14 500 on; B is the run's Gaussian budget (`--budget`, `StrategyContext.budget`) if set, else `budget` (the release's
   per-scene `--budget`, budget.txt), else `budget_multiple` x the initial count (this suite's default
   for scenes the release has no budget for, the rule this suite uses for MCMC's `cap_max`).
3. Candidates: mean absolute gradient >= `grow_grad2d_abs` (3e-4; / 1.5 after 14 500 while below the
   budget). k = min(budget_t, N + candidates) - N of them, drawn without replacement with
   probability proportional to the score (`torch.multinomial`; candidates with score 0 are never
   drawn), are each replaced by a long-axis split (`improved_long_axis_split_params`): 2 children at
   mean +- 3 `split_distance` (0.45) s_max along the longest axis, long-axis scale
   s_max (1 - d), other scales x sqrt(1 - d^2), opacity x `opacity_reduction` (0.6).
4. Prune opacity < `prune_opa` (0.005), before 14 900 only. No size-based pruning.

Besides: opacity < 0.02 is pruned once at iteration 300; opacities are reset to min(o, 0.05) every
3 000 iterations in (500, 15 000); recovery-aware pruning removes the `recovery_prune_fraction` (20 %)
least opaque Gaussians 300 iterations after the resets before 9 000 (3 300, 6 300). The multi-step
update (one optimizer step on the summed gradients of 5 iterations after 15 000, of 20 after 22 500)
is the method's optimizer (methods/improved_gs.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError, TrainingError
from strings_bench.engine.gaussians import GaussianModel, quat_to_rotmat
from strings_bench.engine.optim import GaussianAdam
import strings_bench.engine.strategies.ops as ops
from strings_bench.engine.strategies.absgs import raster_absgrad
from strings_bench.engine.strategies.base import Strategy
from strings_bench.engine.strategies.contrib import blend_weight_sums
from strings_bench.engine.strategies.default import ndc_norm


def edge_map(image: np.ndarray) -> torch.Tensor:
    """Improved-GS' per-view edge weights (release train.py `get_edges` and the normalisation after it).

    The (H, W, 3) float image in [0, 1] becomes 8-bit (x 255, truncated, as torchvision's ToPILImage),
    grey (PIL "L": ITU-R 601-2 luma), goes through PIL's FIND_EDGES (3x3 kernel 8 at the centre, -1
    around; PIL copies the border pixels unfiltered), back to [0, 1] (/ 255), then is min-max
    normalised. A flat image (max = min) gives zeros.

    Returns:
        (H, W) float32 tensor in [0, 1].
    """
    from PIL import Image, ImageFilter

    arr = np.asarray(image, dtype=np.float32)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise StringsBenchError(f"edge_map expects an (H, W, 3) image, got shape {arr.shape}")
    rgb8 = (np.clip(arr, 0.0, 1.0) * 255.0).astype(np.uint8)  # truncation, as ToPILImage's .byte()
    grey = Image.fromarray(rgb8, mode="RGB").convert("L")
    edges = torch.from_numpy(np.asarray(grey.filter(ImageFilter.FIND_EDGES), dtype=np.float32) / 255.0)
    lo, hi = edges.min(), edges.max()
    if hi <= lo:
        return torch.zeros_like(edges)
    return (edges - lo) / (hi - lo)


def normalise_by_positive_mean(values: torch.Tensor) -> torch.Tensor:
    """Non-zero (positive) entries divided by their mean, the others 0 (release train.py `normalize`)."""
    values = torch.nan_to_num(values.to(torch.float32), nan=0.0)
    out = torch.zeros_like(values)
    pos = values > 0
    if pos.any():
        out[pos] = values[pos] / values[pos].mean()
    return out


@torch.no_grad()
def improved_long_axis_split_params(params: dict[str, torch.Tensor], parents: torch.Tensor, split_distance: float = 0.45,
                                    opacity_reduction: float = 0.6) -> dict[str, torch.Tensor]:
    """Parameter rows of the 2 children of each parent (first all '+' children, then all '-'), the
    release's `long_axis_split`: with d = split_distance and s_max the largest scale (axis a),
    children at mean +- 3 d s_max R e_a; scale on axis a: s_max (1 - d), the others x sqrt(1 - d^2);
    opacity x opacity_reduction (of the activated opacity); rotation and colour copied."""
    if not 0.0 < split_distance < 1.0:
        raise StringsBenchError(f"split_distance must be in (0, 1), got {split_distance}")
    p = {k: v.detach()[parents] for k, v in params.items()}
    scales = torch.exp(p["log_scales"])
    s_max, axis = scales.max(dim=1)
    rows = torch.arange(len(parents), device=scales.device)
    direction = quat_to_rotmat(p["quats"])[rows, :, axis]  # the longest axis in world space
    offset = direction * (3.0 * split_distance * s_max)[:, None]
    new_scales = scales * math.sqrt(1.0 - split_distance ** 2)
    new_scales[rows, axis] = s_max * (1.0 - split_distance)
    opacity = torch.sigmoid(p["opacity_logits"]) * opacity_reduction
    new = {k: torch.cat([v, v]) for k, v in p.items()}
    new["means"] = torch.cat([p["means"] + offset, p["means"] - offset])
    new["log_scales"] = torch.log(torch.cat([new_scales, new_scales]))
    new["opacity_logits"] = torch.logit(torch.cat([opacity, opacity]))
    return new


def growth_budget(step: int, start: int, full: int, final_budget: int) -> int:
    """Growth control: int(sqrt((step - start) / (full - start)) x final_budget), the final budget from `full` on."""
    rate = (step - start) / max(1, full - start)
    if rate >= 1:
        return int(final_budget)
    return int(math.sqrt(max(0.0, rate)) * final_budget)


@dataclass
class ImprovedGSStrategy(Strategy):
    """Improved-GS densification (see the module docstring). Fields are nominal settings; the method
    attaches its training views' edge maps with `attach_views` before training."""

    grow_grad2d_abs: float = 3e-4  # candidates: mean absolute gradient (NDC) >= this (release densify_grad_threshold)
    refine_start_iter: int = 500  # statistics and densification after this step (nominal)
    refine_stop_iter: int = 15_000  # ... and before this one (nominal)
    refine_every: int = 100  # densification interval (nominal)
    # this method's own final count B (the release's --budget, per scene in budget.txt); the run's Gaussian budget replaces it
    budget: int | None = None  # final Gaussian count B (the release's --budget); None: budget_multiple
    budget_multiple: float = 10.0  # with budget unset: final budget = this x the initial number of Gaussians
    growth_full_iter: int = 14_500  # growth control reaches the final budget here (release: densify_until - 500)
    score_views: int = 10  # training views rendered for each edge-aware score (release --cams)
    late_iter: int = 14_500  # after this, score = absolute gradient and, below budget, threshold / late_threshold_div
    late_threshold_div: float = 1.5  # threshold divisor after late_iter while below the budget
    prune_opa: float = 0.005  # densification rounds prune opacity below this
    prune_stop_iter: int = 14_900  # rounds prune only before this step (nominal)
    split_distance: float = 0.45  # long-axis split: children at +-3 x this x s_max; long axis x (1 - this)
    opacity_reduction: float = 0.6  # long-axis split: children's opacity x this
    early_prune_iter: int = 300  # one-off prune of opacity < early_prune_opa at this step (nominal)
    early_prune_opa: float = 0.02  # threshold of the one-off early prune
    reset_every: int = 3_000  # opacity reset interval (nominal), inside the densification window
    reset_value: float = 0.05  # opacity after a reset: min(opacity, this)
    recovery_delay: int = 300  # recovery-aware pruning this many steps after a reset (nominal)
    recovery_stop_iter: int = 9_000  # recovery-aware pruning only before this step (nominal)
    recovery_prune_fraction: float = 0.2  # recovery-aware pruning removes this fraction, the least opaque
    # As EDC (strategies/edc.py): a scaled schedule shrinks the 300-step recovery window (15 steps at
    # x0.05), too short for reset opacities to tell fast from slow recovery; at least this many steps.
    recovery_min_steps: int = 100  # minimum recovery window at scaled schedules (no effect at steps_scale 1)

    def __post_init__(self):
        if self.budget is not None and int(self.budget) < 1:
            raise StringsBenchError(f"improved-gs budget must be a positive number of Gaussians, got {self.budget}",
                                    hint="leave it unset to use budget_multiple x the initial count")
        if not self.budget_multiple > 0:
            raise StringsBenchError(f"improved-gs budget_multiple must be > 0, got {self.budget_multiple}")
        if not 0.0 <= self.recovery_prune_fraction < 1.0:
            raise StringsBenchError(f"recovery_prune_fraction must be in [0, 1), got {self.recovery_prune_fraction}")
        if self.score_views < 1:
            raise StringsBenchError(f"score_views must be >= 1, got {self.score_views}")
        self._views: dict | None = None

    # ---- inputs the method attaches (recomputed from the images at every setup: not state) ------
    def attach_views(self, cameras: dict, edge_maps: dict, backend: str = "auto") -> None:
        """The training views the edge-aware score renders: {view_idx: Camera} and {view_idx: (H, W) edge map}."""
        missing = sorted(set(cameras) - set(edge_maps))
        if missing:
            raise StringsBenchError(f"improved-gs: no edge map for training view(s) {missing[:5]}")
        self._views = {"order": sorted(cameras), "cameras": dict(cameras), "edges": dict(edge_maps),
                       "backend": backend}

    def initialize_state(self, scene_extent: float, cameras=None) -> dict:
        """`Strategy.initialize_state` plus the statistics (grad2d_abs, count), the initial count n_initial (set at the
        first step), the score views' stack and the round counters."""
        state = super().initialize_state(scene_extent, cameras)
        state.update(grad2d_abs=None, count=None, n_initial=None, view_stack=[], all_views_done=[],
                     n_refine=0, n_split=0, n_recovery_prune=0, last_budget=None)
        return state

    def get_raster_kwargs(self, step: int) -> dict:
        """{"compute_absgrad": True}: candidates are chosen on the absolute gradient."""
        return {"compute_absgrad": True}

    def step_pre_backward(self, model, optimizer, state, step, info) -> None:
        """Keep the gradient of `info["means2d"]` (when it is in the graph) for the statistics."""
        if info["means2d"].requires_grad:
            info["means2d"].retain_grad()

    # ---- the budget ---------------------------------------------------------------------------
    def final_budget(self, state: dict) -> int:
        """The final count B: the run's Gaussian budget (the context's), else this method's own `budget` setting, else
        budget_multiple x the initial count."""
        if self.context.budget is not None:
            return int(self.context.budget)
        if self.budget is not None:
            return int(self.budget)
        return max(1, int(round(self.budget_multiple * int(state["n_initial"]))))

    def budget_at(self, state: dict, step: int) -> int:
        """Growth control: the count allowed after the round at `step`."""
        return growth_budget(step, self.at(self.refine_start_iter), self.at(self.growth_full_iter),
                             self.final_budget(state))

    # ---- the schedule ---------------------------------------------------------------------------
    def step_post_backward(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
                           info: dict) -> None:
        """The early prune, then inside (refine_start_iter, refine_stop_iter): the statistics, a densification round
        every `refine_every`, the opacity resets and the recovery-aware prunes (see the module docstring)."""
        if state.get("n_initial") is None:
            state["n_initial"] = len(model)
        if step == self.at(self.early_prune_iter):
            self._prune_where(model, optimizer, state, model.opacities < self.early_prune_opa)
        if not self.at(self.refine_start_iter) < step < self.at(self.refine_stop_iter):
            return
        self._update_state(model, state, info)
        if step % self.every(self.refine_every) == 0:
            self.densify(model, optimizer, state, step)
        reset = self.reset_interval(self.reset_every)
        if step % reset == 0:
            ops.reset_opacity(model, optimizer, self.reset_value)
        if reset < step < self.at(self.recovery_stop_iter) and step % reset == self.recovery_step():
            self.recovery_prune(model, optimizer, state)

    def recovery_step(self) -> int:
        """Steps after each opacity reset at which the recovery-aware pruning runs."""
        reset = self.reset_interval(self.reset_every)
        delay = max(self.at(self.recovery_delay), self.recovery_min_steps)
        return min(delay, reset - 1) % reset

    @torch.no_grad()
    def _update_state(self, model: GaussianModel, state: dict, info: dict) -> None:
        n = len(model)
        if state.get("grad2d_abs") is None or state["grad2d_abs"].shape[0] != n:
            state["grad2d_abs"] = torch.zeros(n, device=model.device)
            state["count"] = torch.zeros(n, device=model.device)
        if info["means2d"].grad is None:  # no backward through this render
            return
        visible = torch.as_tensor(info["radii"], device=model.device) > 0
        norms = ndc_norm(raster_absgrad(info), info["width"], info["height"], info.get("n_cameras", 1))
        state["grad2d_abs"][visible] += norms[visible]
        state["count"][visible] += 1

    # ---- a densification round ----------------------------------------------------------------
    def score_view_list(self, state: dict, step: int) -> list[int]:
        """The views of this round's score: `score_views` popped from a stack of all training views
        (refilled when empty), or every view at the first round at or after 3 400 and 6 400."""
        if self._views is None:
            raise StringsBenchError("improved-gs: the edge-aware score has no training views",
                                    hint="the improved-gs method attaches them in prepare(); a strategy used "
                                         "alone needs strategy.attach_views(cameras, edge_maps)")
        order = self._views["order"]
        for nominal in (3_400, 6_400):  # release: iteration % 3000 == 400 and iteration < 9000
            if step >= self.at(nominal) and nominal not in state["all_views_done"]:
                state["all_views_done"].append(nominal)
                return list(order)
        views = []
        for _ in range(self.score_views):
            if not state["view_stack"]:
                state["view_stack"] = list(order)
            views.append(state["view_stack"].pop())
        return views

    @torch.no_grad()
    def edge_score(self, model: GaussianModel, views: list[int]) -> torch.Tensor:
        """The edge-aware score of every Gaussian over `views` (see the module docstring)."""
        score = torch.zeros(len(model), device=model.device)
        with torch.enable_grad():
            for v in views:
                sums = blend_weight_sums(model, self._views["cameras"][v], self._views["edges"][v].to(model.device),
                                         backend=self._views["backend"])
                score += normalise_by_positive_mean(sums)
        return score / len(views)

    @torch.no_grad()
    def densify(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int) -> None:
        """Score, select within the growth budget, long-axis split, prune; then clear the statistics."""
        if state.get("grad2d_abs") is not None:
            grads = state["grad2d_abs"] / state["count"].clamp_min(1)
            budget = self.budget_at(state, step)
            threshold = self.grow_grad2d_abs
            late = step > self.at(self.late_iter)
            if late:
                score = grads.clone()
                if len(model) < budget:
                    threshold = threshold / self.late_threshold_div
            else:
                score = self.edge_score(model, self.score_view_list(state, step))
            candidates = grads >= threshold
            target = min(budget, int(candidates.sum()) + len(model))
            n_split = target - len(model)
            split = self.select(score, candidates, n_split)
            if split.any():
                parents = split.nonzero().squeeze(1)
                new = improved_long_axis_split_params(model.params, parents, self.split_distance, self.opacity_reduction)
                ops.rebuild(model, optimizer, (~split).nonzero().squeeze(1), new_params=new,
                            parents=torch.cat([parents, parents]), state=state)
            state["n_split"] += int(split.sum())
            state["last_budget"] = budget
        if step < self.at(self.prune_stop_iter):
            self._prune_where(model, optimizer, state, model.opacities < self.prune_opa)
        state["n_refine"] += 1
        state["grad2d_abs"] = state["count"] = None

    @staticmethod
    def select(score: torch.Tensor, candidates: torch.Tensor, n: int) -> torch.Tensor:
        """Mask of min(n, candidates with score > 0) candidates drawn without replacement with
        probability proportional to score (release `long_axis_split`: torch.multinomial)."""
        weights = torch.where(candidates, score, torch.zeros_like(score)).clamp_min(0).to(torch.float64)
        n = min(int(n), int((weights > 0).sum()))
        mask = torch.zeros_like(candidates, dtype=torch.bool)
        if n > 0:
            mask[torch.multinomial(weights, n, replacement=False)] = True
        return mask

    @torch.no_grad()
    def recovery_prune(self, model: GaussianModel, optimizer: GaussianAdam, state: dict) -> None:
        """Remove the Gaussians below the `recovery_prune_fraction` quantile of opacity (release `only_prune(0.2, True)`)."""
        if self.recovery_prune_fraction <= 0:
            return
        opacity = model.opacities.detach()
        threshold = torch.quantile(opacity.to(torch.float64), self.recovery_prune_fraction).to(opacity.dtype)
        pruned = self._prune_where(model, optimizer, state, opacity < threshold)
        state["n_recovery_prune"] += pruned
        state["grad2d_abs"] = state["count"] = None  # the release's only_prune restarts the statistics

    @staticmethod
    def _prune_where(model: GaussianModel, optimizer: GaussianAdam, state: dict, mask: torch.Tensor) -> int:
        if not mask.any():
            return 0
        if mask.all():
            raise TrainingError("improved-gs pruning would remove every Gaussian",
                                hint="training diverged or the scene is empty; check the input images and poses")
        ops.remove(model, optimizer, mask, state=state)
        return int(mask.sum())
