"""3D Gaussian Splatting as a `Method`: the reference implementation every built-in method extends.

Size (~620 lines): one method, 3DGS, with its hooks in the order the loop calls them and their docstrings; a hook
split off into another file would be read out of that order. Its settings are engine/train_config.py.

`GaussianSplatting(config, strategy)` holds the model, the optimizer and the strategy state, and
implements the method protocol (`strings_bench.core.method.Method`); the framework's loop
(`engine.trainer.Trainer`) drives it. Methods change behaviour by subclassing and overriding these
hooks (docs/engine.md):

    prepare(scene)                  -> None                          (preprocessing in setup; STRinGS: masks, Algorithm 1)
    initial_model(scene)            -> GaussianModel                 (default: 3DGS init from SfM points)
    set_model(model)                -> None                          (start optimising a model: fresh Adam and strategy state)
    make_optimizer(model)           -> GaussianAdam                  (default: 3DGS learning rates x extent)
    train_views()                   -> list of view indices          (default: scene.train_idx)
    views_for_step(step)            -> view index                    (default: shuffled per epoch, seeded)
    loss(out, gt, view_idx, step)   -> scalar tensor                 (default: 0.8 L1 + 0.2 (1 - SSIM))
    position_lr(step)               -> float                         (default: 3DGS exponential schedule)
    position_lr_scale(step)         -> None | float | (N,) tensor    (per-row factor on the position step)
    sh_degree_for_step(step)        -> int                           (default: +1 every 1000 x steps_scale, >= 50 steps)
    strategy_step(step)             -> int                           (step number the strategy sees)
    on_step_start(step)             -> None                          (e.g. switch phase: self.set_model(...))
    skips_refinement(step)          -> bool                          (a phase switch skips the step's refinement)
    render_raster(view, sh_degree, model=None) -> RasterOutput       (default: model.render; Mip: through its filter)
    model_to_render()               -> GaussianModel                 (what checkpoint renders show; Mip: filter folded in)
    checkpoint_extra(step)          -> dict                          (method stats for CheckpointResult.extra)
    extra_state() / load_extra_state(state)                          (a subclass's own resumable state)

Every schedule inside (densification, opacity reset, SH degree, position-LR decay) is its nominal
3DGS iteration number multiplied by `config.steps_scale` (intervals keep at least `config.interval_floor`
steps, 50 unless the miniature `rounds` lowers it; opacity resets at least 200), through one
`StrategyContext` (`self.context`) that the method and its strategy share.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from typing import TYPE_CHECKING

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError, TrainingError
from strings_bench.core.instrument import note, timed
from strings_bench.core.settings import Setting, dataclass_settings
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.losses import gs_loss
from strings_bench.engine.motion import motion_record, new_motion_log, note_motion
from strings_bench.engine.optim import GaussianAdam, LearningRates, exponential_lr
from strings_bench.engine.optim_kernels import sums_finite
from strings_bench.engine.strategies.base import Strategy, StrategyContext
from strings_bench.engine.strategies.default import DefaultStrategy
# the settings, apart so that they read without a method; imported from here too (engine.splatting.TrainConfig)
from strings_bench.engine.train_config import TrainConfig, config_from_settings, settings_keys  # noqa: F401
from strings_bench.core.method import Method

if TYPE_CHECKING:
    from strings_bench.raster.types import RasterOutput
    from strings_bench.scene.scene import Scene

log = logging.getLogger(__name__)


def _state_to_cpu(obj):
    """A strategy state made storable: tensors to the CPU, torch generators to their state."""
    if isinstance(obj, torch.Generator):
        return {"__torch_generator__": obj.get_state(), "device": str(obj.device)}
    if torch.is_tensor(obj):
        return obj.detach().cpu()
    if isinstance(obj, dict):
        return {k: _state_to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_state_to_cpu(v) for v in obj)
    return obj


def _state_to_device(obj, device: torch.device):
    if isinstance(obj, dict) and "__torch_generator__" in obj:
        gen = torch.Generator(device=obj.get("device", "cpu"))
        gen.set_state(obj["__torch_generator__"])
        return gen
    if torch.is_tensor(obj):
        return obj.to(device)
    if isinstance(obj, dict):
        return {k: _state_to_device(v, device) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_state_to_device(v, device) for v in obj)
    return obj


class GaussianSplatting(Method):
    """Vanilla 3DGS (Kerbl et al. 2023) on the suite's engine; see the module docstring for the hooks.

    Args:
        config: training settings (`TrainConfig`); default 3DGS.
        strategy: densification strategy (a `Strategy` dataclass); default `DefaultStrategy`.
        model: start from this model instead of `initial_model(scene)`.

    Example (``scene`` is a `strings_bench.scene.scene.Scene`)::

        from strings_bench.engine.splatting import GaussianSplatting, TrainConfig
        from strings_bench.engine.trainer import Trainer

        method = GaussianSplatting(TrainConfig(steps_scale=0.01))
        for result in Trainer(method, scene, checkpoints=[70, 300], device="auto").train():
            print(result.iteration, result.gaussians)
    """

    name = "3dgs"
    paper = ""  # the citation is the method spec's (its *_spec.py beside the method); MethodSpec.instantiate sets it
    strategy_cls: type[Strategy] = DefaultStrategy
    # A subclass's own settings dataclass (e.g. STRinGS' t1, alpha, beta, gamma); its instance is
    # `self.method_settings`.
    method_settings_cls: type | None = None
    forced_settings: dict = {}  # settings a variant pins (the paper's ablations), over any given

    def __init__(self, config: TrainConfig | None = None, strategy: Strategy | None = None,
                 model: GaussianModel | None = None):
        self.config = config or TrainConfig()
        # the schedule scale and the Gaussian budget, told once to the strategy (and used by the method's own at/every)
        self.context = StrategyContext(steps_scale=self.config.steps_scale, interval_floor=self.config.interval_floor,
                                       budget=self.config.gaussian_budget, budget_reserved=self.budget_reserved)
        self.strategy = (strategy if strategy is not None else self.strategy_cls(context=self.context)).bind(self.context)
        self.settings: dict = {}
        self.method_settings = self.method_settings_cls() if self.method_settings_cls is not None else None
        self._given_model = model
        self.scene: "Scene | None" = None
        self.model: GaussianModel | None = None
        self.optimizer: GaussianAdam | None = None
        self.strategy_state: dict = {}
        self.downscale = 1.0
        self.device = torch.device("cpu")
        self.rng = np.random.default_rng(self.config.seed)
        self._view_stack: list[int] = []
        self._view_key: tuple | None = None
        self._targets: dict[int, torch.Tensor] = {}
        self._cameras: dict = {}
        self._step_info: tuple | None = None
        self.step = 0
        self.last_loss = float("nan")
        # The model's size over training, for the cell's record: the most Gaussians it held, and the first step at
        # which it filled the Gaussian budget in force then (run --budget; STRinGS' phase 1 keeps part of it free)
        self.size_log: dict = {"peak_gaussians": 0, "budget_reached_at": None}
        self.motion_log: dict = new_motion_log()

    @classmethod
    def from_settings(cls, **settings) -> "GaussianSplatting":
        """Build from flat settings: TrainConfig fields, `lr_<group>`, strategy fields and the fields of
        `method_settings_cls`. Called by `MethodSpec.build` when a run plans a job, before `setup`.

        Args:
            **settings: flat setting name -> value (the spec's defaults, presets, steps scale and `--set`,
                merged); `forced_settings` win over them.
        Returns:
            the method, not set up; `settings` holds what it was given.
        Raises:
            StringsBenchError: an unknown key, naming the valid ones.
        """
        settings = {**settings, **cls.forced_settings}
        own = {f.name for f in dataclasses.fields(cls.method_settings_cls)} if cls.method_settings_cls else set()
        config, strategy = config_from_settings(settings, cls.strategy_cls, ignore=tuple(own))
        method = cls(config, strategy)
        method.settings = dict(settings)
        if cls.method_settings_cls is not None:
            method.method_settings = cls.method_settings_cls(**{k: v for k, v in settings.items() if k in own})
        return method

    @classmethod
    def settings_schema(cls) -> list[Setting]:
        """Every setting this method takes, with its default and meaning. Called by `strings-bench methods show`
        and when a run checks `--set` keys, without building the method.

        Returns:
            one `Setting` per key: TrainConfig's, the learning rates (`lr_<group>`), the strategy's fields, then
            `method_settings_cls`' fields.
        """
        out = dataclass_settings(TrainConfig, "training", skip=("lrs",))
        out += dataclass_settings(LearningRates, "learning rates (x scene extent for means)", prefix="lr_")
        seen = {s.name for s in out}
        out += [s for s in dataclass_settings(cls.strategy_cls, f"densification ({cls.strategy_cls.__name__})")
                if s.name not in seen]
        if cls.method_settings_cls is not None:
            out += dataclass_settings(cls.method_settings_cls, cls.__name__)  # the name is the spec's
        return out

    # ---- schedule helpers -------------------------------------------------------------------
    def at(self, nominal: float) -> int:
        """The step actually run for nominal 3DGS iteration `nominal` (`StrategyContext.at`: x steps_scale, at least
        1). Called by the hooks that read a schedule."""
        return self.context.at(nominal)

    def every(self, nominal: float) -> int:
        """The interval, in steps, of a nominal 3DGS interval `nominal` (`StrategyContext.every`: x steps_scale, at
        least config.interval_floor steps). Called by the hooks that read a schedule."""
        return self.context.every(nominal)

    # ---- set-up --------------------------------------------------------------------------------
    def setup(self, scene: "Scene", *, downscale: float = 1.0, device: str = "cpu", seed: int | None = None) -> None:
        """Prepare training on `scene` (see `Method.setup`): the training images decoded once, `prepare`
        (preprocessing), the initial model (`initial_model`, then `set_model`: Adam and the strategy state), all on
        `device`. Called once by the loop before the first step (timed as preprocess_seconds), and again before
        `load_state_dict` on resume."""
        self.scene = scene
        self.downscale = float(downscale)
        self.device = torch.device(device)
        if seed is not None:
            self.config.seed = int(seed)
        self.extent = float(scene.extent)
        self.background = torch.tensor(self.config.background, dtype=torch.float32, device=self.device)
        self.rng = np.random.default_rng(self.config.seed)
        self._view_stack, self._view_key, self._targets, self._cameras = [], None, {}, {}
        self.step = 0
        self.preload_targets(scene.train_idx)
        self.prepare(scene)
        self.set_model(self._given_model if self._given_model is not None else self.initial_model(scene))

    def prepare(self, scene: "Scene") -> None:
        """Preprocessing before the initial model (STRinGS: masks and Algorithm 1). Called once by `setup`, after the
        training images are loaded and before `initial_model`; timed as preprocess_seconds. Default: nothing.

        Args:
            scene: the scene being trained on (also `self.scene`).
        """

    # ---- hooks --------------------------------------------------------------------------------
    def initial_model(self, scene: "Scene") -> GaussianModel:
        """The model training starts from. Called once by `setup`, after `prepare` (not when the method was given
        a `model`).

        Args:
            scene: the scene; `scene.model.xyz` (P, 3) float world units and `scene.model.rgb` (P, 3) uint8 are
                its SfM points.
        Returns:
            a `GaussianModel` on `self.device`; default one Gaussian per SfM point (3DGS initialisation).
        """
        return GaussianModel.from_points(scene.model.xyz, scene.model.rgb, sh_degree=self.config.sh_degree,
                                         init_opacity=self.config.init_opacity, device=self.device)

    def train_views(self) -> list[int]:
        """The views training samples from. Called by `views_for_step` every step, and by `set_model` (the
        strategy's cameras). Changing the list restarts the permutation.

        Returns:
            scene view indices; default `scene.train_idx`.
        """
        return list(self.scene.train_idx)

    def views_for_step(self, step: int) -> int:
        """The view trained on at `step`. Called once per step in `train_step`, after `position_lr` and before the
        render.

        Args:
            step: the 1-based step.
        Returns:
            a scene view index; default 3DGS' order: a random permutation of `train_views()`, redrawn when used
            up, from the method's seeded generator.
        Raises:
            TrainingError: the scene has no training views.
        """
        views = self.train_views()
        if not views:
            raise TrainingError(f"scene {self.scene.name} has no training views",
                                hint="check split.json or the number of registered images")
        key = tuple(views)
        if key != self._view_key:
            self._view_key, self._view_stack = key, []
        if not self._view_stack:
            self._view_stack = [views[i] for i in self.rng.permutation(len(views))][::-1]
        return self._view_stack.pop()

    def loss(self, out: "RasterOutput", gt: torch.Tensor, view_idx: int, step: int) -> torch.Tensor:
        """The training loss of one step. Called once per step in `train_step`, after the render and the strategy's
        `step_pre_backward`; the strategy's `loss_terms` are added to what it returns, then backward runs.

        Args:
            out: the rasterizer's output (`RasterOutput`; `out.color` is (H, W, 3) float32 in [0, 1]).
            gt: the training image, (H, W, 3) float32 in [0, 1], on the method's device.
            view_idx: the scene view rendered.
            step: the 1-based step.
        Returns:
            a scalar tensor; default 3DGS' (1 - lambda_dssim) L1 + lambda_dssim (1 - SSIM).
        """
        return gs_loss(out.color, gt, self.config.lambda_dssim)

    def position_lr(self, step: int) -> float:
        """The position learning rate at `step`. Called first thing in each `train_step` (after `on_step_start`).

        Args:
            step: the 1-based step.
        Returns:
            the learning rate of the means, in world units (scene extent x the 3DGS rate); default 3DGS'
            log-linear decay over `position_lr_steps` (scaled), times `position_lr_gain`.
        """
        lrs = self.config.lrs
        lr = exponential_lr(step, lrs.means * self.extent, lrs.means_final * self.extent,
                            self.at(self.config.position_lr_steps))
        gain = self.config.position_lr_gain
        return lr if gain == 1 else lr * gain

    def position_lr_scale(self, step: int):
        """A factor on the position step at `step`. Called once per step in `train_step`, after backward and
        before the optimizer step.

        Args:
            step: the 1-based step.
        Returns:
            None (no factor; the default), a float multiplying the position learning rate, or an (N,) float
            tensor on the model's device scaling each Gaussian's position update (STRinGS: 0 in phase 1,
            eta_r per row in phase 2).
        """
        return None

    def sh_degree_for_step(self, step: int) -> int:
        """The SH degree rendered at `step`. Called in each `train_step` (the render) and by `render`.

        Returns:
            0..`config.sh_degree`; default +1 every `sh_increase_every` (scaled) steps.
        """
        return min(self.config.sh_degree, step // self.every(self.config.sh_increase_every))

    def strategy_step(self, step: int) -> int:
        """The step number the densification strategy sees. Called once per step in `train_step`, before the render.

        Returns:
            a 1-based step; default `step` itself (STRinGS restarts the count in phase 2).
        """
        return step

    def on_step_start(self, step: int) -> None:
        """Called first in every `train_step`, before anything is rendered; a phase switch calls
        `self.set_model(new_model)` here. Default: nothing.

        Args:
            step: the 1-based step about to run.
        """

    def skips_refinement(self, step: int) -> bool:
        """The phase-switch hook of `refine`: True skips the strategy's round at `step` (its gradients are
        zeroed, its statistics not taken). False here; STRinGS hands phase 1 over before T1's refinement."""
        return False

    def checkpoint_extra(self, step: int) -> dict:
        """Method statistics stored in the checkpoint's result (`CheckpointResult.extra`, then result.json). Called
        at each checkpoint after the test views are rendered, before `refine(step)`.

        Returns:
            a JSON-serialisable dict; default the steps scale, the paper iteration, the SH degree, the last loss,
            the peak Gaussian count and the motion log's summary. Extend it with `{**super().checkpoint_extra(step), ...}`.
        """
        extra = {"steps_scale": self.config.steps_scale, "paper_iteration": round(step / self.config.steps_scale),
                 "sh_degree": self.sh_degree_for_step(step), "last_loss": self.last_loss,
                 "peak_gaussians": int(self.size_log["peak_gaussians"]), **motion_record(self.motion_log)}
        if self.context.budget is not None:
            extra["budget_reached_at"] = self.size_log["budget_reached_at"]  # a step, or None: never filled
        return extra

    def note_model_size(self, step: int) -> None:
        """Update `size_log` after the model may have grown (a refinement, a phase switch): the peak count, and the first
        step at which the budget now in force held the model (`Strategy.budget_holds`)."""
        self.size_log["peak_gaussians"] = max(int(self.size_log["peak_gaussians"]), len(self.model))
        if self.strategy.budget_holds(self.model) and self.size_log["budget_reached_at"] is None:
            self.size_log["budget_reached_at"] = int(step)

    # ---- model / optimizer ---------------------------------------------------------------------
    def make_optimizer(self, model: GaussianModel) -> GaussianAdam:
        """The optimizer of `model`. Called by `set_model` (the initial model, a phase switch) and on resume.

        Returns:
            a `GaussianAdam` over `model.params`; default the 3DGS learning rates, the position's x scene extent.
        """
        return GaussianAdam(model.params, self.config.lrs.group_lrs(self.extent))

    def set_model(self, model: GaussianModel) -> None:
        """Start optimising `model`, with a fresh optimizer (`make_optimizer`) and strategy state. Called by `setup`
        with the initial model; call it from `on_step_start` to switch phase.

        Raises:
            TrainingError: `model` has no Gaussians.
            StringsBenchError: `model` already holds more Gaussians than the run's budget allows.
        """
        if len(model) == 0:
            raise TrainingError(f"the initial model for scene {self.scene.name} has no Gaussians",
                                hint="the SfM model (or the selected subset of points) is empty")
        self.model = model
        self.optimizer = self.make_optimizer(model)
        self.strategy_state = self.strategy.initialize_state(self.extent, [self.camera(i) for i in self.train_views()])
        budget_now = self.context.budget_now()  # the budget less what the method keeps free
        if budget_now is not None and len(model) > budget_now:
            budget, reserved = self.context.budget, self.budget_reserved()
            more = f" and {reserved} it adds later" if reserved else ""
            raise StringsBenchError(
                f"the budget of {budget} Gaussians is below what {self.name} starts from on {self.scene.name}: "
                f"{len(model)} Gaussians{more}; a budget stops densification, it cannot remove initial Gaussians",
                hint="give a larger --budget (at least the scene's SfM point count)")
        self.note_model_size(self.step)

    def budget_reserved(self) -> int:
        """Gaussians this method will add by itself later (outside the strategy), kept free of the budget
        (`StrategyContext.budget_now`). Called by `set_model`.

        Returns:
            a count, 0 here; STRinGS' phase 1 keeps the non-text points that join at T1.
        """
        return 0

    def target(self, view_idx: int) -> torch.Tensor:
        """The ground-truth image of a view, (H, W, 3) float32 on the method's device (kept once loaded)."""
        if view_idx not in self._targets:
            img = self.scene.load_image(view_idx, self.downscale)
            self._targets[view_idx] = torch.from_numpy(np.array(img, dtype=np.float32)).to(self.device)
        return self._targets[view_idx]

    def preload_targets(self, views) -> None:
        """Decode the images of `views` into `target()`'s cache, a few at a time in threads (PIL
        releases the GIL). `setup` preloads the training views, as the 3DGS reference loads its
        images before training: decoding is data loading (preprocess_seconds), not an optimisation
        step, and a quick schedule whose first epoch is its whole run would otherwise decode an
        image in every timed step."""
        from concurrent.futures import ThreadPoolExecutor

        todo = [int(v) for v in dict.fromkeys(views) if int(v) not in self._targets]
        if not todo:
            return
        with ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1, len(todo)))) as pool:
            images = list(pool.map(lambda v: self.scene.load_image(v, self.downscale), todo))
        for v, img in zip(todo, images):
            self._targets[v] = torch.from_numpy(np.array(img, dtype=np.float32)).to(self.device)

    def camera(self, view_idx: int):
        """The view's camera at the training downscale (built once: a downscaled camera is a new object)."""
        cam = self._cameras.get(view_idx)
        if cam is None:
            cam = self._cameras[view_idx] = self.scene.camera(view_idx, self.downscale)
        return cam

    def render_raster(self, view_idx: int, sh_degree: int | None = None, model: GaussianModel | None = None, **kw):
        """Render a view. Called once per step in `train_step` (with the strategy's `get_raster_kwargs`) and by
        `render` at checkpoints.

        Args:
            view_idx: the scene view.
            sh_degree: the SH bands used (None: all the model holds).
            model: what to render (default: the model being trained).
            **kw: further `rasterize` arguments (`mip_filter`, `compute_absgrad`).
        Returns:
            the `RasterOutput` (colour (H, W, 3), alpha, depth, radii, means2d) at the training resolution.
        """
        model = self.model if model is None else model
        return model.render(self.camera(view_idx), self.background, sh_degree=sh_degree,
                            backend=self.config.backend, **kw)

    def model_to_render(self) -> GaussianModel:
        """The model that checkpoint renders show. Called by `render` at each checkpoint.

        Returns:
            a `GaussianModel`; default the trained one (Mip-Splatting: its 3D filter folded in).
        """
        return self.model

    # ---- the protocol ----------------------------------------------------------------------------
    def train_step(self, step: int) -> float:
        """One optimisation step (see `Method.train_step`), called by the loop for step = 1, 2, ...: the hooks in
        this order: `on_step_start`, `position_lr`, `views_for_step`, `strategy_step`, `render_raster`, the
        strategy's `step_pre_backward`, `loss` plus the strategy's `loss_terms`, backward, finite checks,
        `position_lr_scale`, then Adam.

        Returns:
            the step's loss (a float).
        Raises:
            TrainingError: a non-finite loss, gradient or parameter, naming the iteration and parameter groups.
        """
        self.step = step
        self.on_step_start(step)
        model, opt, strategy = self.model, self.optimizer, self.strategy
        # The rasterizer may cull a Gaussian with NaN parameters without a NaN loss: check the values too.
        with torch.no_grad():
            if not sums_finite(model.params.values()):
                raise self._nonfinite_error(step, "a parameter is not finite")
        opt.set_lr("means", self.position_lr(step))
        view = self.views_for_step(step)
        cam = self.camera(view)
        sstep = self.strategy_step(step)
        out = self.render_raster(view, sh_degree=self.sh_degree_for_step(step), **strategy.get_raster_kwargs(sstep))
        info = {"raster": out, "means2d": out.means2d, "radii": out.radii, "width": cam.width,
                "height": cam.height, "n_cameras": 1, "view_idx": view, "camera": cam}
        strategy.step_pre_backward(model, opt, self.strategy_state, sstep, info)
        note("render", color=out.color)  # a profiling tool's mark: the loss's backward ends at this image's gradient
        with timed("loss"):
            loss = self.loss(out, self.target(view), view, step)
        extra = strategy.loss_terms(model, info, sstep)
        if torch.is_tensor(extra) or extra:
            loss = loss + extra
        value = float(loss.detach())
        if not math.isfinite(value):
            raise self._nonfinite_error(step, f"the loss is {value}")
        with timed("backward"):
            loss.backward()
        grads = [p.grad for p in model.params.values() if p.grad is not None]
        # One reduction per group: a sum is non-finite when any element is, or when the gradients are so
        # large (> 3e38 in total) that the run has diverged anyway (sums_finite: on the numba threads).
        if grads and not sums_finite(grads):
            bad_grads = [k for k, p in model.params.items() if p.grad is not None and not torch.isfinite(p.grad).all()]
            bad_grads = bad_grads or [k for k, p in model.params.items() if p.grad is not None
                                      and not sums_finite([p.grad])]
            raise self._nonfinite_error(step, f"the gradient of {', '.join(bad_grads)} is not finite", bad_grads)
        scale = self.position_lr_scale(step)
        row_scale = None
        if scale is not None:
            if torch.is_tensor(scale) and scale.ndim >= 1:
                row_scale = {"means": scale}
            else:
                opt.set_lr("means", opt.lrs["means"] * float(scale))
        before = model.params["means"].detach().clone()  # for the motion log; the update itself is untouched
        opt.step(row_scale)
        note_motion(self.motion_log, before, model.params["means"].detach(), self.extent, model.extras.get("is_text"))
        self.last_loss = value
        self._step_info = (step, sstep, info)
        return value

    def refine(self, step: int) -> None:
        """The strategy's post-backward work for `step` (`step_post_backward`: densify, prune, reset), then zero the
        gradients. Called by the loop after `train_step(step)`, and after the checkpoint of `step` was evaluated."""
        if self._step_info is None or self._step_info[0] != step:
            return
        _, sstep, info = self._step_info
        self._step_info = None
        if self.skips_refinement(step):
            self.optimizer.zero_grad()
            return
        count = len(self.model)
        self.strategy.step_post_backward(self.model, self.optimizer, self.strategy_state, sstep, info)
        if len(self.model) != count:
            self.motion_log["count_changes"] += 1
        self.optimizer.zero_grad()
        self.note_model_size(step)

    @torch.no_grad()
    def render(self, view_idx: int) -> np.ndarray:
        """The current model's render of view `view_idx` at the step's SH degree. Called at each checkpoint, once per
        test view, after `train_step` and before `refine`.

        Returns:
            (H, W, 3) float32 in [0, 1], at the training downscale.
        """
        out = self.render_raster(view_idx, sh_degree=self.sh_degree_for_step(self.step), model=self.model_to_render())
        return out.color.detach().clamp(0, 1).cpu().numpy().astype(np.float32)

    def num_gaussians(self) -> int:
        """Gaussians in the current model (0 before `setup`). Called at each checkpoint and for the budget."""
        return len(self.model) if self.model is not None else 0

    def save_model(self, path) -> None:
        """Write the model as a 3DGS PLY to `path` (atomic). Called at checkpoints with `run --keep-models`, and by
        `methods check`."""
        from strings_bench.engine.ply import write_ply

        write_ply(path, self.model)

    # ---- resumable state -------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything needed to continue bit for bit: step, model, Adam moments, strategy statistics
        (tensors on the CPU, generators as their state), the view-order generator and stack, the last
        loss, and `extra_state()`. Called when the training state is saved: at checkpoints and every
        `--save-every`."""
        return {
            "step": self.step,
            "model": self.model.state_dict(),
            "optimizer": _state_to_cpu(self.optimizer.state_dict()),
            "strategy_state": _state_to_cpu(self.strategy_state),
            "rng": self.rng.bit_generator.state,
            "view_stack": list(self._view_stack),
            "view_key": self._view_key,
            "last_loss": self.last_loss,
            "size_log": dict(self.size_log),
            "motion_log": dict(self.motion_log),
            "extra": self.extra_state(),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore `state_dict()` (the `state` given) after `setup()`, on this method's device. Called on resume,
        before the first step run again."""
        model = GaussianModel.from_state_dict(state["model"], device=self.device)
        self.model = model
        self.optimizer = self.make_optimizer(model)
        self.optimizer.load_state_dict(_state_to_device(state["optimizer"], self.device))
        self.strategy_state = _state_to_device(state["strategy_state"], self.device)
        self.rng.bit_generator.state = state["rng"]
        self._view_stack = list(state["view_stack"])
        self._view_key = state["view_key"]
        self.last_loss = state["last_loss"]
        # states saved before the size log existed start it at the loaded model's size
        self.size_log = dict(state.get("size_log") or {"peak_gaussians": len(model), "budget_reached_at": None})
        self.step = int(state["step"])
        # states saved before the motion log existed: it counts from the loaded step on (its `from_step`)
        self.motion_log = dict(state.get("motion_log") or new_motion_log(from_step=self.step))
        self.load_extra_state(state.get("extra") or {})

    def extra_state(self) -> dict:
        """A subclass's own resumable state (phase flags, ...). Called by `state_dict` when the training state is
        saved (at checkpoints and every `--save-every` minutes).

        Returns:
            anything `torch.save` can store; default {}.
        """
        return {}

    def load_extra_state(self, state: dict) -> None:
        """Restore `extra_state()`. Called by `load_state_dict` on resume, after `setup`. Default: nothing.

        Args:
            state: what `extra_state()` returned ({} for a state saved without it).
        """

    def _nonfinite_error(self, step: int, what: str, groups: list[str] | None = None) -> TrainingError:
        bad_params = [k for k, p in self.model.params.items() if not torch.isfinite(p.detach()).all()]
        parts = [what]
        if bad_params:
            parts.append(f"non-finite values in parameter group(s) {', '.join(bad_params)}")
        elif groups is None:
            parts.append("every parameter is finite (the render or the loss itself produced it)")
        return TrainingError(
            f"training of {self.scene.name} diverged at iteration {step}: " + "; ".join(parts),
            hint="lower the learning rate of the named group, check the scene's images and poses, or use another seed")
