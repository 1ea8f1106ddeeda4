"""Run a comparison cell by cell: one (scene, method, seed) per run folder, a few at a time, each banked as soon as
it finishes. The real captures by name, or any other scenes by dataset id:

    python tools/captures_cells.py --captures tum_freiburg3_office,bundler_et [--methods 3dgs,strings,...]
        [--seeds 0-2] [--lanes 2] [--runs runs] [--bank docs/results/data/captures/cells] [--dry-run]
    python tools/captures_cells.py --scenes synthetic360-cpu/storeroom,synthetic360-cpu/pantry --methods ...
        --bank docs/results/data/synthetic360-cpu/cells

Each cell is the captures' regime (docs/results/captures.md) for one method and seed:

    strings-bench run --schedule cpu --downscale 1 --methods M --set seed=S --datasets captures/C \\
        --ocr ENGINE --out RUNS/cap-C-seedS-M --no-progress            # output in RUNS/cap-C-seedS-M.log

with ENGINE the capture's own OCR engine (its GT engine, `strings-bench datasets show captures/C`); a scene given
by `--scenes DATASET/SCENE` runs at the schedule's own size (no `--downscale`) with the default OCR engine, in the
folder RUNS/DATASET-SCENE-seedS-M. Each run has one thread
per run (NUMBA_NUM_THREADS, OMP_NUM_THREADS and MKL_NUM_THREADS set to 1), so that `--lanes` runs share as many
cores. A run folder per cell keeps each cell's training time and peak memory its own, and lets cells of one
comparison come from several days or machines.

- A cell all of whose checkpoints are banked (`--bank`, tools/bank_cells.py) is skipped; one whose run
  folder holds every checkpoint is banked and skipped; any other is run, and `strings-bench run` resumes what an
  interrupted run left in its folder.
- Cells run in the order of the captures, then the seeds, then the methods given, so a seed's methods finish
  together; a finished run's folder is banked before its lane starts the next cell.
- A capture not built yet is built before its first cell starts (`strings-bench datasets prepare`), while the
  running cells go on: two runs would otherwise build it at once.
- A cell whose run folder another process is running (its lock held: `strings-bench run` holds it while it
  runs) counts as one of the `--lanes` runs until that process ends; it is then banked if it finished, and run
  (resumed) here if not. So a second copy of this script, or a cell started by hand, is never run twice at once.
- `--dry-run` prints the plan (each cell: banked, running elsewhere, finished, or to run) and runs nothing.

Prints a line per cell started and finished; rc 0 when every cell finished and was banked, 1 when some run
failed (its log names why; the other cells still run), 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.results import RESULT_FILE
from strings_bench.core.schedules import get_schedule
from strings_bench.datasets.captures import CAPTURES, is_built
from strings_bench.store import run_folder_busy

SCHEDULE = "cpu"
DOWNSCALE = "1"
METHODS = ("3dgs", "strings", "strings-pos-lr", "edc-absgs", "improved-gs")
N_CHECKPOINTS = len(get_schedule(SCHEDULE).paper_checkpoints)
ONE_THREAD = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


BANK_CELLS = Path(__file__).with_name("bank_cells.py")


def bank(run_dir: Path, bank_dir: Path) -> str:
    """tools/bank_cells.py RUN_DIR --out BANK_DIR; returns its line (raises StringsBenchError when it fails)."""
    proc = subprocess.run([sys.executable, str(BANK_CELLS), str(run_dir), "--out", str(bank_dir)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise StringsBenchError(f"banking {run_dir} failed: {proc.stderr.strip() or proc.stdout.strip()}")
    return proc.stdout.strip()


@dataclass(frozen=True)
class Cell:
    capture: str  # the scene's name (a capture's name when dataset is "captures")
    method: str
    seed: int
    dataset: str = "captures"

    @property
    def is_capture(self) -> bool:
        return self.dataset == "captures"

    @property
    def folder_name(self) -> str:
        prefix = "cap" if self.is_capture else self.dataset
        return f"{prefix}-{self.capture}-seed{self.seed}-{self.method}"

    def checkpoints(self, root: Path) -> int:
        """How many of the cell's checkpoints have a result under root/<folder name> (a run folder or a banked one)."""
        cells = root / self.folder_name / "cells" / self.method / self.dataset / self.capture
        return len(list(cells.glob(f"*/{RESULT_FILE}"))) if cells.is_dir() else 0

    def command(self, runs: Path, strings_bench: str) -> list[str]:
        if self.is_capture:  # full size, the capture's own GT engine
            extra = ["--downscale", DOWNSCALE]
            tail = ["--ocr", CAPTURES[self.capture].gt_ocr]
        else:
            extra, tail = [], []
        return [strings_bench, "run", "--schedule", SCHEDULE, *extra, "--methods", self.method,
                "--set", f"seed={self.seed}", "--datasets", f"{self.dataset}/{self.capture}",
                *tail, "--out", str(runs / self.folder_name), "--no-progress"]


