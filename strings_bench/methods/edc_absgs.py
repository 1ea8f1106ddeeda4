"""EDC-AbsGS (Deng et al. 2025, the implementation linked from their preprint) on the suite's engine:
long-axis split without cloning, selection on the absolute gradient, recovery-aware pruning after each
opacity reset, and a lower position learning rate (engine/strategies/edc.py; docs/baselines.md).

Settings: as 3dgs, plus EDCStrategy fields (grow_grad2d_abs = 3.5e-4, split_offset, other_axes_factor,
opacity_factor, recovery_delay, recovery_prune_opa, release_schedule). The spec's defaults set the
position LR to 4e-5 -> 2e-6.
"""

from __future__ import annotations

from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.engine.strategies.edc import EDCStrategy



class EDCAbsGS(GaussianSplatting):
    strategy_cls = EDCStrategy
