"""Overhead per cell of `--executor slurm` against `--executor local`: the same small grid, run alternately with
each executor into fresh run folders, and whether their results.csv agree in every non-time column.

    sudo bash scripts/slurm_local.sh                       # a Slurm on this machine (or run on a cluster's login node)
    python studies/slurm_vs_local/slurm_vs_local.py --csv docs/results/data/slurm-overhead/overhead.csv

The grid: --methods (default 3dgs,strings) on --scenes synthetic scenes of 96x72 pixels and 12 views (the tests'
size), the tiny schedule at --steps-scale 0.002 (checkpoints 3K and 7K: 6 and 14 steps), no LPIPS. Both executors
train with one thread (OMP_NUM_THREADS=1 for the local run, as each Slurm task of --cpus-per-job 1 gets), and Slurm
runs one task at a time (--slurm-array-parallelism 1), so the two runs do the same work one job after another and
their wall times differ by what Slurm adds: sbatch, queueing, the task's start (a new Python importing torch and
strings-bench, reading the pickled job, building the scene's evaluator that a local run builds once per scene)
and the driver's polling. Per cell: that difference over the cells. A first local run warms the caches both read.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path


def is_time(column: str) -> bool:
    return column.endswith("_seconds") or column == "peak_memory_mb"


def rows(path: Path) -> dict[tuple, dict]:
    with open(path, newline="") as f:
        return {(r["method"], r["dataset"], r["scene"], r["iteration"]): r for r in csv.DictReader(f)}


def differing(a: Path, b: Path) -> int:
    """Cells (present in either file) that differ in a non-time column or are missing from one."""
    ra, rb = rows(a), rows(b)
    bad = set(ra) ^ set(rb)
    for key in set(ra) & set(rb):
        if any(ra[key].get(c) != rb[key].get(c) for c in set(ra[key]) | set(rb[key]) if not is_time(c)):
            bad.add(key)
    return len(bad)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default="runs/slurm_vs_local", help="folder for the run folders (emptied); on a "
                    "cluster: a folder every node mounts")
    ap.add_argument("--methods", default="3dgs,strings")
    ap.add_argument("--scenes", default="books,globe")
    ap.add_argument("--repeats", type=int, default=2, help="runs per executor, alternating (default 2)")
    ap.add_argument("--warmup", action=argparse.BooleanOptionalAction, default=True,
                    help="first one local run that is not recorded (it compiles the numba kernels and fills the OCR "
                         "cache of the ground truth views, which every later run then reads; default on)")
    ap.add_argument("--partition", default=None, help="--slurm-partition (default: the cluster's default)")
    ap.add_argument("--csv", default=None, help="write one row per run to this file")
    args = ap.parse_args(argv)

    from strings_bench.datasets.synthetic import build_scene, settings_with

    settings = settings_with(width=96, height=72, n_views=12)
    scenes = [str(build_scene(name, settings, progress=False)) for name in args.scenes.split(",")]  # built once, here
    work = Path(args.work).resolve()
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    base = ["run", "--methods", args.methods, "--datasets", ",".join(scenes), "--schedule", "tiny",
            "--steps-scale", "0.002", "--checkpoints", "3000,7000", "--no-lpips", "--no-progress"]
    slurm = ["--executor", "slurm", "--cpus-per-job", "1", "--slurm-array-parallelism", "1", "--slurm-time", "30"]
    slurm += ["--slurm-partition", args.partition] if args.partition else []
    out_rows = []
    runs = [(0, "local")] if args.warmup else []
    runs += [(repeat, executor) for repeat in range(1, args.repeats + 1) for executor in ("local", "slurm")]
    for repeat, executor in runs:
        out = work / f"{executor}-{repeat}"
        cmd = [sys.executable, "-m", "strings_bench", *base, "--out", str(out), *(slurm if executor == "slurm" else [])]
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            print(f"--executor {executor} failed (exit {proc.returncode}): {' '.join(cmd)}", file=sys.stderr)
            return 1
        if repeat == 0:
            print(f"warm-up (not recorded): {wall:.1f} s", flush=True)
            continue
        cells = rows(out / "results.csv")
        inside = sum(float(r["total_seconds"] or 0) + float(r["eval_seconds"] or 0) for r in cells.values())
        out_rows.append({"executor": executor, "repeat": repeat, "jobs": len(cells) // 2, "cells": len(cells),
                         "wall_seconds": round(wall, 1), "cell_seconds_sum": round(inside, 1),
                         "load_average_before": round(load, 1), "load_average_after": round(os.getloadavg()[0], 1),
                         "differing_cells_vs_local_1": None, "added_seconds_per_cell": None})
        print(f"--executor {executor} #{repeat}: {wall:.1f} s for {len(cells)} cells", flush=True)
    reference = work / "local-1" / "results.csv"
    for row in out_rows:
        row["differing_cells_vs_local_1"] = differing(reference, work / f"{row['executor']}-{row['repeat']}" / "results.csv")
    for repeat in range(1, args.repeats + 1):
        local, slurm_row = (next(r for r in out_rows if r["executor"] == e and r["repeat"] == repeat)
                            for e in ("local", "slurm"))
        per_cell = (slurm_row["wall_seconds"] - local["wall_seconds"]) / slurm_row["cells"]
        slurm_row["added_seconds_per_cell"] = round(per_cell, 2)  # against the local run of the same repeat
        print(f"repeat {repeat}: Slurm adds {per_cell:.1f} s per cell "
              f"({slurm_row['wall_seconds']:.1f} s against {local['wall_seconds']:.1f} s)")
    if args.csv:
        Path(args.csv).parent.mkdir(parents=True, exist_ok=True)
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(out_rows[0]))
            writer.writeheader()
            writer.writerows(out_rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
