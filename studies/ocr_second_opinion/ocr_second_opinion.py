"""What a second OCR engine costs a cell's evaluation: `--ocr rapidocr` against `--ocr rapidocr,tesseract`.

Evaluates two cells' renders (the ground-truth test views, blurred with sigma 0.7 and 1.0 px) of one
synthetic scene with the runner's Evaluator, once per engine list, each time with an empty OCR cache, LPIPS off, and
prints the evaluation seconds of each (the first cell of a list pays the GT reads; the second only
its render reads) and the agreement the second engine records.

    python studies/ocr_second_opinion/ocr_second_opinion.py [--scene books] [--width 320 --height 240 --views 48]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="books")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--views", type=int, default=48)
    args = ap.parse_args()

    from scipy.ndimage import gaussian_filter

    from strings_bench.eval.protocol import Evaluator
    from strings_bench.datasets.synthetic import build_scene, settings_with
    from strings_bench.eval.ocr import OCRCache, get_backend
    from strings_bench.scene.scene import Scene

    path = build_scene(args.scene, settings_with(width=args.width, height=args.height, n_views=args.views), progress=False)
    scene = Scene.load(path)
    cells = [{scene.names[i]: gaussian_filter(scene.load_image(i), sigma=(s, s, 0)).astype(np.float32)
              for i in scene.test_idx} for s in (0.7, 1.0)]  # two cells with different renders
    print(f"{args.scene} {args.width}x{args.height}: {len(cells[0])} test views")
    for engines in (["rapidocr"], ["rapidocr", "tesseract"]):
        with tempfile.TemporaryDirectory() as tmp:
            backends = [get_backend(e, cache=OCRCache(Path(tmp) / "ocr")) for e in engines]
            ev = Evaluator.for_scene(scene, backends, 1.0, with_lpips=False)
            times = []
            for renders in cells:  # two cells of one scene: the second reuses the GT reads
                t0 = time.perf_counter()
                out = ev.evaluate("bench", renders)
                times.append(time.perf_counter() - t0)
            extra = {e: {"cer": v["cer"]["cer"], "agreement": v["agreement"]["renders"]}
                     for e, v in (out.get("ocr_engines") or {}).items()}
            print(f"--ocr {','.join(engines)}: first cell {times[0]:.1f} s, next cell {times[1]:.1f} s, "
                  f"primary cer {out['cer']['cer']}, {json.dumps(extra)}")


if __name__ == "__main__":
    main()
