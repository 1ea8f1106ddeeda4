"""Jobs and where they run.

A `Job` trains one method on one scene and evaluates its checkpoints; it is plain data, so it can
travel to another process or machine. An `Executor` runs jobs (`submit(job)` -> Future): the
`LocalExecutor` here, one after another in this process, the `RayExecutor` (ray_executor.py) or the
`SlurmExecutor` (slurm_executor.py).
"""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Protocol

from strings_bench.bench.budget import Budget
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.results import CellKey, safe_name

if TYPE_CHECKING:
    from strings_bench.engine.trainer import SaveEvery

@dataclass(frozen=True, kw_only=True)
class Job:
    """Train one method on one scene and evaluate its checkpoints: every value resolved by the plan
    (bench/plan.py), keyword by keyword; the runner and the trainer take them as they are. Plain data: it can
    travel."""

    run_dir: str
    method: str
    dataset: str
    scene: str
    scene_path: str
    scene_settings: dict
    checkpoints: tuple[int, ...]
    labels: dict  # iteration -> paper label
    schedule: str  # the run's schedule (core/schedules.py); recorded as the cell's "schedule"
    downscale: float
    # the OCR engines in canonical specs ("rapidocr", "tesseract:lang=rus"), the primary first
    ocr: tuple[str, ...]
    # the steps scale the method trains at (the schedule's, or the method's --set steps_scale): its checkpoints are
    # scaled by it, and it reaches the method as its `steps_scale` setting where the method takes one
    steps_scale: float
    method_settings: dict = field(default_factory=dict)  # the method's --set values, the all-methods ones included
    # the method's final settings, built with as they are: its spec's defaults, presets, steps scale, --set values
    # and a --budget N count
    settings: dict = field(default_factory=dict)
    method_presets: tuple[str, ...] = ()  # the method's presets in order (recorded): dataset-conditional, then --presets
    cer_profile: str = "paper"  # strings_bench.eval.cer.PROFILES; the authors' rules by default
    # the device, resolved by the plan for jobs run in-process ("cpu", "cuda", "cuda:N"); for jobs sent to a
    # distributed executor the checked name its worker resolves ("auto", "cpu", "cuda")
    device: str = "cpu"
    save_every: "SaveEvery | None" = None  # when the training state is saved besides checkpoints (None: every 10 min)
    keep_models: bool = False  # write each cell's model.ply
    # of `checkpoints`, those that only `--checkpoints every:N` adds: evaluated with the word-crop metrics only
    # (Evaluator.evaluate_words); () when there are none or the run asked for --dense-eval full
    dense_checkpoints: tuple[int, ...] = ()
    lpips_checkpoints: tuple[int, ...] = ()  # of `checkpoints`, those scored with LPIPS too (--lpips-at)
    budget: Budget | None = None  # the run's equal Gaussian budget rule (bench/budget.py), recorded with each cell
    # the job's budget in Gaussians where the plan knows it (--budget N; also in settings); None without a budget,
    # for the reference method, and under --budget METHOD, whose count is read where the job runs
    budget_count: int | None = None

    def state_path(self) -> Path:
        """The resumable training state of this (method, scene)."""
        return (Path(self.run_dir) / "state" / safe_name(self.method) / safe_name(self.dataset) / safe_name(self.scene)
                / "training_state.pt")

    def cells(self) -> list[CellKey]:
        return [CellKey(self.method, self.dataset, self.scene, it) for it in self.checkpoints]


class Executor:
    """Where jobs run. `submit` returns a Future of `run_job(job)`'s return value; every other member has
    a default here, so an executor overrides only what it does differently:

    - `in_process` (True): jobs run in this process. False: in other processes, so the driver follows
      progress from the run folder and rebuilds results.csv itself;
    - `check_options(device, **options)`, on the class: refuse what it cannot do before any scene is built
      (default: it takes no options);
    - `start(run_dir, jobs)` before the first submit (connect, check that workers see the run folder),
      `submit_many(jobs)` (a stage's jobs at once: the Slurm executor sends them as a job array),
      `cancel()` on Ctrl-C (stop every job still running), `close()` after the run;
    - `detach` (False): True when the run only submits its jobs and returns (`--detach`); a later run follows them.
    """

    in_process = True
    detach = False

    @classmethod
    def check_options(cls, device: str = "auto", **options) -> None:
        if options:
            raise StringsBenchError(f"executor {cls.__name__} takes no options (given: {', '.join(sorted(options))})",
                                    hint="--ray-address and --max-retries apply to --executor ray, the --slurm-* options and "
                                         "--detach to --executor slurm, --cpus-per-job to both")

    def submit(self, job: Job) -> Future:
        raise NotImplementedError

    def submit_many(self, jobs: list[Job]) -> list[Future]:
        """Submit several jobs at once (a batch scheduler sends them as one job array); one Future each."""
        return [self.submit(j) for j in jobs]

    def map(self, jobs: Iterable[Job]) -> list[Any]:
        return [self.submit(j).result() for j in jobs]

    def progress_note(self) -> str | None:
        """A few words for the progress bar while jobs run elsewhere (e.g. how many are queued), or None."""
        return None

    def start(self, run_dir: Path, jobs: list[Job]) -> None:
        pass

    def cancel(self) -> None:
        pass

    def close(self) -> None:
        pass


class LocalExecutor(Executor):
    """Runs each job in this process, one after another (the default)."""

    in_process = True

    def __init__(self, runner: Callable[[Job], Any]):
        self.runner = runner

    def submit(self, job: Job) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(self.runner(job))
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            fut.set_exception(exc)
        return fut



# name -> the executor class, or "module:Class" imported when chosen (Ray and submitit are imported only then).
EXECUTORS: dict[str, type[Executor] | str] = {"local": LocalExecutor, "ray": "strings_bench.bench.ray_executor:RayExecutor",
                                              "slurm": "strings_bench.bench.slurm_executor:SlurmExecutor"}


def executor_factory(name: str) -> type[Executor]:
    """The executor class registered under `name` in EXECUTORS; a clear error for an unknown name."""
    if name not in EXECUTORS:
        raise StringsBenchError(f"unknown executor {name!r}", hint=f"executors: {', '.join(EXECUTORS)}")
    cls = EXECUTORS[name]
    if isinstance(cls, str):
        import importlib

        module, _, attr = cls.partition(":")
        cls = getattr(importlib.import_module(module), attr)
    return cls


def get_executor(name: str, runner: Callable[[Job], Any], **options) -> Executor:
    """The executor `name` running jobs with `runner`; `options` go to its factory (e.g. the Ray
    executor's `address`, `max_retries`)."""
    return executor_factory(name)(runner, **options)
