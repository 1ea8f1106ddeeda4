"""Vanilla 3D Gaussian Splatting (Kerbl et al., SIGGRAPH 2023) on the suite's engine.

The implementation is the engine's reference method, `engine.splatting.GaussianSplatting`; this
module names it for the registry. Settings (flat, `strings-bench methods show 3dgs`): TrainConfig
fields (steps_scale, seed, sh_degree, background, backend, ...), `lr_<group>` learning rates, and
DefaultStrategy fields. The opacity LR defaults to the paper's 0.05; the 2024 3DGS release uses
0.025 (`lr_opacity_logits=0.025`).
"""

from __future__ import annotations

from strings_bench.engine.splatting import GaussianSplatting


class GS3D(GaussianSplatting):
    """3DGS as registered (`methods/gs3d_spec.py`, "3dgs"): the engine's reference method unchanged."""
