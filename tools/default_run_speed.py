"""The default run (and optionally the demo and the test suite) of a reference commit and of this checkout,
side by side in one run, as ratios new / reference, and the check that the figures did not change.

    python tools/default_run_speed.py --ref f2de671 [--ref-dir DIR] [--out DIR] [--sequential]
                                           [--demo] [--tests] [--engine] [--all] [--bank CSV] [--record JSON]

1. The default run (`strings-bench run --methods strings,3dgs`, the `cpu` schedule) of both versions, each
   with its own empty cache folder (STRINGS_BENCH_CACHE), so each builds the scene, compiles its kernels and
   reads its OCR as on a fresh clone, and no arm is served the other's OCR reads. By default both arms run
   at the same time, so a shared machine's load falls on both alike (--sequential: reference first, then
   this checkout). Printed: each arm's wall time, the sum of `eval_seconds` over the six checkpoints (goal:
   new <= 0.5x the reference's), `train_seconds`, and the ratios.
2. Every column of the two results.csv but the times (`*_seconds`) and `peak_memory_mb` (the process's
   memory, which varies from run to run) compared cell by cell as written, and every cell's result.json, when both
   arms trained on the same scene; a reference that built another room (an older scene generator) is not
   comparable, and the new arm's run (and the demo's, with --demo) is compared with the banked figures instead
   (--figures, the README's). Any difference is printed and the script exits with status 1.
3. --demo: `bash scripts/demo.sh` in a fresh `git clone` of each version (set-up included: the venv and
   pip's downloads), its last line ("demo: set-up S s, run R s") parsed (goal: set-up + run <= 5 min).
4. --tests: `bash scripts/test.sh` of each version in a fresh clone with empty caches, as CI runs it; the
   seconds pytest reports for the tests (goal: <= 8 min), the set-up apart. Never on a machine shared with others.
5. --engine: `tools/engine_ab.py --old ENGINE_REF` (default 142d0ce, the engine before its speed work): 3DGS
   training steps of both engines alternating, at the default run's two model sizes (about 63 000 and 335 000
   Gaussians); printed as old / new (goal: >= 2x at both sizes).
--all is --demo --tests --engine. --record FILE.json writes every measure, its goal and whether it was met, with the
machine, the date and the commits; `--summarize-record FILE.json --table T.csv --readme R.csv` turns a banked record
into the docs' table and the README's paragraph on times (tables of `strings-bench docs refresh`).

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


def commit_of(src: Path) -> str:
    return subprocess.run(["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()


def start_run(src: Path, out: Path, cache: Path, log_path: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(src), "STRINGS_BENCH_CACHE": str(cache)}
    cmd = [sys.executable, "-m", "strings_bench", "run", "--methods", "strings,3dgs", "--out", str(out), "--no-progress"]
    log = open(log_path, "w")
    return subprocess.Popen(cmd, cwd=src, env=env, stdout=log, stderr=subprocess.STDOUT)


def wait_sampling_load(procs: dict, t0: dict, wall: dict, loads: list[float], every_s: float = 5.0) -> None:
    """Wait for every process in `procs`, noting each one's wall time as it ends (to 0.2 s) and the load average
    every `every_s` meanwhile."""
    sampled = float("-inf")
    while True:
        for name, p in procs.items():
            if p.poll() is not None and name not in wall:
                wall[name] = time.perf_counter() - t0[name]
        if all(p.poll() is not None for p in procs.values()):
            return
        if time.perf_counter() - sampled >= every_s:
            loads.append(os.getloadavg()[0])
            sampled = time.perf_counter()
        time.sleep(0.2)


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


def scene_folder(run: Path) -> str | None:
    """The name of the scene folder (name and content key) a run folder's first cell was made on."""
    import json

    for path in sorted(run.glob("cells/*/*/*/*/result.json")):
        scene = json.loads(path.read_text(encoding="utf-8")).get("config", {}).get("scene", {})
        return Path(scene["path"]).name if scene.get("path") else None
    return None


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


