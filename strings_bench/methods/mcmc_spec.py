"""3DGS-MCMC's spec (the method: mcmc.py)."""

from strings_bench.methods.spec import MethodSpec, PaperFigures

SPEC = MethodSpec(
    name="mcmc", title="3DGS-MCMC", implementation="strings_bench.methods.mcmc:MCMC",
    description="3DGS-MCMC: dead-Gaussian relocation (eq. 9), 5% growth to a cap, opacity/scale L1, SGLD "
                "position noise",
    paper="Kheradmand, Rebain, Sharma, Sun, Tseng, Isack, Kar, Tagliasacchi, Yi: "
          "3D Gaussian Splatting as Markov Chain Monte Carlo (NeurIPS 2024)",
    defaults={"init_opacity": 0.5, "init_scale_factor": 0.1},
    paper_figures=PaperFigures.table1(tandt=(.272, .120), dl3dv=(.511, .142), strings360=(.927, .110),
                                      minutes=(5.6, 34.0)))
