"""How long a synthetic scene takes to build at a large size, and what rendering views in parallel saves.

1. Renders the first --views views of the scene's orbit with one process and with --workers processes
   (default: every usable core), in the same run, and prints seconds per view and the ratio (the
   workers' time includes starting them, which rebuilds the scene's textures in each). Checks that
   both give the same pixels.
2. With --build, builds the whole scene (n_views = --views) into a private cache folder and prints the
   stage timings from its scene_meta.json (render, features, matching, triangulation).

    python studies/synthetic_build/synthetic_build.py [--scene pantry] [--size 1600x1200] [--views 16] [--build]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="pantry")
    ap.add_argument("--size", default="1600x1200")
    ap.add_argument("--views", type=int, default=16)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--build", action="store_true", help="also build the whole scene and print its stage timings")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))

    import strings_bench.datasets.synthetic.generate as generate
    from strings_bench.core.cpus import usable_cores
    from strings_bench.datasets.synthetic import SCENE_NAMES_360, SYNTHETIC360_DEFAULTS, settings_with

    extra = SYNTHETIC360_DEFAULTS if args.scene in SCENE_NAMES_360 else {}
    st = settings_with(width=width, height=height, n_views=max(8, args.views), **extra)
    workers = args.workers or usable_cores()
    t0 = time.perf_counter()
    spec = generate.make_spec(args.scene, st.seed, st)
    spec_s = time.perf_counter() - t0
    print(f"{args.scene} {width}x{height}, supersample {st.supersample}: scene content (textures) {spec_s:.1f} s; "
          f"{usable_cores()} usable cores")

    def first_views(n_workers: int):
        t = time.perf_counter()
        out = []
        for k, (_, res, _) in enumerate(generate.render_views(spec, st, workers=n_workers)):
            out.append(res.rgb)
            if k + 1 == args.views:
                break
        return time.perf_counter() - t, out

    one_s, one = first_views(1)
    many_s, many = first_views(workers)
    same = all(np.array_equal(a, b) for a, b in zip(one, many))
    print(f"\n| render | views | seconds | s per view | x one process |\n|---|---|---|---|---|")
    print(f"| 1 process | {args.views} | {one_s:.1f} | {one_s / args.views:.2f} | 1.00 |")
    print(f"| {workers} processes | {args.views} | {many_s:.1f} | {many_s / args.views:.2f} | {one_s / many_s:.2f} |")
    print(f"same pixels: {'yes' if same else 'NO'}")

    if args.build:
        with tempfile.TemporaryDirectory() as tmp:
            os.environ["STRINGS_BENCH_CACHE"] = tmp
            os.environ[generate.RENDER_WORKERS_ENV] = str(workers)
            t = time.perf_counter()
            path = generate.build_scene(args.scene, st, progress=True)
            total = time.perf_counter() - t
            meta = json.loads((Path(path) / "scene_meta.json").read_text())
            print(f"\nbuild of {st.n_views} views: {total:.1f} s; scene_meta timings_s: "
                  f"{json.dumps(meta.get('timings_s'))}; sfm: {json.dumps(meta.get('sfm', {}).get('timings', meta.get('sfm')))[:400]}")


if __name__ == "__main__":
    main()
