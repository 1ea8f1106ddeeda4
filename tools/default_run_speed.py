"""The default run (and optionally the demo and the test suite) of a reference commit and of this checkout,
side by side in one run, as ratios new / reference, and the check that the figures did not change.

    python tools/default_run_speed.py --ref f2de671 [--ref-dir DIR] [--out DIR] [--sequential]
                                           [--demo] [--tests] [--bank CSV]

1. The default run (`strings-bench run --methods strings,3dgs`, the `cpu` schedule) of both versions, each
   with its own empty cache folder (STRINGS_BENCH_CACHE), so each builds the scene, compiles its kernels and
   reads its OCR as on a fresh clone, and no arm is served the other's OCR reads. By default both arms run
   at the same time, so a shared machine's load falls on both alike (--sequential: reference first, then
   this checkout). Printed: each arm's wall time, the sum of `eval_seconds` over the six checkpoints (goal:
   new <= 0.5x the reference's), `train_seconds`, and the ratios.
2. Every column of the two results.csv but the times (`*_seconds`) and `peak_memory_mb` (the process's
   memory, which varies from run to run) compared cell by cell as written; any difference is printed and
   the script exits with status 1.
3. --demo: `bash scripts/demo.sh` in a fresh `git clone` of each version (set-up included: the venv and
   pip's downloads), its last line ("demo: set-up S s, run R s") parsed (goal: set-up + run <= 5 min).
4. --tests: `bash scripts/test.sh` of each version (goal: <= 8 min). Never on a machine shared with others.

The demo and the tests run the committed code of each version (a clone of its commit); the runs of 1. run
the checkouts' files as they are (--new-dir: another checkout, e.g. a worktree of the commit to time).

    python tools/default_run_speed.py --summarize BANKED.csv [--table TABLE.csv]

reads a banked pair (BANKED.csv, this checkout's results.csv, and BANKED.ref.csv beside it) again: the
evaluation and training sums, their ratios and the column check, written as a table CSV for the docs (--table).

The reference is a `git worktree` of --ref (made under the system's temporary folder unless --ref-dir
names one; a folder that exists is used as it is). --bank CSV copies this checkout's results.csv there,
with the reference's beside it (<name>.ref.csv).
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
VARYING = ("peak_memory_mb",)  # not a time, but differs from run to run


def load() -> str:
    try:
        return " ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def ref_checkout(ref: str, where: Path | None) -> Path:
    path = where or Path(tempfile.gettempdir()) / f"strings-bench-ref-{ref}"
    if not path.exists():
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(path), ref], check=True,
                       capture_output=True)
    return path


def commit_of(src: Path) -> str:
    return subprocess.run(["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()


def start_run(src: Path, out: Path, cache: Path, log_path: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(src), "STRINGS_BENCH_CACHE": str(cache)}
    cmd = [sys.executable, "-m", "strings_bench", "run", "--methods", "strings,3dgs", "--out", str(out), "--no-progress"]
    log = open(log_path, "w")
    return subprocess.Popen(cmd, cwd=src, env=env, stdout=log, stderr=subprocess.STDOUT)


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def column_sum(rows: list[dict], col: str) -> float:
    return sum(float(r[col]) for r in rows if r.get(col) not in (None, ""))


def compare(ref_rows: list[dict], new_rows: list[dict]) -> list[str]:
    """Differences in the columns that are not times, cell by cell (method, scene, iteration)."""
    key = lambda r: (r["method"], r["dataset"], r["scene"], r["iteration"])  # noqa: E731
    ref, new = {key(r): r for r in ref_rows}, {key(r): r for r in new_rows}
    out = []
    if set(ref) != set(new):
        out.append(f"cells differ: reference {sorted(ref)}, new {sorted(new)}")
    cols_ref = list(ref_rows[0]) if ref_rows else []
    cols_new = list(new_rows[0]) if new_rows else []
    if cols_ref != cols_new:
        out.append(f"columns differ: only in the reference {sorted(set(cols_ref) - set(cols_new))}, "
                   f"only in the new {sorted(set(cols_new) - set(cols_ref))}")
    for k in sorted(set(ref) & set(new)):
        for c in cols_ref:
            if c.endswith("_seconds") or c in VARYING or c not in new[k]:
                continue
            if ref[k][c] != new[k][c]:
                out.append(f"{'/'.join(k)} {c}: reference {ref[k][c]!r}, new {new[k][c]!r}")
    return out


CELL_VARYING = ("timings", "config", "extra", "peak_memory_mb")  # times, paths, versions; the figures are the rest


def compare_cells(ref_run: Path, new_run: Path) -> tuple[int, list[str]]:
    """(cells compared, differences) of the result.json of every cell both run folders hold: every key but
    CELL_VARYING and the readability's `seconds`, i.e. every per-view metric, OCR word and word-crop record."""
    import json

    def figures(path: Path) -> dict:
        rec = json.loads(path.read_text(encoding="utf-8"))
        for k in CELL_VARYING:
            rec.pop(k, None)
        if isinstance(rec.get("readability"), dict):
            rec["readability"].pop("seconds", None)
        return rec

    out, n = [], 0
    for path in sorted(new_run.glob("cells/*/*/*/*/result.json")):
        other = ref_run / path.relative_to(new_run)
        if not other.exists():
            continue
        n += 1
        a, b = figures(other), figures(path)
        for k in sorted(set(a) | set(b)):
            if a.get(k) != b.get(k):
                out.append(f"{path.parent.relative_to(new_run)}: result.json key {k!r} differs")
    return n, out


