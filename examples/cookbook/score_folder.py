"""Cookbook: scoring a folder of renders from Python (docs/cookbook/score-folder.md). The renders here are a
scene's own test views, sharp and blurred, standing in for the output of any renderer; `evaluate` scores them as
`strings-bench evaluate FOLDER --scene SCENE` does.

Run it:  python examples/cookbook/score_folder.py [OUT_DIR]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from PIL import Image, ImageFilter

from strings_bench.bench.evaluate import EvaluateOptions, evaluate


def write_renders(scene, folder: Path, blur_px: float) -> Path:
    """One PNG per test view, named after the view (<stem>.png): the `folder` layout `evaluate` reads."""
    folder.mkdir(parents=True, exist_ok=True)
    for i in scene.test_idx:
        image = Image.open(scene.image_path(i)).convert("RGB")
        image.filter(ImageFilter.GaussianBlur(blur_px)).save(folder / f"{Path(scene.names[i]).stem}.png")
    return folder


def main(out: Path) -> None:
    import pandas as pd

    from strings_bench.datasets.synthetic import build_scene, settings_with
    from strings_bench.scene.scene import Scene

    # a synthetic scene with printed text, 480x360, 8 views (built into the cache on first use)
    scene_dir = build_scene("books", settings_with(width=480, height=360, n_views=8), progress=False)
    scene = Scene.load(scene_dir)
    for blur in (0.0, 0.8):
        renders = write_renders(scene, out / f"renders-blur{blur}", blur)
        run_dir = evaluate(renders, EvaluateOptions(scene=str(scene_dir), out=out / f"scored-blur{blur}",
                                                    method=f"blur-{blur}px", with_lpips=False, report=False,
                                                    progress=False), say=lambda line: None)
        row = pd.read_csv(run_dir / "results.csv").iloc[0]
        known = "n/a" if pd.isna(row["cer_known"]) else f"{row['cer_known']:.3f}"
        print(f"blur {blur} px: OCR-CER {row['cer']:.3f} over {int(row['cer_chars'])} GT character(s), "
              f"known-text CER {known}, PSNR {row['psnr']:.2f} dB  ({run_dir.name}/results.csv)")


if __name__ == "__main__":
    if len(sys.argv) > 1:
        main(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            main(Path(tmp))