def seeds_arg(text: str) -> list[int]:
    """"0-2" or "0,2,5" -> the seeds."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.strip().partition("-")
        if not lo.isdigit() or (hi and not hi.isdigit()):
            raise argparse.ArgumentTypeError(f"seeds are numbers or ranges (0-2, 0,2), got {text!r}")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def plan(captures: list[str], methods: list[str], seeds: list[int], scenes: list[str] = ()) -> list[Cell]:
    """The cells in run order: scene by scene, then seed by seed, the methods of a seed in turn (A, B, A, B)."""
    unknown = [c for c in captures if c not in CAPTURES]
    if unknown:
        raise StringsBenchError(f"unknown capture(s): {', '.join(unknown)}", hint=f"captures: {', '.join(CAPTURES)}")
    places = [("captures", c) for c in captures]
    for text in scenes:
        dataset, _, scene = text.partition("/")
        if not dataset or not scene or "/" in scene:
            raise StringsBenchError(f"--scenes takes DATASET/SCENE, got {text!r}",
                                    hint="e.g. synthetic360-cpu/storeroom (strings-bench datasets list)")
        places.append((dataset, scene))
    return [Cell(scene, m, s, dataset) for dataset, scene in places for s in seeds for m in methods]


RUNNING_ELSEWHERE = "running elsewhere"


def state(cell: Cell, runs: Path, bank_dir: Path, n_checkpoints: int = N_CHECKPOINTS) -> str:
    """"banked", "running elsewhere" (another process holds its run folder's lock), "finished" (every checkpoint
    in its run folder, not all banked) or "to run"."""
    if cell.checkpoints(bank_dir) >= n_checkpoints:
        return "banked"
    if run_folder_busy(runs / cell.folder_name):
        return RUNNING_ELSEWHERE
    if cell.checkpoints(runs) >= n_checkpoints:
        return "finished"
    return "to run"


def run_cells(cells: list[Cell], runs: Path, bank_dir: Path, lanes: int, strings_bench: str,
              poll_seconds: float = 5.0) -> int:
    """Run the cells not banked, `lanes` at a time; bank each finished folder. Returns the number of failed runs."""
    todo, elsewhere = [], []
    for cell in cells:
        st = state(cell, runs, bank_dir)
        if st == "finished":
            print(f"{cell.folder_name}: finished before; {bank(runs / cell.folder_name, bank_dir)}", flush=True)
        elif st == RUNNING_ELSEWHERE:  # takes a lane until it ends
            elsewhere.append(cell)
            print(f"{cell.folder_name}: running in another process; banked here when it ends", flush=True)
        elif st == "to run":
            todo.append(cell)
    env = {**os.environ, **ONE_THREAD}
    running: dict[Cell, tuple[subprocess.Popen, float]] = {}
    failed = 0
    prepared: set[str] = set()
    runs.mkdir(parents=True, exist_ok=True)
    while todo or running or elsewhere:
        for cell in list(elsewhere):
            if run_folder_busy(runs / cell.folder_name):
                continue
            elsewhere.remove(cell)
            if state(cell, runs, bank_dir) == "finished":
                print(f"{cell.folder_name}: ended in the other process; {bank(runs / cell.folder_name, bank_dir)}",
                      flush=True)
            else:  # stopped before its last checkpoint: resumed here, first
                todo.insert(0, cell)
                print(f"{cell.folder_name}: stopped in the other process before finishing; resumed here", flush=True)
        for cell, (proc, t0) in list(running.items()):
            if proc.poll() is None:
                continue
            del running[cell]
            minutes = (time.monotonic() - t0) / 60
            if proc.returncode == 0:
                print(f"{cell.folder_name}: done in {minutes:.1f} min; {bank(runs / cell.folder_name, bank_dir)}",
                      flush=True)
            else:
                failed += 1
                print(f"{cell.folder_name}: FAILED (rc {proc.returncode}) after {minutes:.1f} min; see "
                      f"{runs / cell.folder_name}.log", flush=True)
        while todo and len(running) + len(elsewhere) < lanes:
            cell = todo.pop(0)
            if cell.is_capture and cell.capture not in prepared:
                if not is_built(cell.capture):  # built once, before its cells run side by side
                    print(f"building captures/{cell.capture} ...", flush=True)
                    proc = subprocess.run([strings_bench, "datasets", "prepare", f"captures/{cell.capture}"], env=env,
                                          capture_output=True, text=True)
                    if proc.returncode != 0:
                        raise StringsBenchError(f"building captures/{cell.capture} failed:\n{proc.stderr[-2000:]}")
                prepared.add(cell.capture)
            log = open(runs / f"{cell.folder_name}.log", "a", encoding="utf-8")
            proc = subprocess.Popen(cell.command(runs, strings_bench), env=env, stdout=log, stderr=subprocess.STDOUT)
            log.close()  # the child holds its own descriptor
            running[cell] = (proc, time.monotonic())
            print(f"{cell.folder_name}: started", flush=True)
        if running or elsewhere:
            time.sleep(poll_seconds)
    return failed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--captures", default="", help="comma-separated capture names (strings-bench datasets list)")
    ap.add_argument("--scenes", default="", help="comma-separated DATASET/SCENE of other datasets, run at the "
                                                   "schedule's own size with the default OCR engine")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated (default: %(default)s)")
    ap.add_argument("--seeds", type=seeds_arg, default=[0, 1, 2], help="e.g. 0-2 or 0,2 (default: 0-2)")
    ap.add_argument("--lanes", type=int, default=2, help="runs at a time, one thread each (default: %(default)s)")
    ap.add_argument("--runs", type=Path, default=Path("runs"), help="where the run folders go (default: runs)")
    ap.add_argument("--bank", type=Path, default=Path("docs/results/data/captures/cells"),
                    help="the bank of finished cells (default: %(default)s)")
    ap.add_argument("--strings-bench", default="strings-bench", help=argparse.SUPPRESS)  # tests: a stand-in
    ap.add_argument("--dry-run", action="store_true", help="print the plan and run nothing")
    args = ap.parse_args(argv)
    if args.lanes < 1:
        ap.error("--lanes must be at least 1")
    if not args.captures.strip() and not args.scenes.strip():
        ap.error("give --captures, --scenes or both")
    try:
        cells = plan([c.strip() for c in args.captures.split(",") if c.strip()],
                     [m.strip() for m in args.methods.split(",") if m.strip()], args.seeds,
                     [c.strip() for c in args.scenes.split(",") if c.strip()])
        if args.dry_run:
            for cell in cells:
                print(f"{cell.folder_name}: {state(cell, args.runs, args.bank)}")
            return 0
        failed = run_cells(cells, args.runs, args.bank, args.lanes, args.strings_bench)
    except StringsBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