def demo(src_repo: Path, commit: str, work: Path) -> tuple[float, float | None, float | None]:
    """(wall seconds, set-up s, run s) of scripts/demo.sh in a fresh clone of `commit`."""
    clone = work / f"clone-{commit[:10]}"
    subprocess.run(["git", "clone", "-q", str(src_repo), str(clone)], check=True)
    subprocess.run(["git", "-C", str(clone), "checkout", "-q", commit], check=True)
    env = {**os.environ, "STRINGS_BENCH_CACHE": str(work / f"cache-demo-{commit[:10]}")}
    t = time.perf_counter()
    p = subprocess.run(["bash", "scripts/demo.sh", "--no-progress"], cwd=clone, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    m = re.search(r"demo: set-up (\d+) s, run (\d+) s", p.stdout)
    return wall, (float(m.group(1)) if m else None), (float(m.group(2)) if m else None)


def summarize(banked: Path, table: Path | None) -> int:
    rows = {"reference": read_csv(banked.with_suffix(".ref.csv")), "new": read_csv(banked)}
    diffs = compare(rows["reference"], rows["new"])
    out = [("measure", "reference", "new", "new / reference")]
    for col, what in (("eval_seconds", "evaluation"), ("train_seconds", "training")):
        r, n = column_sum(rows["reference"], col), column_sum(rows["new"], col)
        out.append((f"{what}, sum of `{col}` over the {len(rows['new'])} checkpoints", f"{r:.1f} s", f"{n:.1f} s",
                    f"{n / r:.2f}x"))
    same = ("every column but `*_seconds` and `peak_memory_mb`", "", "",
            "the same in every cell" if not diffs else f"{len(diffs)} difference(s)")
    out.append(same)
    for line in out:
        print(" | ".join(line))
    for d in diffs[:40]:
        print("  " + d)
    if table:
        with open(table, "w", newline="", encoding="utf-8") as fh:
            csv.writer(fh).writerows(out)
    return 1 if diffs else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="f2de671", help="the reference commit (default f2de671)")
    ap.add_argument("--ref-dir", type=Path, help="a checkout of --ref to use (default: a git worktree made for it)")
    ap.add_argument("--new-dir", type=Path, help="the checkout to time against the reference (default: this one)")
    ap.add_argument("--out", type=Path, help="folder for both runs (default: a temporary folder)")
    ap.add_argument("--cache-from", type=Path,
                    help="start each arm's cache as a copy of this cache folder without its ocr/ (the scene, masks "
                         "and compiled kernels built once; every OCR read still cold): the run without the build")
    ap.add_argument("--sequential", action="store_true", help="the reference's run first, then this checkout's")
    ap.add_argument("--demo", action="store_true", help="also time scripts/demo.sh from a fresh clone of each")
    ap.add_argument("--tests", action="store_true", help="also time scripts/test.sh of each (an idle machine only)")
    ap.add_argument("--compare-runs", type=Path, nargs=2, metavar=("REF_RUN", "NEW_RUN"),
                    help="only compare two run folders: results.csv's common cells and every cell's result.json")
    ap.add_argument("--summarize", type=Path, help="only read a banked pair (BANKED.csv and BANKED.ref.csv) again")
    ap.add_argument("--table", type=Path, help="with --summarize: write the table as CSV here")
    ap.add_argument("--bank", type=Path, help="copy this checkout's results.csv here (the reference's beside it)")
    args = ap.parse_args()
    if args.summarize:
        return summarize(args.summarize, args.table)
    if args.compare_runs:
        ref_run, new_run = args.compare_runs
        r, n = read_csv(ref_run / "results.csv"), read_csv(new_run / "results.csv")
        keys = {(x["method"], x["iteration"]) for x in r} & {(x["method"], x["iteration"]) for x in n}
        r = [x for x in r if (x["method"], x["iteration"]) in keys]
        n = [x for x in n if (x["method"], x["iteration"]) in keys]
        diffs = compare(r, n)
        cells, cell_diffs = compare_cells(ref_run, new_run)
        print(f"results.csv, {len(keys)} common cell(s): " + ("every column but the times the same" if not diffs
                                                            else f"{len(diffs)} difference(s)"))
        print(f"result.json, {cells} cell(s): " + ("every figure the same" if not cell_diffs
                                                   else f"{len(cell_diffs)} difference(s)"))
        for d in (diffs + cell_diffs)[:40]:
            print("  " + d)
        return 1 if diffs or cell_diffs else 0

    ref_src = ref_checkout(args.ref, args.ref_dir)
    work = args.out or Path(tempfile.mkdtemp(prefix="default-run-speed-"))
    work.mkdir(parents=True, exist_ok=True)
    new_src = (args.new_dir or REPO).resolve()
    arms = {"reference": ref_src, "new": new_src}
    print(f"reference {args.ref} at {ref_src}; new: {new_src} ({commit_of(new_src)}); runs under {work}; load before: {load()}", flush=True)
    wall: dict[str, float] = {}
    t0 = {}
    procs = {}
    for name, src in arms.items():
        for sub in (f"run-{name}", f"cache-{name}"):
            shutil.rmtree(work / sub, ignore_errors=True)
        if args.cache_from:
            for sub in Path(args.cache_from).iterdir():
                if sub.is_dir() and sub.name != "ocr":
                    shutil.copytree(sub, work / f"cache-{name}" / sub.name, symlinks=True)
        t0[name] = time.perf_counter()
        procs[name] = start_run(src, work / f"run-{name}", work / f"cache-{name}", work / f"run-{name}.log")
        if args.sequential:
            procs[name].wait()
            wall[name] = time.perf_counter() - t0[name]
    loads = []
    while any(p.poll() is None for p in procs.values()):
        loads.append(os.getloadavg()[0])
        for name, p in procs.items():
            if p.poll() is not None and name not in wall:
                wall[name] = time.perf_counter() - t0[name]
        time.sleep(5)
    for name, p in procs.items():
        wall.setdefault(name, time.perf_counter() - t0[name])
        if p.returncode != 0:
            print(f"{name}: the run failed (exit {p.returncode}); see {work / f'run-{name}.log'}")
            return 2
    rows = {name: read_csv(work / f"run-{name}" / "results.csv") for name in arms}
    ev = {name: column_sum(r, "eval_seconds") for name, r in rows.items()}
    tr = {name: column_sum(r, "train_seconds") for name, r in rows.items()}
    print(f"\nboth arms {'one after the other' if args.sequential else 'at the same time'}; "
          f"1-min load average while they ran: mean {sum(loads) / max(1, len(loads)):.1f}, "
          f"max {max(loads, default=float('nan')):.1f}\n")
    print("| measure | reference | new | new / reference | goal |\n|---|---|---|---|---|")
    print(f"| default run, evaluation (sum of eval_seconds, {len(rows['new'])} checkpoints) | {ev['reference']:.1f} s | "
          f"{ev['new']:.1f} s | {ev['new'] / ev['reference']:.2f}x | <= 0.5x |")
    print(f"| default run, training (sum of train_seconds) | {tr['reference']:.1f} s | {tr['new']:.1f} s | "
          f"{tr['new'] / tr['reference']:.2f}x | |")
    what = "cache seeded without OCR: no scene build" if args.cache_from else "empty cache: scene build, kernels, OCR masks, report"
    print(f"| default run, wall time ({what}) | {wall['reference']:.0f} s | "
          f"{wall['new']:.0f} s | {wall['new'] / wall['reference']:.2f}x | |")
    status = 0
    if args.demo:
        d = {name: demo(REPO, commit_of(src), work) for name, src in arms.items()}
        for name, (w, s, r) in d.items():
            print(f"| demo from a fresh clone ({name}) | set-up {s} s, run {r} s | wall {w:.0f} s | | <= 300 s |")
        print(f"| demo from a fresh clone, wall | {d['reference'][0]:.0f} s | {d['new'][0]:.0f} s | "
              f"{d['new'][0] / d['reference'][0]:.2f}x | <= 300 s |")
    if args.tests:
        secs = {}
        for name, src in arms.items():
            t = time.perf_counter()
            subprocess.run(["bash", "scripts/test.sh"], cwd=src, capture_output=True)
            secs[name] = time.perf_counter() - t
        print(f"| test suite (scripts/test.sh) | {secs['reference']:.0f} s | {secs['new']:.0f} s | "
              f"{secs['new'] / secs['reference']:.2f}x | <= 480 s |")
    diffs = compare(rows["reference"], rows["new"])
    n_cells, cell_diffs = compare_cells(work / "run-reference", work / "run-new")
    print(f"result.json of {n_cells} cell(s): " + ("every figure the same (all but times, paths and versions)"
                                                   if not cell_diffs else f"{len(cell_diffs)} difference(s)"))
    for d in cell_diffs[:20]:
        print("  " + d)
    diffs += cell_diffs
    if diffs:
        print(f"\nresults.csv: {len(diffs)} difference(s) outside the time columns:")
        for d in diffs[:40]:
            print("  " + d)
        status = 1
    else:
        print(f"\nresults.csv: every column but *_seconds and {', '.join(VARYING)} is the same in all "
              f"{len(rows['new'])} cells")
    if args.bank:
        args.bank.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(work / "run-new" / "results.csv", args.bank)
        shutil.copyfile(work / "run-reference" / "results.csv", args.bank.with_suffix(".ref.csv"))
        print(f"banked: {args.bank} (this checkout), {args.bank.with_suffix('.ref.csv')} (reference {args.ref})")
    return status


if __name__ == "__main__":
    sys.exit(main())
