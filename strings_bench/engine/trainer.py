"""The training loop shared by every method.

`Trainer(scene, config, strategy).train()` optimises a GaussianModel and yields a
`CheckpointResult` at each requested checkpoint. Methods change behaviour by subclassing and
overriding the hooks (see docs/engine.md):

    initial_model(scene)            -> GaussianModel                 (default: 3DGS init from SfM points)
    train_views()                   -> list of view indices          (default: scene.train_idx)
    views_for_step(step)            -> view index                    (default: shuffled per epoch, seeded)
    loss(out, gt, view_idx, step)   -> scalar tensor                 (default: 0.8 L1 + 0.2 (1 - SSIM))
    position_lr(step)               -> float                         (default: 3DGS exponential schedule)
    position_lr_scale(step)         -> None | float | (N,) tensor    (per-row factor on the position step)
    sh_degree_for_step(step)        -> int                           (default: +1 every 1000 x steps_scale)
    strategy_step(step)             -> int                           (step number the strategy sees)
    on_step_start(step)             -> None                          (e.g. switch phase: self.set_model(...))
    checkpoint_extra(step)          -> dict                          (method stats for CheckpointResult.extra)

Steps are 1-based, as in 3DGS. Checkpoints are the steps actually run (as the runner asks for them:
round(paper iteration x steps_scale)); every schedule inside (densification, opacity reset, SH degree,
position-LR decay) is its nominal 3DGS iteration number multiplied by `steps_scale`.

Training time counts the optimisation steps only (render, loss, backward, Adam, densification),
not the checkpoint renders or file writes. Preprocess time (CheckpointResult.preprocess_seconds) is
the method's work before the first step: `self.preprocess_seconds` (set by an adapter for work done
before the trainer exists, e.g. STRinGS' masks and Algorithm 1) plus building the initial model
(nearest-neighbour scales; STRinGS' Eq. 1). Peak memory is the process's peak resident set size
(resource.getrusage ru_maxrss; it is a process-lifetime peak, so it includes earlier work in the
same process), or torch.cuda.max_memory_allocated on a CUDA device.
"""

from __future__ import annotations

import logging
import math
import random
import resource
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError, TrainingError
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.losses import gs_loss
from strings_bench.core.method import CheckpointResult
from strings_bench.engine.optim import GaussianAdam, LearningRates, exponential_lr
from strings_bench.engine.strategies.base import Strategy, scaled_interval, scaled_step
from strings_bench.engine.strategies.default import DefaultStrategy

if TYPE_CHECKING:
    from strings_bench.scene.scene import Scene

log = logging.getLogger(__name__)


@dataclass
class TrainConfig:
    checkpoints: tuple[int, ...] = (7_000, 30_000)  # steps actually run (already x steps_scale)
    steps_scale: float = 1.0  # multiplies every iteration number (quick runs)
    seed: int = 0
    sh_degree: int = 3
    sh_increase_every: int = 1_000
    downscale: float = 1
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)  # 3DGS default (black)
    lrs: LearningRates = field(default_factory=LearningRates)
    position_lr_steps: int = 30_000  # nominal length of the position-LR decay
    lambda_dssim: float = 0.2
    init_opacity: float = 0.1
    device: str = "cpu"
    backend: str = "auto"  # rasterizer backend
    progress: bool = True
    ply_dir: str | None = None  # write <ply_dir>/iteration_<step>.ply at each checkpoint
    render_test: bool = True

    def __post_init__(self):
        if self.steps_scale <= 0:
            raise StringsBenchError(f"steps_scale must be > 0, got {self.steps_scale}")
        if not self.checkpoints or any(int(c) <= 0 for c in self.checkpoints):
            raise StringsBenchError(f"checkpoints must be positive iteration numbers, got {self.checkpoints}")


def peak_memory_mb(device: str | torch.device = "cpu") -> float:
    if torch.device(device).type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2 ** 20
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 2 ** 20 if sys.platform == "darwin" else rss / 2 ** 10  # bytes on macOS, KiB on Linux


