"""Run schedules: how long a run trains and which checkpoints it evaluates (`run --schedule`), and how an
iteration is labelled (7000 -> 7K). This is the one table of schedule scales.

A *schedule* is the run's: its steps scale, its checkpoints (named by the paper iteration they stand
for) and the scenes it uses when none are named. It is not a *method preset* (a named variant of one
method's settings, such as STRinGS' `release`; `run --presets strings=release`; methods/strings/spec.py).
The schedule's scale reaches every method that trains (its `steps_scale` setting; bench/plan.py), always.

Every iteration number of a method (checkpoints, densification window, resets, LR schedules) is
multiplied by the schedule's steps_scale; intervals keep at least strategies.base.MIN_SCALED_INTERVAL
steps. Measured on 2 CPU cores (synthetic scenes, 320x240; see README and docs/engine.md):
- cpu (0.05: 150/350/1 500 steps for 3K/7K/30K, synthetic360-cpu/storeroom) is the default run: the
  CPU regime of docs/synthetic.md on a frozen room-scale scene where 3DGS reads late, as on the paper's
  captures, in DEFAULT_RUN_TIME (README, "Results of the default run");
- early (0.15: 450/1 050 steps for 3K/7K, synthetic/extinguisher), the default before: the paper's
  "readable early" checkpoints on an easy object-centred scene where 3DGS reads early
  (docs/results/default-run.md, "The default run");
- quick (0.01: 70/300 steps for 7K/30K) runs all five synthetic scenes, two methods, in about 10
  minutes, but text stays illegible (every CER ~1.0): the pipeline end to end, not a comparison;
- standard (0.05: 350/1500 steps) gives visibly sharper text, at several minutes per method and scene;
- paper (1.0) is the paper's 30K schedule (hours per scene on a CPU; meant for a GPU).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace
from typing import Iterable

from strings_bench.core.errors import StringsBenchError


def iteration_label(iteration: int) -> str:
    """How a paper iteration is named everywhere (tables, results.csv, `methods show`): 7000 -> '7K',
    30000 -> '30K', 350 -> '350'."""
    return f"{iteration // 1000}K" if iteration >= 1000 and iteration % 1000 == 0 else str(iteration)


# Schedules. Checkpoints are named by the paper iteration they stand for; the iteration actually
# trained is round(paper_iteration * steps_scale). DEFAULT_SCHEDULE is the default of `strings-bench run`.
# 3K is the end of STRinGS' phase 1 (the position-LR ablation of the paper is read there).
PAPER_CHECKPOINTS = (3000, 7000, 30000)
DEFAULT_DATASETS = ("synthetic",)
# The default run's time (`strings-bench run --methods strings,3dgs`, the run alone: no set-up), stated here once:
# `run --help`, the docs' CLI reference, the HTML report's schedule line and the README take it from here. Measured
# from a fresh clone on 2 idle cores: docs/results/data/default-run-speed/record.json, the demo's run (211 s;
# docs/results/engine-speed.md); tests/lint/test_docs_rules.py holds this figure to that record.
DEFAULT_RUN_MINUTES = 4
DEFAULT_RUN_TIME = f"about {DEFAULT_RUN_MINUTES} min on 2 CPU cores"
DEFAULT_SCHEDULE = "cpu"


@dataclass(frozen=True)
class Schedule:
    """A run's schedule: its steps scale, the paper checkpoints it evaluates, its default scenes."""

    name: str
    steps_scale: float
    paper_checkpoints: tuple[int, ...] = PAPER_CHECKPOINTS
    downscale: float = 1
    description: str = ""
    # the scenes a run of this schedule uses when no --datasets is given (None: every synthetic scene)
    datasets: tuple[str, ...] | None = None
    # `--checkpoints every:N`: also evaluate every N paper iterations up to the last checkpoint (None: no dense
    # checkpoints). The dense ones that are not paper_checkpoints are evaluated cheaply (`dense_checkpoints`).
    dense_every: int | None = None
    # How a shrunk schedule stands in for the paper's (MINIATURES): "shrink" scales every iteration number
    # and keeps the paper's per-step learning rates, as every CPU regime has.
    miniature: str = "shrink"

    def miniature_settings(self) -> dict:
        """The method settings the miniature adds (to every method that trains with a steps scale)."""
        return MINIATURES[self.miniature].settings(self.steps_scale)

    def default_datasets(self) -> list[str]:
        """The --datasets of a run of this schedule that names none."""
        return list(self.datasets or DEFAULT_DATASETS)

    def dense_paper_checkpoints(self) -> list[int]:
        """The paper iterations of `every:N` (N, 2N, ... up to the last paper checkpoint), [] without it."""
        if not self.dense_every:
            return []
        return list(range(self.dense_every, max(self.paper_checkpoints) + 1, self.dense_every))

    def checkpoints(self, steps_scale: float | None = None) -> list[int]:
        """Every iteration trained to and evaluated: the paper checkpoints and the dense ones, scaled."""
        s = self.steps_scale if steps_scale is None else steps_scale
        return sorted({max(1, int(round(c * s))) for c in (*self.paper_checkpoints, *self.dense_paper_checkpoints())})

    def dense_checkpoints(self, steps_scale: float | None = None) -> list[int]:
        """The iterations that only `every:N` adds (not a paper checkpoint's): evaluated with the word-crop
        metrics only unless the run asks for full evaluation (`--dense-eval full`)."""
        s = self.steps_scale if steps_scale is None else steps_scale
        main = {max(1, int(round(c * s))) for c in self.paper_checkpoints}
        return sorted({max(1, int(round(c * s))) for c in self.dense_paper_checkpoints()} - main)

    def label_of(self, iteration: int, steps_scale: float | None = None) -> str:
        s = self.steps_scale if steps_scale is None else steps_scale
        for c in (*self.paper_checkpoints, *self.dense_paper_checkpoints()):
            if max(1, int(round(c * s))) == iteration:
                return iteration_label(c)
        return iteration_label(iteration)


