"""The densification-strategy interface (gsplat style).

A strategy is a dataclass whose fields are its settings (flat `--set` keys of the method that uses
it). `engine.splatting.GaussianSplatting` drives it; per training step (1-based) it calls:

    state = strategy.initialize_state(scene_extent, steps_scale, cameras)  # at every set_model(): the initial
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

A strategy's own round of growing and pruning is `densify` (DefaultStrategy); `refine` is the method's
hook that calls `step_post_backward`.

Iteration numbers in settings are nominal (for a 30 000-step run); `self.at(state, n)` gives the
actual step for the run's `steps_scale`, `self.every(state, n)` the actual interval (with floors in
scaled-down runs, see MIN_SCALED_INTERVAL). Strategies change the Gaussians only through
`strategies.ops`, which keeps the optimizer state, `model.extras` and the tensors of `state` in step.
`state` is part of the resumable training state (saved with torch.save): anything picklable;
tensors and torch generators in it, also inside dicts and lists, are moved to the CPU to be saved
and back to the method's device on resume.
"""

from __future__ import annotations

import math
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


def keep_within_budget(candidates: torch.Tensor, scores: torch.Tensor, cost: torch.Tensor | int,
                       room: int | None) -> torch.Tensor:
    """The candidates that fit in `room` new Gaussians, highest `scores` first (Taming-3DGS' budgeted densification).

    Args:
        candidates: (N,) bool, the Gaussians a strategy selected to grow.
        scores: (N,) float, the strategy's score (higher grows first); ties go to the lower index.
        cost: (N,) int or an int, the Gaussians each candidate adds (a clone 1, a 3DGS split n_split - 1).
        room: how many Gaussians may be added; None: no budget (every candidate is kept).

    Returns:
        (N,) bool, a subset of `candidates` whose total cost is at most `room`: the longest prefix of the candidates
        sorted by decreasing score that fits (a candidate that does not fit stops the growth; none after it is tried,
        so a cheaper low-scoring one never overtakes a costlier high-scoring one).

    Example:
        >>> import torch
        >>> from strings_bench.engine.strategies.base import keep_within_budget
        >>> cand = torch.tensor([True, True, False, True])
        >>> keep_within_budget(cand, torch.tensor([0.1, 0.9, 5.0, 0.5]), 1, room=2).tolist()
        [False, True, False, True]
    """
    candidates = torch.as_tensor(candidates, dtype=torch.bool)
    if room is None:
        return candidates
    cost = torch.as_tensor(cost, device=candidates.device).to(torch.int64).expand(candidates.shape)
    idx = candidates.nonzero().squeeze(1)
    if idx.numel() == 0 or int(cost[idx].sum()) <= room:
        return candidates
    s = scores.detach()[idx].to(torch.float64)
    s = torch.where(torch.isnan(s), torch.tensor(-math.inf, dtype=s.dtype, device=s.device), s)
    order = torch.sort(-s, stable=True).indices  # decreasing score, ties by index
    fits = torch.cumsum(cost[idx][order], 0) <= int(room)
    n_fit = int(fits.long().cumprod(0).sum())  # the longest prefix that fits
    keep = torch.zeros_like(candidates)
    keep[idx[order[:n_fit]]] = True
    return keep


def scaled_interval(nominal: float, steps_scale: float, floor: int = MIN_SCALED_INTERVAL) -> int:
    """A nominal interval in a run scaled by steps_scale: scaled, but in scaled-down runs never
    shorter than `floor` steps (nor than the nominal interval itself)."""
    lower = min(nominal, floor) if steps_scale < 1 else 1
    return int(max(1, scaled_step(nominal, steps_scale), lower))


