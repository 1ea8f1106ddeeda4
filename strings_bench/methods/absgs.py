"""AbsGS (Ye et al., ACM MM 2024) on the suite's engine: vanilla 3DGS with the split decision taken
on the absolute screen-space gradient (engine/strategies/absgs.py; docs/baselines.md).

Settings: as 3dgs, plus AbsGSStrategy fields (grow_grad2d = 2e-4 for cloning, grow_grad2d_abs =
4e-4 for splitting, ...).
"""

from __future__ import annotations

from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.engine.strategies.absgs import AbsGSStrategy



class AbsGS(GaussianSplatting):
    strategy_cls = AbsGSStrategy