def fresh_clone(src_repo: Path, commit: str, where: Path) -> Path:
    """A new clone of `commit` at `where` (replaced if it exists), with the folder of shared data that lies beside
    this checkout (the real photographs some tests read) beside it too, as CI has it."""
    shutil.rmtree(where, ignore_errors=True)
    where.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run(["git", "clone", "-q", str(src_repo), str(where)], check=True)
    subprocess.run(["git", "-C", str(where), "checkout", "-q", commit], check=True)
    shared = (src_repo.parent / "shared").resolve()
    if shared.is_dir() and not (where.parent / "shared").exists():
        (where.parent / "shared").symlink_to(shared)
    return where


def clean_env(cache: Path) -> dict:
    """This process's environment with empty caches under `cache`: the suite's cache and numba's compiled
    kernels, as on a new machine (the tests' numba cache is otherwise ~/.cache/strings-bench/numba)."""
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    env.update(STRINGS_BENCH_CACHE=str(cache), NUMBA_CACHE_DIR=str(cache / "numba"))
    return env


PYTEST_SUMMARY = re.compile(r"^=*\s*(?P<counts>(?:\d+ \w+(?:, )?)+) in (?P<seconds>[\d.]+)s", re.M)


def pytest_summary(output: str) -> dict | None:
    """pytest's last summary line ('1571 passed, 1 skipped in 498.20s (0:08:18)'): the counts and the seconds."""
    found = list(PYTEST_SUMMARY.finditer(output))
    if not found:
        return None
    m = found[-1]
    counts = {w: int(n) for n, w in re.findall(r"(\d+) (\w+)", m.group("counts"))}
    return {"seconds": float(m.group("seconds")), **counts}


def tests(src_repo: Path, commit: str, work: Path) -> dict:
    """scripts/test.sh in a fresh clone of `commit` with empty caches (CI's conditions): wall seconds, the seconds
    pytest reports for the tests, the set-up (the rest), the counts and the exit status."""
    clone = fresh_clone(src_repo, commit, work / f"tests-{commit[:10]}" / "main")
    t = time.perf_counter()
    p = subprocess.run(["bash", "scripts/test.sh"], cwd=clone, env=clean_env(work / f"cache-tests-{commit[:10]}"),
                       capture_output=True, text=True)
    wall = time.perf_counter() - t
    (work / f"tests-{commit[:10]}.log").write_text(p.stdout + p.stderr, encoding="utf-8")
    summary = pytest_summary(p.stdout) or {"seconds": float("nan")}
    return {"wall": wall, "setup": wall - summary["seconds"], "rc": p.returncode, **summary}


def engine(ref: str) -> dict:
    """tools/engine_ab.py --old `ref` at the default run's two model sizes: its JSON (rows and estimate)."""
    import json

    p = subprocess.run([sys.executable, str(REPO / "tools" / "engine_ab.py"), "--old", ref, "--at", "450,1050",
                        "--steps", "8,5", "--reps", "3", "--json"], cwd=REPO, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"engine_ab.py failed:\n{p.stderr[-3000:]}")
    return json.loads(p.stdout[p.stdout.index("{"):])