class Trainer:
    def __init__(self, scene: "Scene", config: TrainConfig | None = None, strategy: Strategy | None = None,
                 model: GaussianModel | None = None):
        self.scene = scene
        self.config = config or TrainConfig()
        self.strategy = strategy if strategy is not None else DefaultStrategy()
        self.extent = float(scene.extent)
        self.device = torch.device(self.config.device)
        self._given_model = model
        self.model: GaussianModel | None = None
        self.optimizer: GaussianAdam | None = None
        self.strategy_state: dict = {}
        self.rng = np.random.default_rng(self.config.seed)
        self._view_stack: list[int] = []
        self._view_key: tuple | None = None
        self._targets: dict[int, torch.Tensor] = {}
        self.background = torch.tensor(self.config.background, dtype=torch.float32, device=self.device)
        self.last_loss = float("nan")
        self.preprocess_seconds = 0.0  # work before the trainer (adapters add theirs)
        self.init_seconds = 0.0  # building the initial model (measured in train())

    # ---- schedule helpers -------------------------------------------------------------------
    def at(self, nominal: float) -> int:
        return scaled_step(nominal, self.config.steps_scale)

    def every(self, nominal: float) -> int:
        return scaled_interval(nominal, self.config.steps_scale)

    # ---- hooks --------------------------------------------------------------------------------
    def initial_model(self, scene: "Scene") -> GaussianModel:
        return GaussianModel.from_points(scene.model.xyz, scene.model.rgb, sh_degree=self.config.sh_degree,
                                         init_opacity=self.config.init_opacity, device=self.device)

    def train_views(self) -> list[int]:
        return list(self.scene.train_idx)

    def views_for_step(self, step: int) -> int:
        """3DGS order: a random permutation of the training views, redrawn when used up."""
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

    def loss(self, out, gt: torch.Tensor, view_idx: int, step: int) -> torch.Tensor:
        return gs_loss(out.color, gt, self.config.lambda_dssim)

    def position_lr(self, step: int) -> float:
        lrs = self.config.lrs
        return exponential_lr(step, lrs.means * self.extent, lrs.means_final * self.extent,
                              self.at(self.config.position_lr_steps))

    def position_lr_scale(self, step: int):
        return None

    def sh_degree_for_step(self, step: int) -> int:
        return min(self.config.sh_degree, step // self.every(self.config.sh_increase_every))

    def strategy_step(self, step: int) -> int:
        return step

    def on_step_start(self, step: int) -> None:
        pass

    def checkpoint_extra(self, step: int) -> dict:
        return {}

    # ---- model / optimizer ---------------------------------------------------------------------
    def make_optimizer(self, model: GaussianModel) -> GaussianAdam:
        return GaussianAdam(model.params, self.config.lrs.group_lrs(self.extent))

    def set_model(self, model: GaussianModel) -> None:
        """Start optimising `model` (fresh Adam state and strategy state): initial model, phase switches."""
        if len(model) == 0:
            raise TrainingError(f"the initial model for scene {self.scene.name} has no Gaussians",
                                hint="the SfM model (or the selected subset of points) is empty")
        self.model = model
        self.optimizer = self.make_optimizer(model)
        self.strategy_state = self.strategy.initialize_state(self.extent, self.config.steps_scale)

    def target(self, view_idx: int) -> torch.Tensor:
        if view_idx not in self._targets:
            img = self.scene.load_image(view_idx, self.config.downscale)
            self._targets[view_idx] = torch.from_numpy(np.array(img, dtype=np.float32)).to(self.device)
        return self._targets[view_idx]

    def camera(self, view_idx: int):
        return self.scene.camera(view_idx, self.config.downscale)

    def render(self, view_idx: int, sh_degree: int | None = None, **kw):
        return self.model.render(self.camera(view_idx), self.background, sh_degree=sh_degree,
                                 backend=self.config.backend, **kw)

    # ---- the loop --------------------------------------------------------------------------------
    def seed_everything(self) -> None:
        torch.manual_seed(self.config.seed)
        random.seed(self.config.seed)
        np.random.seed(self.config.seed)
        self.rng = np.random.default_rng(self.config.seed)

    def checkpoint_steps(self, checkpoints=None) -> list[int]:
        steps = sorted({int(c) for c in (checkpoints or self.config.checkpoints)})
        if steps[0] < 1:
            raise StringsBenchError(f"checkpoint iterations must be >= 1, got {steps}")
        return steps

    def train(self, checkpoints=None) -> Iterator[CheckpointResult]:
        from tqdm.auto import tqdm

        self.seed_everything()
        self._deferred_refinement = None
        t0 = time.perf_counter()
        self.set_model(self._given_model if self._given_model is not None else self.initial_model(self.scene))
        self.init_seconds = time.perf_counter() - t0
        at_steps = set(self.checkpoint_steps(checkpoints))
        total = max(at_steps)
        train_seconds = 0.0
        bar = tqdm(total=total, desc=f"train {self.scene.name}", disable=not self.config.progress, leave=False,
                   dynamic_ncols=True)
        try:
            for step in range(1, total + 1):
                t0 = time.perf_counter()
                # At a checkpoint the model is evaluated after the step's optimizer update but before
                # that step's densification / opacity reset, as the reference code saves before it
                # densifies; otherwise a reset landing on a checkpoint step (e.g. 3K in 3DGS) would be
                # evaluated at opacity 0.01.
                self.train_step(step, defer_refinement=step in at_steps)
                train_seconds += time.perf_counter() - t0
                bar.update(1)
                if step % 10 == 0 or step == total:
                    bar.set_postfix(loss=f"{self.last_loss:.4f}", gaussians=len(self.model))
                if step in at_steps:
                    yield self.checkpoint(step, train_seconds)
                    if self._deferred_refinement is not None:  # the step completes as the reference's does
                        t0 = time.perf_counter()
                        self._deferred_refinement()
                        train_seconds += time.perf_counter() - t0
        finally:
            bar.close()

    def train_step(self, step: int, defer_refinement: bool = False) -> float:
        """One optimisation step. With defer_refinement the strategy's post-backward work (densify,
        reset) is kept in self._deferred_refinement for the caller to run after a checkpoint."""
        self.on_step_start(step)
        model, opt, strategy = self.model, self.optimizer, self.strategy
        # The rasterizer may cull a Gaussian with NaN parameters without a NaN loss: check the values too.
        with torch.no_grad():
            if not torch.isfinite(torch.stack([p.sum() for p in model.params.values()])).all():
                raise self._nonfinite_error(step, "a parameter is not finite")
        opt.set_lr("means", self.position_lr(step))
        view = self.views_for_step(step)
        cam = self.camera(view)
        sstep = self.strategy_step(step)
        out = self.render(view, sh_degree=self.sh_degree_for_step(step), **strategy.get_raster_kwargs(sstep))
        info = {"raster": out, "means2d": out.means2d, "radii": out.radii, "width": cam.width,
                "height": cam.height, "n_cameras": 1, "view_idx": view, "camera": cam}
        strategy.step_pre_backward(model, opt, self.strategy_state, sstep, info)
        loss = self.loss(out, self.target(view), view, step)
        extra = strategy.loss_terms(model, info, sstep)
        if torch.is_tensor(extra) or extra:
            loss = loss + extra
        value = float(loss.detach())
        if not math.isfinite(value):
            raise self._nonfinite_error(step, f"the loss is {value}")
        loss.backward()
        grads = [p.grad for p in model.params.values() if p.grad is not None]
        # One reduction per group: a sum is non-finite when any element is, or when the gradients are so
        # large (> 3e38 in total) that the run has diverged anyway.
        if grads and not torch.isfinite(torch.stack([g.sum() for g in grads])).all():
            bad_grads = [k for k, p in model.params.items() if p.grad is not None and not torch.isfinite(p.grad).all()]
            bad_grads = bad_grads or [k for k, p in model.params.items() if p.grad is not None
                                      and not torch.isfinite(p.grad.sum())]
            raise self._nonfinite_error(step, f"the gradient of {', '.join(bad_grads)} is not finite", bad_grads)
        scale = self.position_lr_scale(step)
        row_scale = None
        if scale is not None:
            if torch.is_tensor(scale) and scale.ndim >= 1:
                row_scale = {"means": scale}
            else:
                opt.set_lr("means", opt.lrs["means"] * float(scale))
        opt.step(row_scale)
        self.last_loss = value

        def refine() -> None:
            self._deferred_refinement = None
            strategy.step_post_backward(model, opt, self.strategy_state, sstep, info)
            opt.zero_grad()

        if defer_refinement:
            self._deferred_refinement = refine
        else:
            refine()
        return value

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

    # ---- checkpoints --------------------------------------------------------------------------------
    @torch.no_grad()
    def render_views(self, views: list[int], sh_degree: int | None = None) -> dict[str, np.ndarray]:
        out = {}
        for i in views:
            r = self.render(i, sh_degree=sh_degree)
            out[self.scene.names[i]] = r.color.detach().clamp(0, 1).cpu().numpy().astype(np.float32)
        return out

    def checkpoint(self, step: int, train_seconds: float) -> CheckpointResult:
        degree = self.sh_degree_for_step(step)
        renders = self.render_views(list(self.scene.test_idx), sh_degree=degree) if self.config.render_test else {}
        extra = {"steps_scale": self.config.steps_scale, "paper_iteration": round(step / self.config.steps_scale),
                 "sh_degree": degree,
                 "last_loss": self.last_loss, "init_seconds": self.init_seconds}
        if self.config.ply_dir:
            from strings_bench.scene.ply import write_ply

            path = Path(self.config.ply_dir) / f"iteration_{step}.ply"
            write_ply(path, self.model)
            extra["ply"] = str(path)
        extra.update(self.checkpoint_extra(step))
        return CheckpointResult(iteration=step, renders=renders, train_seconds=train_seconds,
                                gaussians=len(self.model), peak_memory_mb=peak_memory_mb(self.device), extra=extra,
                                preprocess_seconds=self.preprocess_seconds + self.init_seconds)


# ---- settings dicts (method presets, CLI --set) -> config + strategy ---------------------------------
def config_from_settings(settings: dict, checkpoints=None, downscale: float | None = None,
                         strategy_cls: type[Strategy] = DefaultStrategy, ignore: tuple[str, ...] = ()):
    """Split a flat settings dict into (TrainConfig, strategy).

    Keys: TrainConfig fields (steps_scale, seed, sh_degree, background, ...), learning rates as
    `lr_<group>` (lr_means, lr_means_final, lr_opacity_logits, ...), and fields of `strategy_cls`
    (grow_grad2d, refine_every, ...). Unknown keys are an error (typos must not pass silently);
    keys in `ignore` are left to the caller. A key that is both a TrainConfig and a strategy field
    (`seed`: the trainer's seed and MCMC's sampling generator) goes to both.
    """
    from dataclasses import fields as dc_fields

    cfg_fields = {f.name for f in dc_fields(TrainConfig)} - {"lrs"}
    lr_fields = {f.name for f in dc_fields(LearningRates)}
    strat_fields = {f.name for f in dc_fields(strategy_cls)}
    cfg_kw, lr_kw, strat_kw, unknown = {}, {}, {}, []
    for key, value in settings.items():
        if key in ignore:
            continue
        if key in cfg_fields or key in strat_fields:
            if key in cfg_fields:
                cfg_kw[key] = value
            if key in strat_fields:
                strat_kw[key] = value
        elif key.startswith("lr_") and key[3:] in lr_fields:
            lr_kw[key[3:]] = float(value)
        else:
            unknown.append(key)
    if unknown:
        raise StringsBenchError(
            f"unknown setting(s) {', '.join(sorted(unknown))}",
            hint=f"trainer settings: {', '.join(sorted(cfg_fields))}; learning rates: "
                 f"{', '.join('lr_' + f for f in sorted(lr_fields))}; strategy: {', '.join(sorted(strat_fields))}")
    if checkpoints is not None:
        cfg_kw["checkpoints"] = tuple(int(c) for c in checkpoints)
    elif "checkpoints" in cfg_kw:
        cfg_kw["checkpoints"] = tuple(int(c) for c in cfg_kw["checkpoints"])
    if downscale is not None:
        cfg_kw["downscale"] = downscale
    if "background" in cfg_kw:
        cfg_kw["background"] = tuple(float(x) for x in cfg_kw["background"])
    return TrainConfig(lrs=LearningRates(**lr_kw), **cfg_kw), strategy_cls(**strat_kw)
