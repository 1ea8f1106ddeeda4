"""3DGS-MCMC (Kheradmand et al., NeurIPS 2024) on the suite's engine: relocation of dead Gaussians,
5 % growth up to a cap, opacity/scale regularisers and position noise (strategies/mcmc.py;
docs/baselines.md).

Initialisation follows the public 3DGS-MCMC code: opacity 0.5 (`init_opacity`) and the 3DGS
nearest-neighbour scale x 0.1 (`init_scale_factor`).

Settings: as 3dgs, plus `init_scale_factor` and MCMCStrategy fields (cap_max, cap_multiple,
grow_rate, min_opacity, opacity_reg, scale_reg, noise_lr, refine_start_iter/stop_iter/every).
"""

from __future__ import annotations

import copy
import math

import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.strategies.mcmc import MCMCStrategy
from strings_bench.methods.gs3d import SPEC as GS3D_SPEC
from strings_bench.methods.gs3d import GS3DAdapter
from strings_bench.methods.registry import MethodSpec, register_method

PAPER = ("Kheradmand, Rebain, Sharma, Sun, Tseng, Isack, Kar, Tagliasacchi, Yi: "
         "3D Gaussian Splatting as Markov Chain Monte Carlo (NeurIPS 2024)")
METHOD_KEYS = ("init_scale_factor",)


def _trainer_cls():
    from strings_bench.engine.trainer import Trainer

    class MCMCTrainer(Trainer):
        """3DGS init with the MCMC release's opacity (config.init_opacity) and scales x init_scale_factor."""

        init_scale_factor: float = 0.1

        def initial_model(self, scene):
            model = super().initial_model(scene)
            with torch.no_grad():
                model.params["log_scales"].add_(math.log(self.init_scale_factor))
            return model

    return MCMCTrainer


class MCMCAdapter(GS3DAdapter):
    name = "mcmc"
    paper = PAPER
    strategy_cls = MCMCStrategy

    def make_trainer(self, scene, checkpoints, downscale):
        from strings_bench.engine.trainer import config_from_settings

        config, strategy = config_from_settings(self.settings, checkpoints, downscale, self.strategy_cls,
                                                ignore=METHOD_KEYS)
        config.progress = config.progress and self.progress
        factor = float(self.settings.get("init_scale_factor", 0.1))
        if not factor > 0:
            raise StringsBenchError(f"mcmc init_scale_factor must be > 0, got {factor}")
        trainer = _trainer_cls()(scene, config, strategy)
        trainer.init_scale_factor = factor
        return trainer


SPEC = register_method(MethodSpec(
    name="mcmc",
    factory=MCMCAdapter,
    description="3DGS-MCMC: dead-Gaussian relocation (eq. 9), 5% growth to a cap, opacity/scale L1, SGLD position noise",
    paper=PAPER,
    defaults={"steps_scale": 1.0, "init_opacity": 0.5, "init_scale_factor": 0.1},
    presets=copy.deepcopy(GS3D_SPEC.presets),
))
