"""EDC-AbsGS' spec (the method: edc_absgs.py)."""

from strings_bench.methods.spec import MethodSpec, PaperFigures

SPEC = MethodSpec(
    name="edc-absgs", title="EDC-AbsGS", implementation="strings_bench.methods.edc_absgs:EDCAbsGS",
    description="EDC-AbsGS: long-axis split (no clone) on the absolute gradient, recovery-aware pruning, "
                "position LR 4e-5 -> 2e-6",
    paper="Deng, Diao, Li, Chen, Zhang: Efficient Density Control for 3D Gaussian Splatting (arXiv 2024), on AbsGS",
    defaults={"lr_means": 4e-5, "lr_means_final": 2e-6},
    paper_figures=PaperFigures.table1(tandt=(.142, .118), dl3dv=(.239, .162), strings360=(.328, .116),
                                      minutes=(5.5, 23.2)))