def demo(src_repo: Path, commit: str, work: Path) -> tuple[float, float | None, float | None]:
    """(wall seconds, set-up s, run s) of scripts/demo.sh in a fresh clone of `commit`."""
    clone = fresh_clone(src_repo, commit, work / f"demo-{commit[:10]}" / "main")
    env = clean_env(work / f"cache-demo-{commit[:10]}")
    t = time.perf_counter()
    p = subprocess.run(["bash", "scripts/demo.sh", "--no-progress"], cwd=clone, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    m = re.search(r"demo: set-up (\d+) s, run (\d+) s", p.stdout)
    return wall, (float(m.group(1)) if m else None), (float(m.group(2)) if m else None)


# ---- measures, their goals and the banked record -------------------------------------------------------------
GOALS = {"new/ref": "<= {:g}x", "ref/new": ">= {:g}x", "new<=": "<= {:g} s"}


def measure(name: str, reference, new, unit: str, goal: tuple[str, float] | None = None, speedup: bool = False,
            **extra) -> dict:
    """One row: both arms' values, the ratio (new / reference, or reference / new where the goal is a speed-up),
    the goal and whether the new arm meets it."""
    ok = reference not in (None, 0) and new not in (None, 0) and reference == reference and new == new
    kind = goal[0] if goal else "ref/new" if speedup else "new/ref"
    ratio = (reference / new if kind == "ref/new" else new / reference) if ok else None
    met = None
    if goal and new is not None and new == new:
        met = {"new/ref": ratio is not None and ratio <= goal[1], "ref/new": ratio is not None and ratio >= goal[1],
               "new<=": new <= goal[1]}[kind]
    return {"measure": name, "reference": reference, "new": new, "unit": unit,
            "ratio_kind": "reference / new" if kind == "ref/new" else "new / reference", "ratio": ratio,
            "goal": GOALS[goal[0]].format(goal[1]) if goal else "", "met": met, **extra}


def fmt_value(x, unit: str) -> str:
    return "" if x is None or x != x else f"{x:.1f} {unit}" if unit == "ms" or x < 100 else f"{x:.0f} {unit}"


def measure_row(m: dict) -> tuple[str, ...]:
    ratio = "" if m["ratio"] is None else f"{m['ratio']:.2f}x ({m['ratio_kind']})"
    met = {None: "", True: "met", False: "not met"}[m["met"]]
    return (m["measure"], fmt_value(m["reference"], m["unit"]), fmt_value(m["new"], m["unit"]), ratio, m["goal"], met)


def print_measures(measures: list[dict], header: bool = False) -> None:
    if header:
        print("| measure | reference | new | ratio | goal | |\n|---|---|---|---|---|---|")
    for m in measures:
        print("| " + " | ".join(measure_row(m)) + " |", flush=True)


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or platform.machine()


def check_figures(work: Path, rows: dict, ref: str, banked_csv: Path, banked_name: str,
                  demo_rows: Path | None = None) -> tuple[list[str], str]:
    """Every non-time column of the new arm's run against the reference arm's (cell by cell, results.csv and every
    result.json) when both built the same room; else against the banked figures (`banked_csv`, the README's), which
    come from one machine and are otherwise printed apart, not counted: on a CPU of another kind the word-crop
    recogniser's figures can differ (docs/reproducibility.md). The demo's run (`demo_rows`) is held against this
    machine's run where there is one. Returns (the differences that count, what they were compared with)."""
    same_room = scene_folder(work / "run-reference") == scene_folder(work / "run-new")
    banked = read_csv(banked_csv) if banked_csv.is_file() else None
    banked_diffs = compare(banked, rows["new"]) if banked is not None else []
    if same_room:
        diffs = compare(rows["reference"], rows["new"])
        n_cells, cell_diffs = compare_cells(work / "run-reference", work / "run-new")
        print(f"result.json of {n_cells} cell(s): " + ("every figure the same (all but times, paths and versions)"
                                                       if not cell_diffs else f"{len(cell_diffs)} difference(s)"))
        for d in cell_diffs[:20]:
            print("  " + d)
        diffs += cell_diffs
        against = f"the reference's ({ref})"
    else:  # an older scene generator (or another CPU's BLAS for one before version 3) builds another room
        print(f"the reference built another scene ({scene_folder(work / 'run-reference')}; this checkout: "
              f"{scene_folder(work / 'run-new')}): its figures are not this room's; the new arm's are compared with "
              f"the banked {banked_name}")
        diffs, against = list(banked_diffs), f"the banked {banked_name}"
    if demo_rows is not None and demo_rows.is_file():
        base = rows["new"] if same_room else banked
        if base is not None:
            diffs += [f"demo: {d}" for d in compare(base, read_csv(demo_rows))]
            against += " (and the demo's run against " + ("this checkout's run)" if same_room else "them)")
    if diffs:
        print(f"\nresults.csv: {len(diffs)} difference(s) outside the time columns against {against}:")
        for d in diffs[:40]:
            print("  " + d)
    else:
        print(f"\nresults.csv: every column but *_seconds and {', '.join(VARYING)} is the same in all "
              f"{len(rows['new'])} cells as in {against}")
    if banked is not None and same_room:
        cols = sorted({d.split()[1].rstrip(":") for d in banked_diffs if len(d.split()) > 1})
        print(f"against the banked {banked_name} (made on another machine, perhaps another kind of CPU): "
              + ("the same" if not banked_diffs else
                 f"{len(banked_diffs)} difference(s), in {', '.join(cols)} (not counted above)"))
        for d in banked_diffs[:40]:
            print("  " + d.replace(": reference '", ": banked '"))
    return diffs, against


def cpu_kind(cpuinfo: Path = Path("/proc/cpuinfo")) -> dict:
    """The CPU's vendor family and model numbers and its widest vector instruction set (from /proc/cpuinfo): two
    machines that both say "AMD EPYC" can be a Zen 3 with AVX2 and a Zen 5 with AVX-512, 1.5-1.9x apart in speed and
    apart in some ONNX Runtime figures (docs/reproducibility.md). Empty where /proc/cpuinfo is not there."""
    try:
        text = cpuinfo.read_text()
    except OSError:
        return {}
    fields = {}
    for line in text.splitlines():
        if ":" not in line:
            if fields:
                break  # the first processor's block is enough
            continue
        key, value = (part.strip() for part in line.split(":", 1))
        fields.setdefault(key, value)
    flags = set(fields.get("flags", "").split())
    isa = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "SSE"
    return {"vendor": fields.get("vendor_id"), "family": fields.get("cpu family"), "model": fields.get("model"),
            "vector_isa": isa}


def describe_cpu(machine: dict) -> str:
    """'AMD EPYC (family 25, model 1, AVX2)', or the bare name from a record made before the kind was recorded."""
    kind = machine.get("cpu_kind") or {}
    if not kind.get("family"):
        return machine["cpu"]
    return f"{machine['cpu']} (family {kind['family']}, model {kind['model']}, {kind['vector_isa']})"


def write_record(path: Path, args, arms: dict, measures: list[dict], loads: list[float], same: bool,
                 against: str) -> None:
    import json
    from datetime import datetime, timezone

    rec = {"command": "python tools/default_run_speed.py " + " ".join(sys.argv[1:]),
           "finished_utc": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M"),
           "machine": {"cpu": cpu_name(), "cpu_kind": cpu_kind(), "cores": os.cpu_count(), "load_after": load(),
                       "load_during_runs_max": max(loads, default=None)},
           "reference": {"commit": commit_of(arms["reference"]), "engine": args.engine_ref if args.engine else None},
           "new": {"commit": commit_of(arms["new"])},
           "figures_same": same, "figures_compared_with": against, "measures": measures}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(rec, indent=1) + "\n", encoding="utf-8")
    tmp.replace(path)
    print(f"record: {path}")


