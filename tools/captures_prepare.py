"""What building each scene of the `captures` dataset costs on this machine, and what it holds.

    python tools/captures_prepare.py [NAME ...] [--out docs/results/data/captures]

Each capture is built from scratch in a child process of its own, so that its peak memory (the child's maximum
resident set size: SfM, undistortion, OCR masks) is its own, with an empty cache (no OCR result is reused); the
scene is then moved into the suite's cache, where runs find it. Per capture: the seconds of each stage of
`prepare` (datasets/sfm.py; the given-cameras path of datasets/bundler.py for saharov32), the whole build, the
record's measurements (GT characters read on the held-out views, rho), photos registered, test views. Writes
prepare.csv (costs) and captures.csv (what each scene holds) into --out, and prints both.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

from strings_bench.core.io import atomic_write_text, cache_root
from strings_bench.datasets.captures import (CAPTURES, DATASET_ID, GT_DOWNSCALES, MIN_GT_CHARS, build_capture, read_record,
                                             scene_dir)

STAGES = ("resize", "features", "matching", "mapping", "convert", "undistort", "downscale", "masks")


def one(name: str, into: Path) -> None:
    """In the child (its cache empty): build `name`, move the scene to `into` and print its record and peak memory as
    one JSON line."""
    t0 = time.perf_counter()
    path = build_capture(name, force=True, progress=False, echo=lambda s: print(s, file=sys.stderr))
    wall = time.perf_counter() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kilobytes
    into.parent.mkdir(parents=True, exist_ok=True)
    if into.exists():
        shutil.rmtree(into)
    os.replace(path, into)
    for name_ in ("prepare.json", "capture.json"):  # the records name the folder the scene was built in
        rec = json.loads((into / name_).read_text())
        (rec["prepare"] if name_ == "capture.json" else rec)["scene_dir"] = str(into)
        atomic_write_text(into / name_, json.dumps(rec, indent=2, sort_keys=True) + "\n")
    print(json.dumps({"name": name, "wall_seconds": wall, "peak_rss_mb": peak_mb, "path": str(into),
                      "record": read_record(into)}))


def rows_of(results: list[dict]) -> tuple[list[list[str]], list[list[str]]]:
    cost = [["capture", *[f"{s} s" for s in STAGES], "record s", "total s", "peak memory MB"]]
    held = [["capture", "photos", "registered", "not registered", "test views", "train views",
             *[f"GT chars (downscale {d})" for d in GT_DOWNSCALES], "GT engine", "extent", "median stroke (px)",
             "words", "rho"]]
    for r in results:
        rec = r["record"]
        prep = rec["prepare"]
        st = prep["stage_seconds"]
        cost.append([r["name"], *[f"{st[s]:.1f}" if s in st else "" for s in STAGES], f"{rec['record_seconds']:.1f}",
                     f"{r['wall_seconds']:.1f}", f"{r['peak_rss_mb']:.0f}"])
        d = rec["difficulty"]
        held.append([r["name"], str(prep["num_photos"]), str(prep["num_registered"]), " ".join(prep["unregistered"]),
                     str(len(rec["test_views"])), str(rec["train_views"]),
                     *[str(rec["gt_characters"][str(ds)]["chars"]) for ds in GT_DOWNSCALES], rec["gt_ocr"],
                     f"{d['extent']:.3g}", "" if d["stroke_px"] is None else f"{d['stroke_px']:.2f}", str(d["words"]),
                     "" if d["rho"] is None else f"{d['rho']:.3f}"])
    return cost, held


def as_csv(rows: list[list[str]]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    return buf.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", default=list(CAPTURES), help=f"captures (default: all: {', '.join(CAPTURES)})")
    ap.add_argument("--out", type=Path, default=None, help="folder for prepare.csv and captures.csv")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--into", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        one(args.one, args.into)
        return 0
    results = []
    for name in args.names:
        cold = cache_root() / DATASET_ID / f".cold-{os.getpid()}"  # the same file system: the scene is renamed
        shutil.rmtree(cold, ignore_errors=True)
        env = {**os.environ, "STRINGS_BENCH_CACHE": str(cold)}
        try:
            proc = subprocess.run([sys.executable, __file__, "--one", name, "--into", str(scene_dir(name))],
                                  stdout=subprocess.PIPE, text=True, env=env)
        finally:
            shutil.rmtree(cold, ignore_errors=True)
        if proc.returncode != 0:
            print(f"{name}: the build failed (exit status {proc.returncode})", file=sys.stderr)
            return 1
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        print(f"{name}: {results[-1]['wall_seconds']:.1f} s, peak {results[-1]['peak_rss_mb']:.0f} MB", flush=True)
    cost, held = rows_of(results)
    print(as_csv(cost))
    print(as_csv(held))
    print(f"(CER is not scored below {MIN_GT_CHARS} GT characters)")
    if args.out is not None:
        atomic_write_text(args.out / "prepare.csv", as_csv(cost))
        atomic_write_text(args.out / "captures.csv", as_csv(held))
    return 0


if __name__ == "__main__":
    sys.exit(main())