@dataclass(frozen=True)
class Miniature:
    """A way to shrink the paper's schedule by a factor s (`run --miniature NAME`): the settings it gives every
    training method at scale s. Why they differ (docs/miniature.md): with the per-step learning rates kept, the
    sum of the position LR over a run -- how far a Gaussian can travel -- shrinks by s with the schedule."""

    name: str
    description: str
    position_lr_exponent: float = 0.0  # the position LR is multiplied by s ** -exponent
    interval_floor: int | None = None  # shortest refinement interval in steps (None: the suite's, 50)

    def settings(self, steps_scale: float) -> dict:
        if steps_scale == 1:
            return {}
        out = {}
        if self.position_lr_exponent:
            out["position_lr_gain"] = float(steps_scale) ** -self.position_lr_exponent
        if self.interval_floor is not None:
            out["interval_floor"] = int(self.interval_floor)
        return out


MINIATURES: dict[str, Miniature] = {m.name: m for m in (
    Miniature("shrink", "every iteration number x s, the paper's per-step learning rates (the default; "
                        "a Gaussian can move s times as far as in the paper)"),
    Miniature("lr-sum", "as shrink, with the position LR x 1/s: its sum over the run, how far a Gaussian can "
                        "move, is the paper's", position_lr_exponent=1.0),
    Miniature("lr-sqrt", "as shrink, with the position LR x 1/sqrt(s): halfway (geometrically) between shrink "
                         "and lr-sum", position_lr_exponent=0.5),
    # Shrinking keeps refinement intervals at >= 50 steps (strategies.base.MIN_SCALED_INTERVAL), so a shrunk run
    # refines fewer times than the paper's and its model stays small: 3DGS on storeroom has 3.9k Gaussians at 3K at
    # x0.05 against 223k at x1 (docs/results/full-schedule.md).
    Miniature("rounds", "as shrink, with every refinement interval x s too (no 50-step floor): as many "
                        "refinement rounds as the paper's", interval_floor=1),
    Miniature("lr-sum-rounds", "lr-sum and rounds together: the paper's position-LR sum and its number of "
                               "refinement rounds", position_lr_exponent=1.0, interval_floor=1),
)}