def find(measures: list[dict], prefix: str) -> dict | None:
    return next((m for m in measures if m["measure"].startswith(prefix)), None)


def tests_outcome(m: dict) -> str:
    """' (1 583 passed)', or with the failures, from a test-suite measure that counts them."""
    passed, failed = (m.get(k, {}).get("new") for k in ("passed", "failed"))
    if passed is None:
        return ""
    return f" ({passed:,} passed".replace(",", " ") + (f", {failed} failed)" if failed else ")")


def summarize_record(path: Path, table: Path | None, readme: Path | None) -> int:
    """The record's measures as the docs' table (CSV) and the README's paragraph on how long the two commands
    take (a CSV of one `text` row), both for `strings-bench docs refresh`."""
    import json

    rec = json.loads(path.read_text(encoding="utf-8"))
    rows = [("measure", "reference", "new", "ratio", "goal", "")] + [measure_row(m) for m in rec["measures"]]
    for r in rows:
        print(" | ".join(r))
    if table:
        with open(table, "w", newline="", encoding="utf-8") as fh:
            csv.writer(fh).writerows(rows)
    if readme:
        ms = rec["measures"]
        setup, run = find(ms, "demo from a fresh clone, set-up ("), find(ms, "demo from a fresh clone, run")
        tests_m, tests_setup = find(ms, "default test suite, fresh clone: the tests"), find(ms, "default test suite, fresh clone: set-up")
        if not (setup and run and tests_m and tests_setup):
            raise SystemExit(f"{path}: the record has no demo or test-suite measure (run with --all)")
        text = (f"Measured from fresh clones on a {rec['machine']['cores']}-core {describe_cpu(rec['machine'])}: "
                f"`bash scripts/demo.sh` took {setup['new']:.0f} s of set-up and {run['new']:.0f} s of run "
                f"({setup['new'] + run['new']:.0f} s in all; it prints both in its last line), and `bash scripts/test.sh` "
                f"{tests_setup['new']:.0f} s of set-up and {tests_m['new']:.0f} s of tests{tests_outcome(tests_m)}. How: "
                f"[docs/results/engine-speed.md](docs/results/engine-speed.md), \"The default run, the demo and the tests, "
                f"measured together\".")
        with open(readme, "w", newline="", encoding="utf-8") as fh:
            csv.writer(fh).writerows([("text",), (text,)])
    return 0


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
    ap.add_argument("--tests", action="store_true",
                    help="also time scripts/test.sh of each in a fresh clone with empty caches (an idle machine only)")
    ap.add_argument("--engine", action="store_true", help="also run tools/engine_ab.py --old ENGINE_REF")
    ap.add_argument("--engine-ref", default="142d0ce", help="the engine reference of --engine (default 142d0ce)")
    ap.add_argument("--all", action="store_true", help="--demo --tests --engine")
    ap.add_argument("--record", type=Path, help="write every measure, its goal and the machine here (JSON)")
    ap.add_argument("--summarize-record", type=Path, metavar="RECORD",
                    help="only turn a banked record into tables (--table, --readme)")
    ap.add_argument("--readme", type=Path, help="with --summarize-record: write the README's paragraph (CSV, text)")
    ap.add_argument("--compare-runs", type=Path, nargs=2, metavar=("REF_RUN", "NEW_RUN"),
                    help="only compare two run folders: results.csv's common cells and every cell's result.json")
    ap.add_argument("--summarize", type=Path, help="only read a banked pair (BANKED.csv and BANKED.ref.csv) again")
    ap.add_argument("--table", type=Path, help="with --summarize or --summarize-record: write the table as CSV here")
    ap.add_argument("--bank", type=Path, help="copy this checkout's results.csv here (the reference's beside it)")
    ap.add_argument("--figures", default="docs/results/data/default-run/results.csv",
                    help="the banked results.csv (the README's figures) the new arm's run must reproduce in every "
                         "column but the times (default docs/results/data/default-run/results.csv)")
    args = ap.parse_args()
    if args.all:
        args.demo = args.tests = args.engine = True
    if args.summarize_record:
        return summarize_record(args.summarize_record, args.table, args.readme)
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

    try:
        from tools.checkouts import ref_checkout
    except ImportError:  # run as a file (python tools/default_run_speed.py): its own folder is on the path
        from checkouts import ref_checkout

    ref_src = ref_checkout(args.ref, args.ref_dir)
    work = args.out or Path(tempfile.mkdtemp(prefix="default-run-speed-"))
    work.mkdir(parents=True, exist_ok=True)
    new_src = (args.new_dir or REPO).resolve()
    arms = {"reference": ref_src, "new": new_src}
    print(f"reference {args.ref} at {ref_src}; new: {new_src} ({commit_of(new_src)}); runs under {work}; load before: {load()}", flush=True)
    wall: dict[str, float] = {}
    t0 = {}
    procs = {}
    loads: list[float] = []  # the 1-min load average every 5 s while a run is going
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
            wait_sampling_load({name: procs[name]}, t0, wall, loads)
    wait_sampling_load(procs, t0, wall, loads)
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
    what = "cache seeded without OCR: no scene build" if args.cache_from else "empty cache: scene build, kernels, OCR masks, report"
    measures = [
        measure(f"default run, evaluation (sum of eval_seconds, {len(rows['new'])} checkpoints)", ev["reference"],
                ev["new"], "s", goal=("new/ref", 0.5)),
        measure("default run, training (sum of train_seconds)", tr["reference"], tr["new"], "s"),
        measure(f"default run, wall time ({what})", wall["reference"], wall["new"], "s"),
    ]
    print_measures(measures, header=True)
    status = 0
    if args.demo:
        d = {name: demo(REPO, commit_of(src), work) for name, src in arms.items()}
        for name, (w, s_, r) in d.items():
            print(f"  demo from a fresh clone ({name}): set-up {s_} s, run {r} s, wall {w:.0f} s", flush=True)
        total = {name: (v[1] or 0) + (v[2] or 0) if v[1] is not None else float("nan") for name, v in d.items()}
        more = [measure("demo from a fresh clone, set-up (its last line)", d["reference"][1], d["new"][1], "s"),
                measure("demo from a fresh clone, run (its last line)", d["reference"][2], d["new"][2], "s"),
                measure("demo from a fresh clone, set-up + run", total["reference"], total["new"], "s",
                        goal=("new<=", 300))]
        print_measures(more)
        measures += more
    if args.tests:
        t = {name: tests(REPO, commit_of(src), work) for name, src in arms.items()}
        for name, x in t.items():
            print(f"  test suite ({name}): {x.get('passed', 0)} passed, {x.get('failed', 0)} failed, tests "
                  f"{x['seconds']:.0f} s, set-up {x['setup']:.0f} s, exit {x['rc']}", flush=True)
        more = [measure("default test suite, fresh clone: the tests (pytest's seconds)", t["reference"]["seconds"],
                        t["new"]["seconds"], "s", goal=("new<=", 480),
                        passed={k: t[k].get("passed", 0) for k in t}, failed={k: t[k].get("failed", 0) for k in t}),
                measure("default test suite, fresh clone: set-up (scripts/test.sh less the tests)",
                        t["reference"]["setup"], t["new"]["setup"], "s")]
        print_measures(more)
        measures += more
        if t["new"]["rc"] != 0:
            print(f"the new arm's test suite failed (exit {t['new']['rc']}): {work / 'tests-*.log'}")
            status = 1
    if args.engine:
        e = engine(args.engine_ref)
        more = []
        for row in e["rows"]:
            more.append(measure(f"engine, 3DGS step at {row['gaussians']} Gaussians (ms; engine {args.engine_ref} "
                                f"against this one, reference / new)", row["old_ms"], row["new_ms"], "ms",
                                goal=("ref/new", 2.0), identical=row["identical"]))
        if e.get("estimate"):
            est = e["estimate"]
            more.append(measure("engine, the default run's 3DGS training, interpolated (reference / new)",
                                est["old_s"], est["new_s"], "s", speedup=True))
        print_measures(more)
        measures += more
    diffs, against = check_figures(work, rows, args.ref, REPO / args.figures, args.figures,
                                   demo_rows=work / f"demo-{commit_of(new_src)[:10]}" / "main" / "runs" / "default"
                                   / "results.csv" if args.demo else None)
    if diffs:
        status = 1
    if args.record:
        write_record(args.record, args, arms, measures, loads, same=not diffs, against=against)
    if args.bank:
        args.bank.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(work / "run-new" / "results.csv", args.bank)
        shutil.copyfile(work / "run-reference" / "results.csv", args.bank.with_suffix(".ref.csv"))
        print(f"banked: {args.bank} (this checkout), {args.bank.with_suffix('.ref.csv')} (reference {args.ref})")
    return status


if __name__ == "__main__":
    sys.exit(main())
