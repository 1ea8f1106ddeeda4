"""CLI: `strings-bench render --ply FILE --scene SCENE_DIR --out DIR`: render a Gaussian-splat PLY
(ours or one trained elsewhere, 3DGS layout) at a COLMAP scene's cameras, one PNG per view named
after the image."""

from __future__ import annotations

import argparse
import io
from pathlib import Path

from strings_bench.cli import command_help
from strings_bench.core.errors import StringsBenchError


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "render",
        help=command_help("render"),
        description="Render a Gaussian-splat PLY (3DGS layout) at the cameras of a COLMAP scene folder and "
        "write one PNG per view, named after the image.",
    )
    p.add_argument("--ply", required=True, type=Path, help="the model (3DGS-layout PLY)")
    p.add_argument("--scene", required=True, type=Path, help="scene folder (images/ and sparse/0/)")
    p.add_argument("--out", required=True, type=Path, help="output folder for the PNGs")
    p.add_argument("--split", choices=["test", "train", "all"], default="test", help="which views (default test)")
    p.add_argument("--downscale", type=float, default=1, help="render at 1/N resolution (default 1)")
    p.add_argument("--background", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("R", "G", "B"),
                   help="background colour in [0, 1] (default black, as 3DGS)")
    p.add_argument("--sh-degree", type=int, default=None, help="SH degree to render with (default: the file's)")
    p.add_argument("--backend", default="auto", help="rasterizer backend (default auto)")
    p.add_argument("--device", default="auto",
                   help="where to render: auto (CUDA when torch sees a GPU, else cpu; default), cpu, cuda, cuda:N")
    p.set_defaults(func=run)
    return p


def render_ply(ply: Path, scene_dir: Path, out: Path, split: str = "test", downscale: float = 1,
               background=(0.0, 0.0, 0.0), sh_degree: int | None = None, backend: str = "auto",
               progress: bool = True, device: str = "auto") -> list[Path]:
    """Render the PLY `ply` at the `split` views of `scene_dir` into `out` (PNGs named after the images),
    on `device` (auto, cpu, cuda, cuda:N); returns the written paths."""
    import numpy as np
    import torch
    from PIL import Image
    from tqdm.auto import tqdm

    from strings_bench.core.io import atomic_write_bytes
    from strings_bench.engine.trainer import resolve_device
    from strings_bench.engine.ply import read_ply
    from strings_bench.scene.scene import Scene

    if downscale <= 0:
        raise StringsBenchError(f"--downscale must be > 0, got {downscale}")
    device = resolve_device(device)  # before any file is read: a missing GPU is a clear error
    model = read_ply(ply, device=device)
    scene = Scene.load(scene_dir)
    views = {"test": scene.test_idx, "train": scene.train_idx, "all": list(range(scene.num_views))}[split]
    written = []
    with torch.no_grad():
        for i in tqdm(views, desc=f"render {scene.name}", disable=not progress):
            img = model.render(scene.camera(i, downscale), background, sh_degree=sh_degree, backend=backend).color
            arr = (img.clamp(0, 1).cpu().numpy() * 255 + 0.5).astype(np.uint8)
            buf = io.BytesIO()
            Image.fromarray(arr).save(buf, format="PNG")
            path = out / (Path(scene.names[i]).stem + ".png")
            atomic_write_bytes(path, buf.getvalue())
            written.append(path)
    return written


def run(args: argparse.Namespace) -> int:
    """`strings-bench render`: write the PNGs and say how many."""
    written = render_ply(args.ply, args.scene, args.out, args.split, args.downscale, tuple(args.background),
                         args.sh_degree, args.backend, device=args.device)
    print(f"wrote {len(written)} image(s) to {args.out}")
    return 0
