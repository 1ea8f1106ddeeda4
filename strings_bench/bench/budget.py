"""The equal Gaussian budget of a run (`run --budget N|METHOD`, `--budget-from FOLDER`), in one value: `Budget`.

Two words: the *budget* is the rule (a count or a reference method); the *cap* is the number of Gaussians it sets
for one job (the method setting `max_gaussians`, `StrategyContext.cap`). `--budget N` caps every method of the run
at N Gaussians. `--budget METHOD` makes METHOD the reference: it trains
first, uncapped, and every other method is capped at the Gaussian count METHOD's cell reaches on the same scene at
the job's last checkpoint, read where the job runs from this run folder, or from `--budget-from`'s (a run folder
whose METHOD cells were trained uncapped at the same schedule and image scale). A cap reaches a method as its
`max_gaussians` setting (engine/splatting.py, `TrainConfig`; its strategy gets it in its `StrategyContext`), never
through `--set`; the plan puts a `--budget N` cap into each job's settings (bench/plan.py).

The life of a budget: `Budget.parse` (the command line), `check` (against the run's methods and folders, before any
scene is built), `manifest` (what run.json records), and `record`, where a job runs: what its cells record
(results.csv's `budget` column), from which `cap_of` reads the cap its method is built with.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.results import CellKey, is_finished

SETTING = "max_gaussians"  # the strategy field a cap reaches every method as
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
                f"--budget {self.reference} needs {self.reference} among the run's methods: it trains first, uncapped, "
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
        """`--budget-from FOLDER`: a run folder whose reference cells were trained uncapped, at this run's schedule
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
            raise StringsBenchError(f"--budget-from {folder}: its {ref} cells were capped (--budget "
                                    f"{old.get('budget')}), so their counts are no reference",
                                    hint="give a folder where the reference method trained uncapped")
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

    # ---- resolved where a job runs ------------------------------------------------------------------------------
    def reference_cell(self, dataset: str, scene: str, checkpoints) -> CellKey:
        """The cell whose Gaussian count caps a job on (dataset, scene) with these checkpoints under
        `--budget METHOD`: the reference's cell at the job's last checkpoint."""
        return CellKey(str(self.reference), dataset, scene, max(checkpoints))

    def record(self, method: str, dataset: str, scene: str, checkpoints, run_dir: str | Path) -> dict | str:
        """What a cell of `method` records as its budget: {"rule", "max_gaussians", "reference"}, or "reference" for
        the reference method's own (uncapped) cells. Under `--budget METHOD` the reference's cell (in `run_dir` or
        `--budget-from`'s folder) must be finished, with a Gaussian count."""
        if self.is_reference(method):
            return "reference"
        if self.count is not None:
            return {"rule": str(self.count), "max_gaussians": self.count, "reference": None}
        from strings_bench.store import read_cell

        folder = Path(self.folder or run_dir)
        ref = self.reference_cell(dataset, scene, checkpoints)
        if not is_finished(folder, ref):
            where = f"--budget-from {folder}" if self.folder else "the run folder"
            raise StringsBenchError(
                f"--budget {self.reference}: {method} on {dataset}/{scene} needs {self.reference}'s cell at iteration "
                f"{ref.iteration} ({ref.path(folder)}), which is not in {where}",
                hint=(f"train {self.reference} on this scene into {folder} first" if self.folder else
                      f"add {self.reference} to --methods (its jobs run first, uncapped), or give a number: --budget N"))
        count = (read_cell(folder, ref) or {}).get("gaussians")
        if not count:
            raise StringsBenchError(f"--budget {self.reference}: the reference cell {ref.path(folder)} records no "
                                    "Gaussian count", hint="the reference must be a method that trains Gaussians")
        return {"rule": self.reference, "max_gaussians": int(count),
                "reference": {"method": ref.method, "iteration": ref.iteration,
                              **({"folder": str(folder)} if self.folder else {})}}


def refuse_set(overrides: dict[str, dict]) -> None:
    """A cap is given with --budget, never with --set, with or without a budget (`overrides`: method, or the
    all-methods key, -> its --set values)."""
    if any(SETTING in s for s in overrides.values()):
        raise StringsBenchError(f"{SETTING} is set with --budget, not --set",
                                hint="--budget N caps every method of the run at N Gaussians (docs/guide/running.md)")


def cap_of(record: dict | str | None) -> int | None:
    """The Gaussian cap a cell's budget record sets: its max_gaussians; None for the reference and without one."""
    return int(record["max_gaussians"]) if isinstance(record, dict) else None
