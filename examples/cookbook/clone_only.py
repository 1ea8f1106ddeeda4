"""Cookbook: a densification strategy of your own. 3DGS' adaptive density control, but Gaussians are only ever
cloned, never split (docs/cookbook/densification.md).

Run it:  python examples/cookbook/clone_only.py   (trains 3DGS and CloneOnlySplat on a tiny scene, 100 steps each)
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.engine.strategies import DefaultStrategy
from strings_bench.methods import MethodSpec


@dataclass
class CloneOnlyStrategy(DefaultStrategy):
    """3DGS densification whose large candidates are cloned as well: `_select` is the one step overridden."""

    clone_large: bool = True  # clone the Gaussians 3DGS would split (False: 3DGS' own rule)

    def _select(self, model, state, step):
        clone, split = super()._select(model, state, step)  # (N,) bool masks: 3DGS' choice
        if self.clone_large:
            clone, split = clone | split, torch.zeros_like(split)
        return clone, split


class CloneOnlySplat(GaussianSplatting):
    """3DGS with `CloneOnlyStrategy`: every other hook (loss, schedule, initialisation) is 3DGS'."""

    strategy_cls = CloneOnlyStrategy  # its fields become settings: --set clone-only.clone_large=false


SPEC = MethodSpec(name="clone-only", implementation=CloneOnlySplat,
                  description="3DGS whose densification clones and never splits (a cookbook recipe)")


def main() -> None:
    from strings_bench.bench.check import tiny_scene
    from strings_bench.engine.trainer import Trainer
    from strings_bench.methods import get_method
    from strings_bench.scene.scene import Scene

    scene = Scene.load(tiny_scene())  # 96x72, 8 views, built into the cache on first use
    for method in (get_method("3dgs").build(steps_scale=0.01), SPEC.build(steps_scale=0.01)):
        results = list(Trainer(method, scene, checkpoints=[100], device="cpu", seed=0, progress=False).train())
        state = method.strategy_state
        print(f"{method.name:10s} {results[-1].gaussians:5d} Gaussians after 100 steps; "
              f"last round: {state['last_clone']} cloned, {state['last_split']} split")


if __name__ == "__main__":
    main()
