"""Improved-GS' spec (the method: improved_gs.py); beyond the paper's table, no published figures."""

from strings_bench.methods.spec import MethodSpec

SPEC = MethodSpec(
    name="improved-gs", title="Improved-GS", implementation="strings_bench.methods.improved_gs:ImprovedGS",
    description="Improved-GS: edge-aware score, growth control to a Gaussian budget, long-axis split, "
                "recovery-aware pruning, multi-step update",
    paper="Deng, Diao, Li, Yu, Xu: Improving Densification in 3D Gaussian Splatting for High-Fidelity "
          "Rendering (arXiv 2508.12313, 2025); release github.com/XiaoBin2001/Imporved-GS",
    # the release's arguments/__init__.py: position 4e-5 -> 2e-6, opacity 0.025, SH rest 0.005 / 20
    defaults={"lr_means": 4e-5, "lr_means_final": 2e-6, "lr_opacity_logits": 0.025, "lr_shN": 0.005 / 20})
