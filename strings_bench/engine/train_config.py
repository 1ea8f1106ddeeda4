"""The training settings of every Gaussian method: `TrainConfig` (3DGS' own, with the learning rates) and how a
flat settings dict (`--set` keys) splits into a `TrainConfig` and the method's strategy (`config_from_settings`).

`engine.splatting.GaussianSplatting` is built from them (`from_settings`); they are apart from it because they are
read without building a method (the settings schema, `strings-bench methods show`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.optim import LearningRates
from strings_bench.engine.strategies.base import MIN_SCALED_INTERVAL, Strategy, StrategyContext
from strings_bench.engine.strategies.default import DefaultStrategy


@dataclass
class TrainConfig:
    """The 3DGS training settings (flat `--set` keys of every Gaussian method, with `lr_<group>`)."""

    steps_scale: float = 1.0  # multiplies every iteration number (quick runs)
    seed: int = 0  # seeds the view order and torch/numpy/random
    sh_degree: int = 3  # highest spherical-harmonics degree
    sh_increase_every: int = 1_000  # the SH degree rises by one every this many (nominal) steps
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)  # 3DGS default (black)
    lrs: LearningRates = field(default_factory=LearningRates)
    position_lr_steps: int = 30_000  # nominal length of the position-LR decay
    # A shrunk schedule's miniature `lr-sum` sets 1/steps_scale, so that the LR's sum over a run (how far a
    # Gaussian can move) is the paper's.
    position_lr_gain: float = 1.0  # x the position LR at every step (1: the paper's; miniature lr-sum: 1/steps_scale)
    # The miniature `rounds` sets 1, so that a shrunk run refines as many times as the paper's (an interval of 100
    # at x0.1 is 10 steps) instead of at least every 50 steps.
    interval_floor: int = MIN_SCALED_INTERVAL  # shortest refinement / SH interval of a shrunk run, in steps
    gaussian_budget: int | None = None  # the run's equal Gaussian budget (run --budget; never --set); None: none
    lambda_dssim: float = 0.2  # loss = (1 - l) L1 + l (1 - SSIM)
    init_opacity: float = 0.1  # opacity of the initial Gaussians
    backend: str = "auto"  # rasterizer backend: auto, cpu (float32 blends), cpu-f64 (float64 reference), gsplat

    def __post_init__(self):
        if self.steps_scale <= 0:
            raise StringsBenchError(f"steps_scale must be > 0, got {self.steps_scale}")
        if not (math.isfinite(self.position_lr_gain) and self.position_lr_gain > 0):
            raise StringsBenchError(f"position_lr_gain must be a finite number > 0, got {self.position_lr_gain}")
        if isinstance(self.interval_floor, bool) or int(self.interval_floor) != self.interval_floor \
                or self.interval_floor < 1:
            raise StringsBenchError(f"interval_floor must be a whole number of steps >= 1, got {self.interval_floor}")
        StrategyContext(budget=self.gaussian_budget)  # refuses a budget that is not a positive whole number


def settings_keys(strategy_cls: type[Strategy] = DefaultStrategy) -> dict[str, str]:
    """Every flat setting a Gaussian method takes -> where it goes ("train", "lr", "strategy")."""
    from dataclasses import fields as dc_fields

    keys = {f.name: "train" for f in dc_fields(TrainConfig) if f.name != "lrs"}
    keys.update({f"lr_{f.name}": "lr" for f in dc_fields(LearningRates)})
    for f in dc_fields(strategy_cls):
        if not f.metadata.get("setting", True):  # the strategy's context: given by the method
            continue
        keys[f.name] = "train+strategy" if keys.get(f.name) == "train" else "strategy"
    return keys


def config_from_settings(settings: dict, strategy_cls: type[Strategy] = DefaultStrategy,
                         ignore: tuple[str, ...] = ()) -> tuple[TrainConfig, Strategy]:
    """Split a flat settings dict into (TrainConfig, strategy).

    Keys: TrainConfig fields (steps_scale, seed, sh_degree, background, ...), learning rates as
    `lr_<group>` (lr_means, lr_means_final, lr_opacity_logits, ...), and fields of `strategy_cls`
    (grow_grad2d, refine_every, ...). Unknown keys are an error (typos must not pass silently);
    keys in `ignore` are left to the caller. A key that is both a TrainConfig and a strategy field
    (`seed`: the trainer's seed and MCMC's sampling generator) goes to both.
    """
    where = settings_keys(strategy_cls)
    cfg_kw, lr_kw, strat_kw, unknown = {}, {}, {}, []
    for key, value in settings.items():
        if key in ignore:
            continue
        dest = where.get(key)
        if dest is None:
            unknown.append(key)
            continue
        if "train" in dest:
            cfg_kw[key] = value
        if "strategy" in dest:
            strat_kw[key] = value
        if dest == "lr":
            lr_kw[key[3:]] = float(value)
    if unknown:
        raise StringsBenchError(f"unknown setting(s) {', '.join(sorted(unknown))}",
                                hint=f"valid settings: {', '.join(sorted(set(where) | set(ignore)))}")
    if "background" in cfg_kw:
        cfg_kw["background"] = tuple(float(x) for x in cfg_kw["background"])
    return TrainConfig(lrs=LearningRates(**lr_kw), **cfg_kw), strategy_cls(**strat_kw)