@dataclass
class Strategy:
    """Base strategy: no densification, no extra loss. Subclasses override what they need.

    Subclass it as a dataclass; each field is a setting, and the comment beside the field is the
    meaning `strings-bench methods show` prints. A method picks its strategy with the class
    attribute `strategy_cls` (`engine.splatting.GaussianSplatting`).

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
    training state):
        scene_extent: float, the scene's extent in world units (1.1 x the largest distance of a
            training camera from their mean); size thresholds are fractions of it.
        steps_scale: float, the run's schedule scale (read by `at`, `every`, `reset_interval`).
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
        ...     def initialize_state(self, scene_extent, steps_scale=1.0, cameras=None):
        ...         state = super().initialize_state(scene_extent, steps_scale, cameras)
        ...         state["seen"] = None  # (N,) bool once the first step ran
        ...         return state
        ...
        ...     def step_post_backward(self, model, optimizer, state, step, info):
        ...         if state["seen"] is None:
        ...             state["seen"] = torch.zeros(len(model), dtype=torch.bool)
        ...         state["seen"] |= info["radii"] > 0
        ...         if step % self.every(state, self.prune_every) == 0:
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
    # The equal-budget cap (`run --budget`, docs/guide/running.md): never hold more Gaussians than this. Each strategy
    # honours it by its own rules (docs/baselines.md, "Equal Gaussian budget"): one with a budget of its own uses it
    # (MCMC: cap_max), the others stop densifying at the cap, keeping the highest-scoring candidates when they do
    # not all fit (`keep_within_budget`), as Taming-3DGS does. A subclass may redeclare the field with its own rule.
    max_gaussians: int | None = None  # equal-budget cap on the number of Gaussians (None: no cap; run --budget)

    def __post_init__(self):
        if self.max_gaussians is not None and (int(self.max_gaussians) != self.max_gaussians or self.max_gaussians < 1):
            from strings_bench.core.errors import StringsBenchError

            raise StringsBenchError(f"max_gaussians must be a positive number of Gaussians, got {self.max_gaussians!r}",
                                    hint="leave it unset (None) for no budget")

    def initialize_state(self, scene_extent: float, steps_scale: float = 1.0, cameras=None) -> dict:
        """A fresh state for a new model (called at every `set_model`, so a phase switch resets it).

        Args:
            scene_extent: the scene's extent in world units (`scene.extent`).
            steps_scale: the run's schedule scale (1.0 = the paper's 30 000 steps).
            cameras: the training views' cameras at the training resolution (Mip-Splatting's 3D
                filter reads them); unused here.

        Returns:
            dict with "scene_extent" and "steps_scale" (floats); subclasses add their entries.
        """
        return {"scene_extent": float(scene_extent), "steps_scale": float(steps_scale)}

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

    # ---- the Gaussian budget ----------------------------------------------------------------
    def cap_now(self, state: dict) -> int | None:  # not "budget": Improved-GS has a setting of that name
        """The most Gaussians the model may hold now: `max_gaussians` less what the method keeps free for
        Gaussians it will add itself (`state["reserved_gaussians"]`: STRinGS' phase 1 keeps room for the non-text
        points that join at T1); None without a budget.

        Args:
            state: this strategy's state dict (reads "reserved_gaussians", default 0).

        Example:
            >>> from strings_bench.engine.strategies import Strategy
            >>> Strategy(max_gaussians=1000).cap_now({"reserved_gaussians": 300}), Strategy().cap_now({})
            (700, None)
        """
        if self.max_gaussians is None:
            return None
        return int(self.max_gaussians) - int(state.get("reserved_gaussians", 0))

    def room(self, model: GaussianModel, state: dict) -> int | None:
        """How many Gaussians may still be added (>= 0), or None without a budget.

        Args:
            model: the model (its current size is read).
            state: this strategy's state dict (see `cap_now`).
        """
        cap = self.cap_now(state)
        return None if cap is None else max(0, cap - len(model))

    # ---- helpers ----------------------------------------------------------------------------
    @staticmethod
    def at(state: dict, nominal: float) -> int:
        """The actual step of nominal iteration `nominal`: round(nominal x state["steps_scale"]).

        Args:
            state: a state dict from `initialize_state` (steps_scale defaults to 1).
            nominal: an iteration number of the paper's 30 000-step schedule.

        Example:
            >>> from strings_bench.engine.strategies import Strategy
            >>> Strategy.at({"steps_scale": 0.01}, 15_000)
            150
        """
        return scaled_step(nominal, state.get("steps_scale", 1.0))

    @staticmethod
    def every(state: dict, nominal: float, floor: int = MIN_SCALED_INTERVAL) -> int:
        """The actual interval of nominal interval `nominal`: scaled, but in scaled-down runs never
        shorter than min(floor, nominal) steps; at least 1.

        Args:
            state: a state dict from `initialize_state`.
            nominal: an interval of the paper's schedule (e.g. refine every 100).
            floor: the shortest interval in a scaled-down run (MIN_SCALED_INTERVAL = 50).

        Example:
            >>> from strings_bench.engine.strategies import Strategy
            >>> Strategy.every({"steps_scale": 0.01}, 100), Strategy.every({"steps_scale": 1.0}, 100)
            (50, 100)
        """
        # a run's own floor (TrainConfig.interval_floor; the miniature `rounds` lowers it) can only lower `floor`
        return scaled_interval(nominal, state.get("steps_scale", 1.0), min(floor, int(state.get("interval_floor", floor))))

    @staticmethod
    def reset_interval(state: dict, nominal: float) -> int:
        """Opacity-reset interval: as `every` with the longer floor MIN_SCALED_RESET_INTERVAL (200).

        Args:
            state: a state dict from `initialize_state`.
            nominal: the nominal reset interval (3DGS: 3 000).
        """
        return scaled_interval(nominal, state.get("steps_scale", 1.0), MIN_SCALED_RESET_INTERVAL)
