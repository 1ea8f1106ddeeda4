"""3DGS' spec (the method: gs3d.py)."""

from strings_bench.methods.spec import MethodSpec, PaperFigures

SPEC = MethodSpec(
    name="3dgs", title="3DGS", implementation="strings_bench.methods.gs3d:GS3D",
    description="vanilla 3DGS: SfM init, Adam, adaptive density control (clone/split/prune, opacity reset)",
    paper="Kerbl, Kopanas, Leimkuehler, Drettakis: 3D Gaussian Splatting for Real-Time Radiance Field "
          "Rendering (SIGGRAPH 2023)",
    paper_figures=PaperFigures.table1(tandt=(.209, .121), dl3dv=(.392, .157), strings360=(.736, .148),
                                      minutes=(2.5, 17.2)))
