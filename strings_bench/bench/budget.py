"""The equal Gaussian budget of a run (`run --budget N|METHOD`, `--budget-from FOLDER`), in one value: `Budget`.

One word, budget: the run's rule is a `Budget` (a count or a reference method); the count it sets for one job is
that job's Gaussian budget (the method setting `gaussian_budget`, `StrategyContext.budget`, the cell's
`config.budget.count`). `--budget N` holds every method of the run to N Gaussians. `--budget METHOD` makes METHOD
the reference: it trains first, without a budget, and every other method is held to the Gaussian count METHOD's cell
reaches on the same scene at the job's last checkpoint, read where the job runs from this run folder, or from
`--budget-from`'s (a run folder whose METHOD cells were trained without a budget at the same schedule and image
scale). A job's budget reaches its method as the `gaussian_budget` setting (engine/train_config.py, `TrainConfig`;
its strategy gets it in its `StrategyContext`), never through `--set`; the plan puts a `--budget N` count into each
job's settings (`Budget.for_job`).

The life of a budget: `Budget.parse` (the command line), `check` (against the run's methods and folders, before any
scene is built), `manifest` (what run.json records), and `record`, where a job runs: what its cells record
(results.csv's `budget` column), from which `budget_of` reads the count its method is built with.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.results import CellKey, is_finished

SETTING = "gaussian_budget"  # the method setting (engine/train_config.py, TrainConfig) a job's budget reaches its method as
OLD_SETTING = "max_gaussians"  # its name in cells and training states written before the rename; read, never written
EXAMPLES = "e.g. --budget 40000, --budget 40k, or --budget 3dgs"


@dataclass(frozen=True, kw_only=True)
class Budget:
    """A run's equal Gaussian budget: a `count` (`--budget N`) or a `reference` method (`--budget METHOD`), whose
    cells may come from another run `folder` (`--budget-from`)."""

    count: int | None = None
    reference: str | None = None
    folder: str | None = None

    # ---- from the command line ----------------------------------------------------------------------------
    @classmethod
    def parse(cls, value, folder: str | Path | None = None) -> "Budget | None":
        """`--budget`'s value: None/"" (no budget), a positive count (int, or a string of digits, "40k" = 40 000) or
        a method name; `folder`: `--budget-from`, which goes with a method name only. Anything else is a clear error."""
        if value is None or value == "":
            if folder is not None:
                raise StringsBenchError("--budget-from goes with --budget METHOD (the method whose cells it holds)",
                                        hint="e.g. --budget 3dgs --budget-from runs/seed0")
            return None
        if isinstance(value, bool):
            raise StringsBenchError(f"--budget {value!r} is neither a number of Gaussians nor a method name")
        if isinstance(value, (int, float)):
            if int(value) != value or value < 1:
                raise StringsBenchError(f"--budget {value!r} is not a positive whole number of Gaussians", hint=EXAMPLES)
            if folder is not None:
                return cls.parse(None, folder)  # the error of a --budget-from without a method
            return cls(count=int(value))
        text = str(value).strip()
        digits, mult = (text[:-1], 1000) if text[-1:] in ("k", "K") else (text, 1)
        if digits.isdigit():
            return cls.parse(int(digits) * mult, folder)
        try:
            float(digits)
            numeric = True
        except ValueError:
            numeric = False
        if numeric or not text or text.startswith("-"):
            raise StringsBenchError(f"--budget {value!r} is neither a number of Gaussians nor a method name",
                                    hint=EXAMPLES)
        return cls(reference=text, folder=None if folder is None else str(folder))

    @property
    def rule(self) -> int | str:
        """As given: the count, or the reference method's name (run.json's `budget`)."""
        return self.count if self.count is not None else str(self.reference)

    # ---- checked before any scene is built ----------------------------------------------------------------
    def check(self, methods: list[str], specs: dict, run_dir: Path, schedule: dict, downscale: float) -> "Budget":
        """Refuse what cannot run: a reference that is neither trained here nor in the run folder, a `--budget-from`
        folder that is no such reference, a method that trains no Gaussians. `specs`: the methods' MethodSpecs;
        `schedule`: this run's (as run.json records it). Returns the budget with `--budget-from`'s folder resolved."""
        checked = self
        if self.folder is not None:
            if self.reference in methods:
                raise StringsBenchError(
                    f"--budget {self.reference} --budget-from: {self.reference}'s cells come from that folder, so "
                    f"{self.reference} is not trained in this run",
                    hint=f"leave {self.reference} out of --methods, or drop --budget-from")
            checked = replace(self, folder=str(self._check_folder(Path(self.folder), schedule, downscale)))
        elif (self.reference is not None and self.reference not in methods
              and not (Path(run_dir) / "cells" / self.reference).is_dir()):
            from strings_bench.store import read_manifest

            made_from = (read_manifest(run_dir) or {}).get("budget_from") if Path(run_dir).is_dir() else None
            raise StringsBenchError(
                f"--budget {self.reference} needs {self.reference} among the run's methods: it trains first, without a budget, "
                f"and its Gaussian count on each scene is the others' budget",
                hint=(f"{run_dir} was made with --budget-from {made_from}: give it again to resume" if made_from
                      else f"add it: --methods {self.reference},{','.join(methods)}"))
        for m in methods:
            schema = specs[m].settings()
            if m != self.reference and schema is not None and SETTING not in {s.name for s in schema}:
                raise StringsBenchError(f"method {m} takes no Gaussian budget (it trains no Gaussians of its own)",
                                        hint="leave it out of a --budget run")
        return checked

    def _check_folder(self, folder: Path, schedule: dict, downscale: float) -> Path:
        """`--budget-from FOLDER`: a run folder whose reference cells were trained without a budget, at this run's schedule
        and image scale (so that a count at an iteration means the same model size). Returns it resolved."""
        from strings_bench.store import read_manifest

        folder = folder.expanduser().resolve()
        old = read_manifest(folder) if folder.is_dir() else None
        ref = self.reference
        if old is None:
            raise StringsBenchError(f"--budget-from {folder}: not a run folder (no run.json)",
                                    hint="give the --out folder of a finished run that trained the reference method")
        if not (folder / "cells" / str(ref)).is_dir():
            raise StringsBenchError(f"--budget-from {folder} holds no {ref} cells",
                                    hint=f"the folder must hold {ref}'s cells (--budget {ref})")
        if old.get("budget") not in (None, ref):
            raise StringsBenchError(f"--budget-from {folder}: its {ref} cells were trained under a budget (--budget "
                                    f"{old.get('budget')}), so their counts are no reference",
                                    hint="give a folder where the reference method trained without a budget")
        was = old.get("schedule") or {}
        for key, option in (("steps_scale", "--steps-scale"), ("name", "--schedule")):
            if was.get(key) != schedule.get(key):
                raise StringsBenchError(f"--budget-from {folder} was run with {option} {was.get(key)}; this run asks "
                                        f"for {schedule.get(key)}", hint="the reference must come from the same schedule")
        if old.get("downscale") is not None and float(old["downscale"]) != float(downscale):
            raise StringsBenchError(f"--budget-from {folder} was run at downscale {old['downscale']}; this run asks for "
                                    f"{downscale}", hint="the reference must come from the same image scale")
        return folder

    # ---- recorded ---------------------------------------------------------------------------------------------
    def manifest(self) -> dict:
        """run.json's entries: `budget` (the count or the reference's name) and, with `--budget-from`, `budget_from`."""
        return {"budget": self.rule, **({"budget_from": self.folder} if self.folder is not None else {})}

    def is_reference(self, method: str) -> bool:
        return method == self.reference

    def for_job(self, method: str, settings: dict) -> tuple[dict, int | None]:
        """(a job's final settings, its Gaussian budget) for `method`, as planned: under `--budget N` the count N,
        also in the settings (as SETTING); the reference's and `--budget METHOD`'s other jobs get (settings, None),
        the latter's count being read where the job runs (`record`)."""
        count = None if self.is_reference(method) else self.count
        return (settings if count is None else {**settings, SETTING: count}), count

    # ---- resolved where a job runs ------------------------------------------------------------------------------
    def reference_cell(self, dataset: str, scene: str, checkpoints) -> CellKey:
        """The cell whose Gaussian count is the budget of a job on (dataset, scene) with these checkpoints under
        `--budget METHOD`: the reference's cell at the job's last checkpoint."""
        return CellKey(str(self.reference), dataset, scene, max(checkpoints))

    def record(self, method: str, dataset: str, scene: str, checkpoints, run_dir: str | Path) -> dict | str:
        """What a cell of `method` records as its budget: {"rule", "count", "reference"}, or "reference" for
        the reference method's own cells (trained without a budget). Under `--budget METHOD` the reference's cell (in `run_dir` or
        `--budget-from`'s folder) must be finished, with a Gaussian count."""
        if self.is_reference(method):
            return "reference"
        if self.count is not None:
            return {"rule": str(self.count), "count": self.count, "reference": None}
        from strings_bench.store import read_cell

        folder = Path(self.folder or run_dir)
        ref = self.reference_cell(dataset, scene, checkpoints)
        if not is_finished(folder, ref):
            where = f"--budget-from {folder}" if self.folder else "the run folder"
            raise StringsBenchError(
                f"--budget {self.reference}: {method} on {dataset}/{scene} needs {self.reference}'s cell at iteration "
                f"{ref.iteration} ({ref.path(folder)}), which is not in {where}",
                hint=(f"train {self.reference} on this scene into {folder} first" if self.folder else
                      f"add {self.reference} to --methods (its jobs run first, without a budget), or give a number: --budget N"))
        count = (read_cell(folder, ref) or {}).get("gaussians")
        if not count:
            raise StringsBenchError(f"--budget {self.reference}: the reference cell {ref.path(folder)} records no "
                                    "Gaussian count", hint="the reference must be a method that trains Gaussians")
        return {"rule": self.reference, "count": int(count),
                "reference": {"method": ref.method, "iteration": ref.iteration,
                              **({"folder": str(folder)} if self.folder else {})}}


def refuse_set(overrides: dict[str, dict]) -> None:
    """A Gaussian budget is given with --budget, never with --set, under its name or its old one (`overrides`:
    method, or the all-methods key, -> its --set values)."""
    for name in (SETTING, OLD_SETTING):
        if any(name in s for s in overrides.values()):
            raise StringsBenchError(f"{name} is set with --budget, not --set"
                                    + (f" (and is called {SETTING} now)" if name == OLD_SETTING else ""),
                                    hint="--budget N holds every method of the run to N Gaussians (docs/guide/running.md)")


def budget_of(record: dict | str | None) -> int | None:
    """The Gaussian budget, a count, that a cell's budget record sets (its "count"; "max_gaussians" in cells written
    before the rename); None for the reference and without one."""
    if not isinstance(record, dict):
        return None
    return int(record["count"] if "count" in record else record[OLD_SETTING])
