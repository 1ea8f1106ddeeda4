"""AbsGS (Ye et al., ACM MM 2024) on the suite's engine: vanilla 3DGS with the split decision taken
on the absolute screen-space gradient (strategies/absgs.py; docs/baselines.md).

Settings: as 3dgs (TrainConfig fields, `lr_<group>`), plus AbsGSStrategy fields
(grow_grad2d = 2e-4 for cloning, grow_grad2d_abs = 4e-4 for splitting, ...).
"""

from __future__ import annotations

import copy

from strings_bench.engine.strategies.absgs import AbsGSStrategy
from strings_bench.methods.gs3d import SPEC as GS3D_SPEC
from strings_bench.methods.gs3d import GS3DAdapter
from strings_bench.methods.registry import MethodSpec, register_method

PAPER = "Ye, Li, Zhang, Huang, Ma, Zhou: AbsGS: Recovering Fine Details for 3D Gaussian Splatting (ACM MM 2024)"


class AbsGSAdapter(GS3DAdapter):
    name = "absgs"
    paper = PAPER
    strategy_cls = AbsGSStrategy


SPEC = register_method(MethodSpec(
    name="absgs",
    factory=AbsGSAdapter,
    description="AbsGS: 3DGS densification with splits selected on the absolute (per-pixel |dL/dmean2d| summed) gradient",
    paper=PAPER,
    defaults={"steps_scale": 1.0},
    presets=copy.deepcopy(GS3D_SPEC.presets),  # same schedules as 3dgs
))
