"""OCR of a cell's views one at a time against eval.ocr.read_many's thread pool.

Reads what the runner's Evaluator reads for one cell of a synthetic scene, the GT test views and the
renders (here the GT views blurred with sigma 1 px), each with its dilated text mask, by RapidOCR
with no cache, under several (ONNX threads per read) x (reads at once) splits of the machine's cores.
The reference, measured in the same run, is the split used before read_many: 2 threads, 1 read at a
time. Each configuration is timed --repeats times (median); all must read the same words.

    python studies/ocr_parallel/ocr_parallel.py [--scene extinguisher] [--size 320x240] [--views 48] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="extinguisher")
    ap.add_argument("--size", default="320x240", help="WIDTHxHEIGHT of the synthetic scene's views")
    ap.add_argument("--views", type=int, default=48, help="views of the scene (every 8th is a test view)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))

    from scipy.ndimage import gaussian_filter

    from strings_bench.eval.protocol import to_uint8 as _to_uint8
    from strings_bench.eval.text_masks import eval_mask, eval_mask_settings
    from strings_bench.datasets.synthetic import build_scene, settings_with
    from strings_bench.eval.ocr import read_many
    from strings_bench.core.cpus import usable_cores
    from strings_bench.eval.ocr.rapid import RapidOCRBackend
    from strings_bench.scene.scene import Scene

    scene = Scene.load(build_scene(args.scene, settings_with(width=width, height=height, n_views=args.views),
                                   progress=False))
    settings = eval_mask_settings(scene)
    images, masks = [], []
    for i in scene.test_idx:
        gt = scene.load_image(i)
        m = eval_mask(scene, i, 1.0, settings)
        images += [_to_uint8(gt), _to_uint8(gaussian_filter(gt, sigma=(1, 1, 0)))]
        masks += [m, m]
    cores = usable_cores()
    configs = [(2, 1)] + [(t, max(1, cores // t)) for t in (cores, 2, 1) if (t, max(1, cores // t)) != (2, 1)]
    configs = list(dict.fromkeys(configs))
    print(f"{args.scene} {width}x{height}: {len(images)} reads per cell (GT + render of "
          f"{len(scene.test_idx)} test views), {cores} usable cores, median of {args.repeats}")
    reference_words = None
    rows = []
    for threads, workers in configs:
        backend = RapidOCRBackend(cache=None, threads=threads)
        backend.read(images[0], masks[0])  # loads the models outside the clock
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            words = read_many(backend, images, masks, workers=workers)
            times.append(time.perf_counter() - t0)
        if reference_words is None:
            reference_words = words
        same = words == reference_words
        rows.append((threads, workers, statistics.median(times), same))
    ref = rows[0][2]
    print("\n| ONNX threads per read | reads at once | seconds per cell | x reference | same words |")
    print("|---|---|---|---|---|")
    for threads, workers, sec, same in rows:
        print(f"| {threads} | {workers} | {sec:.2f} | {ref / sec:.2f} | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
