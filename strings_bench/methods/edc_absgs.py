"""EDC-AbsGS (Deng et al. 2025, the implementation linked from their preprint) on the suite's engine:
long-axis split without cloning, selection on the absolute gradient, recovery-aware pruning after each
opacity reset, and a lower position learning rate (strategies/edc.py; docs/baselines.md).

Settings: as 3dgs, plus EDCStrategy fields (grow_grad2d_abs = 3.5e-4, split_offset, other_axes_factor,
opacity_factor, recovery_delay, recovery_prune_opa, release_schedule).
"""

from __future__ import annotations

import copy

from strings_bench.engine.strategies.edc import EDCStrategy
from strings_bench.methods.gs3d import SPEC as GS3D_SPEC
from strings_bench.methods.gs3d import GS3DAdapter
from strings_bench.methods.registry import MethodSpec, register_method

PAPER = ("Deng, Diao, Li, Chen, Zhang: Efficient Density Control for 3D Gaussian Splatting (arXiv 2024), "
         "on AbsGS; code github.com/XiaoBin2001/EDC")


class EDCAbsGSAdapter(GS3DAdapter):
    name = "edc-absgs"
    paper = PAPER
    strategy_cls = EDCStrategy


SPEC = register_method(MethodSpec(
    name="edc-absgs",
    factory=EDCAbsGSAdapter,
    description="EDC-AbsGS: long-axis split (no clone) on the absolute gradient, recovery-aware pruning, position LR 4e-5 -> 2e-6",
    paper=PAPER,
    defaults={"steps_scale": 1.0, "lr_means": 4e-5, "lr_means_final": 2e-6},
    presets=copy.deepcopy(GS3D_SPEC.presets),
))
