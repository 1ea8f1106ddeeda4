"""Vanilla 3D Gaussian Splatting (Kerbl et al., SIGGRAPH 2023) on the suite's engine.

Settings (flat, see trainer.config_from_settings): TrainConfig fields (steps_scale, seed,
sh_degree, background, device, backend, ply_dir, ...), `lr_<group>` learning rates, and
DefaultStrategy fields. The opacity LR defaults to the paper's 0.05; the 2024 3DGS release uses
0.025 (`lr_opacity_logits=0.025`).
"""

from __future__ import annotations

from typing import Iterator

from strings_bench.core.schedules import schedule_presets
from strings_bench.engine.strategies.default import DefaultStrategy
from strings_bench.core.method import CheckpointResult, MethodAdapter
from strings_bench.methods.registry import MethodSpec, register_method

PAPER_CHECKPOINTS = (7000, 30000)
PAPER = "Kerbl, Kopanas, Leimkuehler, Drettakis: 3D Gaussian Splatting for Real-Time Radiance Field Rendering (SIGGRAPH 2023)"


class GS3DAdapter(MethodAdapter):
    name = "3dgs"
    paper = PAPER
    strategy_cls = DefaultStrategy

    def make_trainer(self, scene, checkpoints, downscale):
        from strings_bench.engine.trainer import Trainer, config_from_settings

        config, strategy = config_from_settings(self.settings, checkpoints, downscale, self.strategy_cls)
        config.progress = config.progress and self.progress
        return Trainer(scene, config, strategy)

    def train(self, scene, checkpoints=None, downscale: float = 1) -> Iterator[CheckpointResult]:
        """`checkpoints` are the steps to run to (the runner passes round(paper iteration x steps_scale));
        by default the scaled 7K and 30K."""
        if checkpoints is None:
            s = float(self.settings.get("steps_scale", 1.0))
            checkpoints = sorted({max(1, round(c * s)) for c in PAPER_CHECKPOINTS})
        yield from self.make_trainer(scene, checkpoints, downscale).train()


SPEC = register_method(MethodSpec(
    name="3dgs",
    factory=GS3DAdapter,
    description="vanilla 3DGS: SfM init, Adam, adaptive density control (clone/split/prune, opacity reset)",
    paper=PAPER,
    defaults={"steps_scale": 1.0},
    presets=schedule_presets(),  # paper 1.0, standard 0.05, quick 0.01, tiny 0.005 (the runner picks checkpoints)
))
