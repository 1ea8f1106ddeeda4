"""AbsGS' spec (the method: absgs.py)."""

from strings_bench.methods.spec import MethodSpec, PaperFigures

SPEC = MethodSpec(
    name="absgs", title="AbsGS", implementation="strings_bench.methods.absgs:AbsGS",
    description="AbsGS: 3DGS densification with splits selected on the absolute (per-pixel |dL/dmean2d| summed) "
                "gradient",
    paper="Ye, Li, Zhang, Huang, Ma, Zhou: AbsGS: Recovering Fine Details for 3D Gaussian Splatting (ACM MM 2024)",
    paper_figures=PaperFigures.table1(tandt=(.249, .137), dl3dv=(.411, .160), strings360=(.768, .143),
                                      minutes=(5.4, 22.5)))
