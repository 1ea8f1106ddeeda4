"""Wall time of one `strings-bench run` with `--executor local` and with `--executor ray`, and whether
their results.csv metric columns agree.

    python studies/ray_vs_local/ray_vs_local.py                       # synthetic, strings,3dgs, schedule tiny
    python studies/ray_vs_local/ray_vs_local.py --work /tmp/rvl --datasets synthetic/books --methods 3dgs

Each executor runs the same command into its own fresh run folder and its own fresh cache
(STRINGS_BENCH_CACHE), into which the synthetic scenes and compiled kernels of your cache are copied
first, so that neither run reads the other's OCR results or text masks. The runs go one after
another, never at once. Extra arguments after `--` go to both commands (e.g. `-- --no-lpips`).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

# Columns of results.csv that are not results: they may differ between two runs of the same grid.
NOT_METRICS = {"train_seconds", "preprocess_seconds", "total_seconds", "eval_seconds", "peak_memory_mb"}


def rows(path: Path) -> dict[tuple, dict]:
    with open(path, newline="") as f:
        return {(r["method"], r["dataset"], r["scene"], r["iteration"]): r for r in csv.DictReader(f)}


def compare(a: Path, b: Path) -> dict:
    """Cells only in one file, and per metric column the cells that differ and the largest difference."""
    ra, rb = rows(a), rows(b)
    out = {"cells": len(ra), "only_in_one": sorted(map(list, set(ra) ^ set(rb))), "columns": {}}
    for key in set(ra) & set(rb):
        for col in set(ra[key]) - NOT_METRICS:
            x, y = ra[key].get(col, ""), rb[key].get(col, "")
            if x == y:
                continue
            entry = out["columns"].setdefault(col, {"cells": 0, "max_abs": 0.0})
            entry["cells"] += 1
            try:
                entry["max_abs"] = max(entry["max_abs"], abs(float(x) - float(y)))
            except ValueError:
                entry["max_abs"] = math.inf
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default="runs/ray_vs_local", help="folder for the two run folders and caches (emptied)")
    ap.add_argument("--datasets", default="synthetic")
    ap.add_argument("--methods", default="strings,3dgs")
    ap.add_argument("--schedule", "--preset", dest="schedule", default="tiny")
    ap.add_argument("--json", default=None, help="also write the figures to this file")
    ap.add_argument("extra", nargs="*", help="more `run` arguments, after --")
    args = ap.parse_args(argv)

    from strings_bench.core.io import cache_root

    work = Path(args.work).resolve()
    shutil.rmtree(work, ignore_errors=True)
    figures: dict = {"command": None, "seconds": {}}
    for executor in ("local", "ray"):
        cache = work / f"cache_{executor}"
        cache.mkdir(parents=True)
        for part in ("synthetic", "numba"):  # built scenes and compiled kernels: not what is compared
            if (cache_root() / part).is_dir():
                shutil.copytree(cache_root() / part, cache / part)
        cmd = [sys.executable, "-c", "import sys; from strings_bench.cli import main; sys.exit(main())", "run",
               "--executor", executor, "--datasets", args.datasets, "--methods", args.methods,
               "--schedule", args.schedule, "--out", str(work / f"out_{executor}"), "--no-progress", *args.extra]
        figures["command"] = " ".join(cmd[3:])
        env = {**os.environ, "STRINGS_BENCH_CACHE": str(cache)}
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env)
        figures["seconds"][executor] = round(time.perf_counter() - t0, 1)
        if proc.returncode != 0:
            print(f"--executor {executor} failed (exit {proc.returncode})", file=sys.stderr)
            return 1
        print(f"--executor {executor}: {figures['seconds'][executor]:.1f} s", flush=True)
    figures["agreement"] = compare(work / "out_local" / "results.csv", work / "out_ray" / "results.csv")
    figures["load_average"] = os.getloadavg()
    print(json.dumps(figures, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
