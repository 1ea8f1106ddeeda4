"""Per-image OCR time and known-text CER of each available backend on generated text images.

    python benchmarks/ocr_speed.py [--images 12] [--size 960x540] [--backends rapidocr tesseract]
                                   [--threads N] [--gcv] [--json out.json]

Images: random vocabulary words (Pillow's bundled font, 32-56 px, 3 lines) on a canvas of --size,
light noise added; each backend reads each image once without the cache after one warm-up read
(which also loads the models). Google Vision is only timed with --gcv (it is billed).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time

import numpy as np
from tqdm import tqdm

from strings_bench.cer import scene_cer
from strings_bench.ocr import available_backends, get_backend
from strings_bench.ocr.sample import random_text_image


def make_images(n: int, size: tuple[int, int], seed: int = 0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        img, known = random_text_image(rng, n_lines=3, size=size)
        noisy = np.clip(img + rng.normal(0, 5, img.shape), 0, 255).astype(np.uint8)
        out.append((noisy, known))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--images", type=int, default=12)
    ap.add_argument("--size", default="960x540", help="WxH of each image")
    ap.add_argument("--backends", nargs="*", help="default: every available one except gcv")
    ap.add_argument("--gcv", action="store_true", help="also time Google Vision (billed)")
    ap.add_argument("--threads", type=int, default=None, help="ONNX Runtime intra-op threads for rapidocr")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    images = make_images(args.images, (w, h))

    statuses = available_backends()
    names = args.backends or [n for n, st in statuses.items() if st.available and n != "gcv"]
    if args.gcv and "gcv" not in names:
        names.append("gcv")
    results = {}
    for name in names:
        if not statuses[name].available:
            print(f"{name}: unavailable ({statuses[name].detail})")
            continue
        kwargs = {"threads": args.threads} if (name == "rapidocr" and args.threads) else {}
        backend = get_backend(name, cache=False, **kwargs)
        t0 = time.perf_counter()
        backend.read(images[0][0])  # warm-up: model loading
        warmup = time.perf_counter() - t0
        times, per_image, failures = [], {}, 0
        for i, (img, known) in enumerate(tqdm(images, desc=name, unit="img", file=sys.stderr)):
            t0 = time.perf_counter()
            try:
                words = backend.read(img)
            except Exception as exc:  # counted, as in scoring
                failures += 1
                per_image[str(i)] = (known, None)
                print(f"  {name} failed on image {i}: {exc}", file=sys.stderr)
                continue
            times.append(time.perf_counter() - t0)
            per_image[str(i)] = (known, words)
        cer = scene_cer(per_image)
        results[name] = {
            "version": backend.version,
            "settings": backend.settings,
            "first_read_s": warmup,
            "median_s": statistics.median(times) if times else None,
            "mean_s": statistics.fmean(times) if times else None,
            "min_s": min(times) if times else None,
            "known_text_cer": cer.cer,
            "errors": cer.errors,
            "chars": cer.chars,
            "failures": failures,
        }
        r = results[name]
        print(
            f"{name:<10} median {r['median_s']:.3f} s/img  mean {r['mean_s']:.3f}  min {r['min_s']:.3f}  "
            f"(first read {warmup:.2f} s)  known-text CER {cer.cer:.4f} ({cer.errors}/{cer.chars})  failures {failures}"
        )
    meta = {"images": args.images, "size": [w, h], "machine": platform.processor() or platform.machine(), "python": platform.python_version()}
    if args.json:
        from strings_bench.io_utils import atomic_write_json

        atomic_write_json(args.json, {"meta": meta, "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
