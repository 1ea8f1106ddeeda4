"""The densification-strategy interface (gsplat style).

A strategy is a dataclass whose fields are its settings (flat `--set` keys of the method that uses
it), plus a `StrategyContext` given once at construction: the run's steps scale and interval floor,
and the Gaussian budget with what the method keeps free of it. `engine.splatting.GaussianSplatting`
builds both and drives the strategy; per training step (1-based) it calls:

    state = strategy.initialize_state(scene_extent, cameras)        # at every set_model(): the initial
                                                                    # model, and phase switches (STRinGS)
    # train_step(step):
    sstep = method.strategy_step(step)                              # the step the strategy sees
    kwargs = strategy.get_raster_kwargs(sstep)                      # extra rasterize() arguments
    out = method.render_raster(view, sh_degree=..., **kwargs)       # -> model.render -> rasterize
    info = {"raster": out, "means2d": out.means2d, "radii": out.radii, "width": W, "height": H,
            "n_cameras": 1, "view_idx": view, "camera": camera}
    strategy.step_pre_backward(model, optimizer, state, sstep, info)   # e.g. means2d.retain_grad()
    loss = method.loss(out, gt, view, step) + strategy.loss_terms(model, info, sstep)
    loss.backward(); optimizer.step(row_scale)
    # (the framework evaluates a checkpoint here, before any densification)
    # method.refine(step):
    strategy.step_post_backward(model, optimizer, state, sstep, info)  # gradients still in .grad:
    optimizer.zero_grad()                                                # statistics, densify, reset

Iteration numbers in settings are nominal (for a 30 000-step run); `self.at(n)` gives the actual
step, `self.every(n)` the actual interval (`StrategyContext`). Strategies change the Gaussians only
through `strategies.ops`, which keeps the optimizer state, `model.extras` and the tensors of `state`
in step. `state` holds training state only (statistics, counters, generators), never a setting: it is
part of the resumable training state (torch.save); its tensors and generators, also inside dicts and
lists, are moved to the CPU to be saved and back to the method's device on resume.
Why the interval floors: docs/engine.md, "Schedules and threads".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import torch

from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.optim import GaussianAdam


def scaled_step(nominal: float, steps_scale: float) -> int:
    """A nominal iteration number in a run scaled by steps_scale (rounded)."""
    return int(round(nominal * steps_scale))


# Shortest interval, in steps, between refinement rounds (and SH increases, relocations) of a
# scaled-down run: new Gaussians need that many steps of statistics (docs/engine.md, "Schedules and threads").
MIN_SCALED_INTERVAL = 50
# Shortest opacity-reset interval of a scaled-down run: recovering from opacity 0.01 takes a roughly
# fixed number of Adam steps, not a fraction of the run (docs/engine.md, "Schedules and threads").
MIN_SCALED_RESET_INTERVAL = 200


def keep_within_budget(candidates: torch.Tensor, scores: torch.Tensor, cost: torch.Tensor | int,
                       headroom: int | None) -> torch.Tensor:
    """The candidates that fit in `headroom` new Gaussians, highest `scores` first (Taming-3DGS' budgeted densification).

    Args:
        candidates: (N,) bool, the Gaussians a strategy selected to grow.
        scores: (N,) float, the strategy's score (higher grows first); ties go to the lower index.
        cost: (N,) int or an int, the Gaussians each candidate adds (a clone 1, a 3DGS split n_split - 1).
        headroom: how many Gaussians may be added; None: no budget (every candidate is kept).

    Returns:
        (N,) bool, a subset of `candidates` whose total cost is at most `headroom`: the longest prefix of the candidates
        sorted by decreasing score that fits (a candidate that does not fit stops the growth; none after it is tried,
        so a cheaper low-scoring one never overtakes a costlier high-scoring one).

    Example:
        >>> import torch
        >>> from strings_bench.engine.strategies.base import keep_within_budget
        >>> cand = torch.tensor([True, True, False, True])
        >>> keep_within_budget(cand, torch.tensor([0.1, 0.9, 5.0, 0.5]), 1, headroom=2).tolist()
        [False, True, False, True]
    """
    candidates = torch.as_tensor(candidates, dtype=torch.bool)
    if headroom is None:
        return candidates
    cost = torch.as_tensor(cost, device=candidates.device).to(torch.int64).expand(candidates.shape)
    idx = candidates.nonzero().squeeze(1)
    if idx.numel() == 0 or int(cost[idx].sum()) <= headroom:
        return candidates
    s = scores.detach()[idx].to(torch.float64)
    s = torch.where(torch.isnan(s), torch.tensor(-math.inf, dtype=s.dtype, device=s.device), s)
    order = torch.sort(-s, stable=True).indices  # decreasing score, ties by index
    fits = torch.cumsum(cost[idx][order], 0) <= int(headroom)
    n_fit = int(fits.long().cumprod(0).sum())  # the longest prefix that fits
    keep = torch.zeros_like(candidates)
    keep[idx[order[:n_fit]]] = True
    return keep


def scaled_interval(nominal: float, steps_scale: float, floor: int = MIN_SCALED_INTERVAL) -> int:
    """A nominal interval in a run scaled by steps_scale: scaled, but in scaled-down runs never
    shorter than `floor` steps (nor than the nominal interval itself)."""
    lower = min(nominal, floor) if steps_scale < 1 else 1
    return int(max(1, scaled_step(nominal, steps_scale), lower))


def _no_reserve() -> int:
    return 0


@dataclass(frozen=True)
class StrategyContext:
    """What a method tells its strategy once, at construction: how nominal iteration numbers map to
    the run's steps, and the Gaussian budget. The method's own schedule (`GaussianSplatting.at/every`) is
    the same object, so the method and its strategy scale alike.

    steps_scale: the run's schedule scale (1.0 = the paper's 30 000 steps).
    interval_floor: the shortest refinement / SH interval of a scaled-down run, in steps (the
        miniature `rounds` lowers it to 1).
    budget: the run's equal Gaussian budget, in Gaussians (`run --budget`; the setting `gaussian_budget`); None: none.
    budget_reserved: () -> how many of the budget the method keeps free now for Gaussians it adds itself
        (STRinGS' phase 1: the non-text points that join at T1); 0 by default.
    """

    steps_scale: float = 1.0
    interval_floor: int = MIN_SCALED_INTERVAL
    budget: int | None = None
    budget_reserved: Callable[[], int] = field(default=_no_reserve, compare=False, repr=False)

    def __post_init__(self):
        from strings_bench.core.errors import StringsBenchError

        if not self.steps_scale > 0:
            raise StringsBenchError(f"steps_scale must be > 0, got {self.steps_scale}")
        if self.budget is not None and (isinstance(self.budget, bool) or int(self.budget) != self.budget or self.budget < 1):
            raise StringsBenchError(f"gaussian_budget must be a positive number of Gaussians, got {self.budget!r}",
                                    hint="leave it unset (None) for no budget")

    def at(self, nominal: float) -> int:
        """The step of nominal iteration `nominal`: round(nominal x steps_scale).

        Example:
            >>> from strings_bench.engine.strategies import StrategyContext
            >>> StrategyContext(steps_scale=0.01).at(15_000)
            150
        """
        return scaled_step(nominal, self.steps_scale)

    def every(self, nominal: float, floor: int | None = None) -> int:
        """The interval, in steps, of nominal interval `nominal`: scaled, but in a scaled-down run never
        shorter than min(floor, nominal) steps, `floor` being `interval_floor` (None), or a caller's floor
        lowered to it (a strategy's); at least 1.

        Example:
            >>> from strings_bench.engine.strategies import StrategyContext
            >>> StrategyContext(steps_scale=0.01).every(100), StrategyContext().every(100)
            (50, 100)
        """
        floor = int(self.interval_floor) if floor is None else min(floor, int(self.interval_floor))
        return scaled_interval(nominal, self.steps_scale, floor)

    def reset_interval(self, nominal: float) -> int:
        """An opacity-reset interval, in steps: as `every` with the floor MIN_SCALED_RESET_INTERVAL (200),
        which `interval_floor` does not lower."""
        return scaled_interval(nominal, self.steps_scale, MIN_SCALED_RESET_INTERVAL)

    def budget_now(self) -> int | None:
        """The most Gaussians the model may hold now: `budget` less `budget_reserved()`; None without a budget.

        Example:
            >>> from strings_bench.engine.strategies import StrategyContext
            >>> StrategyContext(budget=1000, budget_reserved=lambda: 300).budget_now(), StrategyContext().budget_now()
            (700, None)
        """
        return None if self.budget is None else int(self.budget) - int(self.budget_reserved())


@dataclass
class Strategy:
    """Base strategy: no densification, no extra loss. Subclasses override what they need.

    Subclass it as a dataclass; each field is a setting, and the comment beside the field is the
    meaning `strings-bench methods show` prints. A method picks its strategy with the class
    attribute `strategy_cls` (`engine.splatting.GaussianSplatting`), which builds it with its
    `StrategyContext` (`context=`, keyword only; not a setting).

    The `info` dict (built by the method for every step; read-only for the strategy):
        raster: the step's `RasterOutput` (`out.absgrad` after backward when get_raster_kwargs
            asked for compute_absgrad).
        means2d: (N, 2) `out.means2d`, projected centres in pixels, in the autograd graph; its
            `.grad` is dL/d(u, v) in pixels after backward if `retain_grad()` was called.
        radii: (N,) int32 `out.radii`, screen radius in pixels, 0 = not visible in this view.
        width, height: int, the training image size in pixels (for NDC conversion: x W/2, H/2).
        n_cameras: int, views in the batch (always 1 here; gsplat's convention).
        view_idx: int, the scene view index trained on.
        camera: the view's `Camera` at the training resolution.

    The `state` dict (created by `initialize_state`, owned by the strategy, saved with the
    training state; state only, no setting):
        scene_extent: float, the scene's extent in world units (1.1 x the largest distance of a
            training camera from their mean); size thresholds are fractions of it.
        ...: the subclass's own entries. A tensor whose first dimension is N (the number of
            Gaussians) is resized by every op of `strategies.ops` (new rows copy their parent or
            are zero), so per-Gaussian statistics stay aligned with the model.

    Example (a strategy that prunes Gaussians no view has seen since its last round):
        >>> from dataclasses import dataclass
        >>> import numpy as np, torch
        >>> import strings_bench.engine.strategies.ops as ops
        >>> from strings_bench.engine.gaussians import GaussianModel
        >>> from strings_bench.engine.optim import GaussianAdam, LearningRates
        >>> from strings_bench.engine.strategies import Strategy
        >>> from strings_bench.scene.camera import Camera
        >>> @dataclass
        ... class PruneUnseen(Strategy):
        ...     prune_every: int = 100  # nominal interval between rounds
        ...
        ...     def initialize_state(self, scene_extent, cameras=None):
        ...         state = super().initialize_state(scene_extent, cameras)
        ...         state["seen"] = None  # (N,) bool once the first step ran
        ...         return state
        ...
        ...     def step_post_backward(self, model, optimizer, state, step, info):
        ...         if state["seen"] is None:
        ...             state["seen"] = torch.zeros(len(model), dtype=torch.bool)
        ...         state["seen"] |= info["radii"] > 0
        ...         if step % self.every(self.prune_every) == 0:
        ...             ops.remove(model, optimizer, ~state["seen"], state=state)
        ...             state["seen"] = None
        >>> cam = Camera(fx=40.0, fy=40.0, cx=24.0, cy=16.0, width=48, height=32, R=np.eye(3), t=np.zeros(3))
        >>> xyz = np.array([[0.0, 0.0, 2.0], [0.3, 0.1, 2.5], [0.0, 0.0, -2.0]])  # the last is behind the camera
        >>> model = GaussianModel.from_points(xyz, np.full((3, 3), 128, np.uint8), sh_degree=0)
        >>> optimizer = GaussianAdam(model.params, LearningRates().group_lrs(extent=1.0))
        >>> strategy = PruneUnseen()
        >>> state = strategy.initialize_state(scene_extent=1.0)
        >>> step = 100
        >>> out = model.render(cam, **strategy.get_raster_kwargs(step))
        >>> info = {"raster": out, "means2d": out.means2d, "radii": out.radii, "width": cam.width,
        ...         "height": cam.height, "n_cameras": 1, "view_idx": 0, "camera": cam}
        >>> strategy.step_pre_backward(model, optimizer, state, step, info)
        >>> loss = out.color.mean() + strategy.loss_terms(model, info, step)
        >>> loss.backward(); optimizer.step()
        >>> strategy.step_post_backward(model, optimizer, state, step, info)
        >>> len(model)
        2
    """

    raster_kwargs = {}  # class attribute (not a setting); subclasses may make it a field
    # the run's schedule scale and Gaussian budget, given once (not a setting: dataclass_settings skips it)
    context: StrategyContext = field(default_factory=StrategyContext, kw_only=True, repr=False, compare=False,
                                     metadata={"setting": False})

    def bind(self, context: StrategyContext) -> "Strategy":
        """Give a strategy built without a context (`Strategy()`) its method's; returns self. A strategy built
        with another context is refused: the method and its strategy must scale alike."""
        if self.context != StrategyContext() and self.context != context:
            from strings_bench.core.errors import StringsBenchError

            raise StringsBenchError(f"{type(self).__name__} was built for {self.context}, its method runs {context}",
                                    hint="build the strategy without a context; the method gives it its own")
        self.context = context
        return self

    def initialize_state(self, scene_extent: float, cameras=None) -> dict:
        """A fresh state for a new model (called at every `set_model`, so a phase switch resets it).

        Args:
            scene_extent: the scene's extent in world units (`scene.extent`).
            cameras: the training views' cameras at the training resolution (Mip-Splatting's 3D
                filter reads them); unused here.

        Returns:
            {"scene_extent": float}; subclasses add their entries.
        """
        return {"scene_extent": float(scene_extent)}

    def get_raster_kwargs(self, step: int) -> dict:
        """Extra keyword arguments for this step's `rasterize` call, e.g. {"compute_absgrad": True}
        (AbsGS) or {"mip_filter": True} (Mip-Splatting). Default: a copy of `raster_kwargs`.

        Args:
            step: the step the strategy sees (`method.strategy_step(step)`, 1-based).

        Returns:
            dict of `rasterize` keyword arguments (sh_degree and backend are the method's).
        """
        return dict(getattr(self, "raster_kwargs", None) or {})

    def step_pre_backward(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
                          info: dict) -> None:
        """Called after the render, before the loss and backward: prepare to read gradients
        (`info["means2d"].retain_grad()`). Must not change the model. Default: nothing.

        Args:
            model: the `GaussianModel` being trained.
            optimizer: its `GaussianAdam`.
            state: this strategy's state dict (see the class docstring).
            step: the step the strategy sees (1-based).
            info: this step's info dict (see the class docstring).
        """

    def loss_terms(self, model: GaussianModel, info: dict, step: int) -> torch.Tensor | float:
        """Regularisers added to the method's loss before backward (MCMC: opacity and scale L1).

        Args:
            model: the `GaussianModel` being trained.
            info: this step's info dict.
            step: the step the strategy sees (1-based).

        Returns:
            a scalar tensor in the autograd graph, or 0.0 for none (the default).
        """
        return 0.0

    def step_post_backward(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
                           info: dict) -> None:
        """Called from `method.refine(step)`, after the optimizer step and after a checkpoint of this
        step was evaluated; the gradients are still in `.grad` (zeroed right after). Accumulate
        statistics, then grow, prune, relocate or reset, through `strategies.ops` only.
        Default: nothing.

        Args:
            model: the `GaussianModel` being trained (changed in place by the ops).
            optimizer: its `GaussianAdam` (the ops keep its moments aligned).
            state: this strategy's state dict (pass it to the ops as `state=`).
            step: the step the strategy sees (1-based).
            info: this step's info dict.
        """

    # ---- the Gaussian budget ---------------------------------------------------------------------
    def headroom(self, model: GaussianModel) -> int | None:
        """How many Gaussians may still be added (>= 0) under the budget now in force
        (`StrategyContext.budget_now`), or None without a budget.

        Args:
            model: the model (its current size is read).
        """
        budget = self.context.budget_now()
        return None if budget is None else max(0, budget - len(model))

    def budget_holds(self, model: GaussianModel) -> bool:
        """Whether the budget has held the model back: it is at the budget now in force (a strategy that drops
        candidates for the budget says so too: `DefaultStrategy`). False without a budget.

        Args:
            model: the model (its current size is read).
        """
        budget = self.context.budget_now()
        return budget is not None and len(model) >= budget

    # ---- the schedule (the context's) -----------------------------------------------------------
    def at(self, nominal: float) -> int:
        """The step of nominal iteration `nominal` (`StrategyContext.at`).

        Args:
            nominal: an iteration number of the paper's 30 000-step schedule.
        """
        return self.context.at(nominal)

    def every(self, nominal: float, floor: int = MIN_SCALED_INTERVAL) -> int:
        """The interval, in steps, of nominal interval `nominal` (`StrategyContext.every`).

        Args:
            nominal: an interval of the paper's schedule (e.g. refine every 100).
            floor: the shortest interval in a scaled-down run (MIN_SCALED_INTERVAL = 50; the run's
                interval_floor lowers it).
        """
        return self.context.every(nominal, floor)

    def reset_interval(self, nominal: float) -> int:
        """An opacity-reset interval, in steps (`StrategyContext.reset_interval`: at least 200 in a scaled-down run).

        Args:
            nominal: the nominal reset interval (3DGS: 3 000).
        """
        return self.context.reset_interval(nominal)
