"""Perceptual-GS' spec (the method: perceptual_gs.py); beyond the paper's table, no published figures."""

from strings_bench.methods.spec import MethodSpec

SPEC = MethodSpec(
    name="perceptual-gs", title="Perceptual-GS", implementation="strings_bench.methods.perceptual_gs:PerceptualGS",
    description="Perceptual-GS: learned per-Gaussian perceptual sensitivity (BCE to Sobel-based maps) drives "
                "extra densification of high/medium-sensitivity Gaussians, opacity decline of clones",
    paper="Zhou, Ni: Perceptual-GS: Scene-adaptive Perceptual Densification for Gaussian Splatting (ICML 2025, "
          "arXiv 2506.12400); release github.com/eezkni/Perceptual-GS")
