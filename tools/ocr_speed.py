"""Per-image OCR time and known-text CER of each available backend on generated text images.

    python tools/ocr_speed.py [--images 12] [--size 960x540] [--backends rapidocr tesseract]
                                   [--threads N] [--gcv] [--json out.json]
                                   [--synthetic [SCENE ...]] [--synthetic-only] [--set KEY=VALUE]

Images: random vocabulary words (Pillow's bundled font, 32-56 px, 3 lines) on a canvas of --size,
light noise added; each backend reads each image once without the cache after one warm-up read
(which also loads the models). Google Vision is only timed with --gcv (it is billed).

--synthetic: RapidOCR (default settings, or --set ones) on the ground-truth test views of the
synthetic scenes (built on first use), scored against the known words with the known-text CER
legibility filter (cer.KNOWN_TEXT_MIN_HEIGHT_PX): per scene the characters counted and excluded,
errors, CER, wall and CPU seconds per image, and the CER of the masked read (image with the
dilated GT text mask, as the runner reads it).
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

from strings_bench.eval.cer import KNOWN_TEXT_MIN_HEIGHT_PX, known_scene_cer, scene_cer
from strings_bench.eval.ocr import available_backends, get_backend
from strings_bench.eval.ocr.sample import random_text_image


def make_images(n: int, size: tuple[int, int], seed: int = 0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        img, known = random_text_image(rng, n_lines=3, size=size)
        noisy = np.clip(img + rng.normal(0, 5, img.shape), 0, 255).astype(np.uint8)
        out.append((noisy, known))
    return out


SYNTHETIC_SCENES = ["books", "extinguisher", "globe", "chemicals", "shelf"]


def synthetic_table(scenes: list[str], settings: dict, threads: int | None, min_h: float) -> list[dict]:
    """Known-text CER of RapidOCR on the GT test views of synthetic scenes (unmasked and masked)."""
    from strings_bench.datasets import resolve_scenes
    from strings_bench.eval.text_masks import eval_mask, eval_mask_settings
    from strings_bench.scene.scene import Scene

    kwargs = dict(settings)
    if threads:
        kwargs["threads"] = threads
    backend = get_backend("rapidocr", cache=False, **kwargs)
    rows = []
    for name in scenes:
        scene = Scene.load(resolve_scenes([f"synthetic/{name}"])[0].path)
        mask_settings = eval_mask_settings(scene)
        plain, masked, wall, cpu = {}, {}, [], []
        for i in tqdm(scene.test_idx, desc=name, unit="view", file=sys.stderr):
            img = (np.clip(scene.load_image(i), 0, 1) * 255).round().astype(np.uint8)
            if not wall:
                backend.read(img)  # warm-up (model loading) outside the timing
            known = [(k.text, k.polygon) for k in scene.known_words(i) or []]
            t0, c0 = time.perf_counter(), time.process_time()
            plain[str(i)] = (known, backend.read(img))
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            masked[str(i)] = (known, backend.read(img, mask=eval_mask(scene, i, 1, mask_settings)))
        r, rm = known_scene_cer(plain, min_h), known_scene_cer(masked, min_h)
        r_all = known_scene_cer(plain, 0.0)
        rows.append({
            "scene": name, "views": len(plain), "chars": r.chars, "excluded_chars": r.legibility["excluded_chars"],
            "errors": r.errors, "cer": r.cer, "cer_masked": rm.cer, "errors_masked": rm.errors,
            "cer_unfiltered": r_all.cer, "wall_s_per_image": statistics.fmean(wall), "cpu_s_per_image": statistics.fmean(cpu),
        })
        x = rows[-1]
        print(f"{name:<13} chars {x['chars']:4d}  excluded {x['excluded_chars']:4d}  errors {x['errors']:4d}  "
              f"CER {x['cer']:.3f}  masked {x['cer_masked']:.3f}  unfiltered {x['cer_unfiltered']:.3f}  "
              f"{x['wall_s_per_image']:.2f} s/img wall, {x['cpu_s_per_image']:.2f} s CPU", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--images", type=int, default=12)
    ap.add_argument("--size", default="960x540", help="WxH of each image")
    ap.add_argument("--backends", nargs="*", help="default: every available one except gcv")
    ap.add_argument("--gcv", action="store_true", help="also time Google Vision (billed)")
    ap.add_argument("--threads", type=int, default=None, help="ONNX Runtime intra-op threads for rapidocr")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--synthetic", nargs="*", metavar="SCENE",
                    help=f"also score the synthetic scenes' GT test views (default: {' '.join(SYNTHETIC_SCENES)})")
    ap.add_argument("--synthetic-only", action="store_true", help="skip the generated-image timing")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="rapidocr setting (JSON value) for --synthetic")
    ap.add_argument("--min-text-height", type=float, default=KNOWN_TEXT_MIN_HEIGHT_PX, help="legibility filter (px)")
    args = ap.parse_args(argv)
    settings = {k.strip(): json.loads(v) for k, v in (item.split("=", 1) for item in args.set)}
    synthetic_rows = None
    if args.synthetic is not None or args.synthetic_only:
        synthetic_rows = synthetic_table(args.synthetic or SYNTHETIC_SCENES, settings, args.threads, args.min_text_height)
    if args.synthetic_only:
        if args.json:
            from strings_bench.core.io import atomic_write_json

            atomic_write_json(args.json, {"synthetic": synthetic_rows, "settings": settings,
                                          "min_text_height_px": args.min_text_height})
        return 0
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
        from strings_bench.core.io import atomic_write_json

        atomic_write_json(args.json, {"meta": meta, "results": results, "synthetic": synthetic_rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