SCHEDULES: dict[str, Schedule] = {
    "paper": Schedule("paper", 1.0,
                    description="the paper's schedule: 30K iterations, checkpoints 3K/7K/30K"),
    # standard and quick leave out 3K: OCR of every test view costs ~1 s per view and cell on a CPU.
    "standard": Schedule("standard", 0.05, paper_checkpoints=(7000, 30000),
                       description="the paper's schedule scaled by 0.05 (350/1500 iterations for 7K/30K)"),
    # The default run: the CPU regime on one frozen synthetic360-cpu room, where 3DGS reads late as on
    # the paper's captures and the methods separate at 30K beyond seed noise (README, docs/strings.md).
    "cpu": Schedule("cpu", 0.05, paper_checkpoints=PAPER_CHECKPOINTS,
                    datasets=("synthetic360-cpu/storeroom",),
                    description="the default: the CPU regime, the paper's schedule scaled by 0.05 (150/350/1500 "
                                f"iterations for 3K/7K/30K) on synthetic360-cpu/storeroom, {DEFAULT_RUN_TIME}; "
                                "3DGS reads late there, as on the paper's captures"),
    # The longer CPU regime, frozen on 3DGS alone before any other method ran on it: at x0.1 3DGS's
    # known-text CER at 7K is 0.755 (draws 0-2 of the three rooms, range 0.690-0.789) against the paper's 0.736
    # OCR-CER; at x0.05 it reads ~0.9 there and at x0.2 0.139 (storeroom), docs/synthetic.md "The longer CPU
    # regime". The paper's 7K question can be asked here; ~1-3 min per 7K cell on 2 cores.
    "cpu-long": Schedule("cpu-long", 0.1, paper_checkpoints=PAPER_CHECKPOINTS,
                         datasets=("synthetic360-cpu",),
                         description="the longer CPU regime: the paper's schedule scaled by 0.1 (300/700/3000 "
                                     "iterations for 3K/7K/30K) on the three synthetic360-cpu rooms, where 3DGS "
                                     "reads at 7K as on the paper's captures (known-text CER ~0.75)"),
    # The former default run: one easy scene, the paper's early checkpoints (docs/ocr.md).
    "early": Schedule("early", 0.15, paper_checkpoints=(3000, 7000),
                    datasets=("synthetic/extinguisher",),
                    description="the paper's schedule scaled by 0.15 (450/1050 iterations for 3K/7K) on "
                                "synthetic/extinguisher, ~5 min on 2 CPU cores; text becomes legible, 3DGS first"),
    "quick": Schedule("quick", 0.01, paper_checkpoints=(7000, 30000),
                    description="the paper's schedule scaled by 0.01 (70/300 iterations for 7K/30K) on the five "
                                "synthetic scenes, ~10 min on 2 CPU cores; text stays illegible (CER ~1.0)"),
    "tiny": Schedule("tiny", 0.005, description="smoke test: scaled by 0.005 (15/35/150 iterations for 3K/7K/30K)"),
}


def get_schedule(name: str) -> Schedule:
    if name not in SCHEDULES:
        raise StringsBenchError(f"unknown schedule {name!r}", hint=f"schedules: {', '.join(SCHEDULES)}")
    return SCHEDULES[name]


def schedule(name: str, steps_scale: float | None = None, checkpoints: Iterable[int] | None = None,
             dense_every: int | None = None, miniature: str | None = None) -> Schedule:
    """The run's schedule: schedule `name` with `run --steps-scale` and `--checkpoints` applied.

    steps_scale replaces the schedule's scale (every method is then scaled by it); checkpoints are
    paper iterations (e.g. (3000, 7000)), each trained as round(iteration x steps_scale); dense_every
    (`--checkpoints every:500`) adds a checkpoint every that many paper iterations; miniature names how the
    shrunk schedule stands in for the paper's (MINIATURES).
    """
    p = get_schedule(name)
    if steps_scale is not None:
        if not (isinstance(steps_scale, (int, float)) and math.isfinite(steps_scale) and steps_scale > 0):
            raise StringsBenchError(f"steps scale must be a number > 0, got {steps_scale!r}",
                                    hint="e.g. --steps-scale 0.2 (7K = 1400 steps); 1 is the paper's schedule")
        p = replace(p, steps_scale=float(steps_scale), description=f"{p.description} [--steps-scale {steps_scale:g}]")
    if checkpoints is not None:
        given = list(checkpoints)
        if not given or not all(isinstance(c, numbers.Integral) and not isinstance(c, bool) and c >= 1 for c in given):
            raise StringsBenchError(f"checkpoints must be paper iterations (integers >= 1), got {given!r}",
                                    hint="e.g. --checkpoints 3000,7000")
        its = tuple(sorted({int(c) for c in given}))
        p = replace(p, paper_checkpoints=its, description=f"{p.description} [--checkpoints {','.join(map(str, its))}]")
    if dense_every is not None:
        if not (isinstance(dense_every, numbers.Integral) and not isinstance(dense_every, bool) and dense_every >= 1):
            raise StringsBenchError(f"every:N needs N paper iterations (an integer >= 1), got {dense_every!r}",
                                    hint="e.g. --checkpoints every:500")
        p = replace(p, dense_every=int(dense_every), description=f"{p.description} [every:{int(dense_every)}]")
    if miniature is not None:
        if miniature not in MINIATURES:
            raise StringsBenchError(f"unknown miniature {miniature!r}",
                                    hint="miniatures: " + "; ".join(f"{m.name}: {m.description}" for m in MINIATURES.values()))
        if miniature != p.miniature:
            p = replace(p, miniature=miniature, description=f"{p.description} [--miniature {miniature}]")
    return p
