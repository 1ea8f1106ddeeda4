"""Mip-Splatting's spec (the method: mip_splatting.py)."""

from strings_bench.methods.spec import MethodSpec, PaperFigures

SPEC = MethodSpec(
    name="mip-splatting", title="Mip-Splatting", implementation="strings_bench.methods.mip_splatting:MipSplatting",
    description="Mip-Splatting: 3D smoothing filter from the training cameras' sampling rate + 2D mip filter",
    paper="Yu, Chen, Huang, Sattler, Geiger: Mip-Splatting: Alias-free 3D Gaussian Splatting (CVPR 2024)",
    paper_figures=PaperFigures.table1(tandt=(.222, .125), dl3dv=(.392, .149), strings360=(.748, .129),
                                      minutes=(5.7, 31.7)))
