"""3DGS-MCMC (Kheradmand et al., NeurIPS 2024) on the suite's engine: relocation of dead Gaussians,
5 % growth up to a cap, opacity/scale regularisers and position noise (engine/strategies/mcmc.py;
docs/baselines.md).

Initialisation follows the public 3DGS-MCMC code: opacity 0.5 (the spec's `init_opacity`) and the
3DGS nearest-neighbour scale x 0.1 (`init_scale_factor`).

Settings: as 3dgs, plus `init_scale_factor` and MCMCStrategy fields (cap_max, cap_multiple,
grow_rate, min_opacity, opacity_reg, scale_reg, noise_lr, refine_start_iter/stop_iter/every, seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.engine.strategies.mcmc import MCMCStrategy



@dataclass(frozen=True)
class MCMCSettings:
    init_scale_factor: float = 0.1  # initial scales = 3DGS nearest-neighbour scale x this (public code)

    def __post_init__(self):
        if not self.init_scale_factor > 0:
            raise StringsBenchError(f"mcmc init_scale_factor must be > 0, got {self.init_scale_factor}")


class MCMC(GaussianSplatting):
    """3DGS init with the MCMC release's opacity (config.init_opacity) and scales x init_scale_factor."""

    strategy_cls = MCMCStrategy
    method_settings_cls = MCMCSettings

    def initial_model(self, scene):
        model = super().initial_model(scene)
        with torch.no_grad():
            model.params["log_scales"].add_(math.log(self.method_settings.init_scale_factor))
        return model
