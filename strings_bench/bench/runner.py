"""Run methods x scenes x checkpoints, evaluate every checkpoint, and keep the results resumable.

One *cell* is (method, dataset, scene, checkpoint iteration). A cell is finished when its
`result.json` exists; that file is written last and atomically, so a killed run loses at most the
cell in progress. Re-running the same command skips finished cells. A trained method's training
state is saved at every checkpoint and every `--save-every` (engine.trainer), so a (method, scene)
killed mid-training continues from its last saved state (`resumed_from_step` in result.json);
checkpoints already evaluated are passed over (never rewritten).

Run folder (see docs/guide/running.md):

    RUN_DIR/
      run.json                          the run's settings (schedule, steps scale, checkpoints, downscale, OCR,
                                        --set values); a re-run must match
      results.csv                       one row per cell, rebuilt after every cell
      cells/<method>/<dataset>/<scene>/<iteration>/
          result.json                   everything about the cell (config, timings, metrics, OCR words, CER)
          renders/<view stem>.png       the method's test-view renders
          model.ply                     the model at this checkpoint (--keep-models)
      state/<method>/<dataset>/<scene>/training_state.pt
                                        the resumable training state; removed when the (method, scene) is done
      gt/<dataset>/<scene>/<view stem>.png   ground-truth test views at the evaluated size
      report/                           tables, figures, index.html (strings_bench.reports.write_report)

The run's configuration is one `RunConfig` (bench/plan.py), planned into jobs by `plan_run`, which resolves
every value (device, OCR engines, save schedule, final method settings, Gaussian budget, LPIPS checkpoints) once: the runner
takes a job as it is and reads run.json only to compare it with the plan (a resume). The schedules are
core/schedules.py; `strings_bench.bench.run` plans and executes. The run folder is written and read
through the store (strings_bench/store/). Execution goes through an `Executor` (bench/executors.py:
`submit(job)` / `map(jobs)`); `LocalExecutor` runs jobs one after another in this process,
`RayExecutor` (bench/ray_executor.py, `--executor ray`) runs each job as a Ray task, `SlurmExecutor`
(bench/slurm_executor.py, `--executor slurm`) as a task of a Slurm job array. A distributed executor only has to run `run_job(job)` somewhere that sees RUN_DIR (jobs
are plain data) — cells are independent files, and results.csv is rebuilt from them on the driver.
"""

from __future__ import annotations

import json
import logging
import time
from concurrent.futures import FIRST_COMPLETED, wait
from pathlib import Path
from typing import Callable, Iterable, Iterator

from strings_bench.bench.budget import SETTING as BUDGET_SETTING
from strings_bench.bench.budget import budget_of
from strings_bench.bench.executors import Executor, Job, executor_factory
from strings_bench.bench.plan import RunPlan
from strings_bench.bench.records import device_info, versions, write_gt_pngs, write_run_report
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import jsonable
from strings_bench.core.method import Method
from strings_bench.core.results import CellKey, is_finished, safe_name
from strings_bench.eval.metrics import describe as metrics_describe
from strings_bench.eval.protocol import Evaluator
from strings_bench.store import (CellConfig, CellRecord, check_manifest, iteration_label, run_folder_lock, write_cell,
                                 write_manifest, write_results_csv)

log = logging.getLogger(__name__)


# ---- running ------------------------------------------------------------------------------------
def build_method(job: Job, budget_count: int | None = None):
    """The job's method, built once from its final settings (bench/plan.py); `budget_count`: a Gaussian budget known
    only where the job runs (`--budget METHOD`: the reference's count), added to them."""
    from strings_bench.methods.registry import get_method

    settings = job.settings if budget_count is None else {**job.settings, BUDGET_SETTING: int(budget_count)}
    return get_method(job.method).instantiate(settings)


def _load_scene(job: Job):
    from strings_bench.scene.scene import Scene

    return Scene.load(job.scene_path, name=job.scene, settings=job.scene_settings)


class Runner:
    """Runs jobs and writes cells.

    `ocr`: None (each job's own engines, `Job.ocr`) or a backend object used in their place (tests).
    `results_csv`: rebuild results.csv after every cell (in-process runs); a worker of a distributed
    executor leaves it to the driver.
    """

    def __init__(self, run_dir: str | Path, ocr=None, progress: bool = True,
                 on_cell: Callable[[CellKey], None] | None = None, results_csv: bool = True):
        self.run_dir = Path(run_dir)
        self.results_csv = results_csv
        self.ocr = ocr
        self.progress = progress
        self.on_cell = on_cell
        self._evaluators: dict[tuple, Evaluator] = {}  # per scene; see run_job
        self._rhos: dict[str, float | None] = {}  # per scene folder: rho, one position step in text strokes

    def __call__(self, job: Job) -> list[CellKey]:
        return self.run_job(job)

    def run_job(self, job: Job) -> list[CellKey]:
        run_dir = Path(job.run_dir)
        todo = [k for k in job.cells() if not is_finished(run_dir, k)]
        if not todo:
            job.state_path().unlink(missing_ok=True)  # left by a run killed after its last cell was written
            return []
        # the budget its cells record (a --budget METHOD reference's count is read here, where the job runs)
        budget = None if job.budget is None else job.budget.record(job.method, job.dataset, job.scene,
                                                                    job.checkpoints, job.run_dir)
        scene = _load_scene(job)
        method = build_method(job, None if job.budget_count is not None else budget_of(budget))
        method.progress = self.progress is not False  # --no-progress reaches the training and mask bars
        from strings_bench.eval.ocr import get_engine

        # the job's engines (the scene's own GT engine first where it names one: bench/plan.py), unless this runner
        # was given a backend object (tests)
        ocr = ([self.ocr] if self.ocr is not None
               else [get_engine(e) if isinstance(e, str) else e for e in job.ocr])
        with_lpips = bool(job.lpips_checkpoints)
        # One Evaluator per scene in this process: the GT side (GT OCR, GT word crops, LPIPS features) is read once
        # and reused by every method's job on the scene.
        ekey = (job.scene_path, json.dumps(job.scene_settings, sort_keys=True, default=str), job.downscale,
                job.cer_profile, job.device, with_lpips, job.ocr)
        evaluator = self._evaluators.get(ekey)
        if evaluator is None:
            evaluator = Evaluator.for_scene(scene, ocr, job.downscale, with_lpips=with_lpips,
                                            cer_profile=job.cer_profile, device=job.device)
            self._evaluators[ekey] = evaluator
            while len(self._evaluators) > EVALUATORS_KEPT:
                del self._evaluators[next(iter(self._evaluators))]  # the scene seen longest ago
        write_gt_pngs(run_dir, job.dataset, job.scene, evaluator)
        wanted = set(job.checkpoints)
        written: list[CellKey] = []
        seen: set[int] = set()
        describe = jsonable(method.describe())
        for result in self._checkpoints(job, method, scene, describe):
            if result.iteration not in wanted:
                log.debug("%s yielded unrequested checkpoint %d; ignored", job.method, result.iteration)
                continue
            seen.add(result.iteration)
            key = CellKey(job.method, job.dataset, job.scene, result.iteration)
            if is_finished(run_dir, key):
                continue  # evaluated in an earlier run; training had to pass through it again
            self._write_cell(job, key, result, evaluator, describe, scene, budget)
            written.append(key)
            if self.on_cell:
                self.on_cell(key)
            if all(is_finished(run_dir, k) for k in job.cells()):
                break
        missing = sorted(k.iteration for k in job.cells() if not is_finished(run_dir, k))
        if missing:
            raise StringsBenchError(f"method {job.method} stopped without checkpoint(s) {missing} on {job.dataset}/{job.scene}",
                                    hint="the method adapter's train() must yield one CheckpointResult per requested iteration")
        if all(is_finished(run_dir, k) for k in job.cells()):
            job.state_path().unlink(missing_ok=True)  # every cell is written: the state is no longer needed
        return written

    def _checkpoints(self, job: Job, method, scene, describe: dict) -> Iterator:
        """The method's checkpoints: trained by the framework's loop for a `Method` (resumable), or
        yielded by a `MethodAdapter` for models trained elsewhere."""
        if not isinstance(method, Method):
            return method.train(scene, list(job.checkpoints), job.downscale)
        from strings_bench.bench.warmup import ensure, wait_for
        from strings_bench.engine.trainer import Trainer

        if str(job.device).startswith("cpu"):  # its kernels from the warm-up's cache, not compiled here
            ensure(job.method)  # on a worker: no plan started the warm-up there
            wait_for(job.method)

        def model_path(step: int) -> Path:
            return CellKey(job.method, job.dataset, job.scene, step).path(Path(job.run_dir)) / "model.ply"

        fingerprint = {"settings": json.loads(json.dumps(describe.get("settings", {}), sort_keys=True, default=str)),
                       "scene_path": job.scene_path, "dataset": job.dataset}
        return Trainer(method, scene, job.checkpoints, downscale=job.downscale, device=job.device,
                       progress=self.progress is not False, state_path=job.state_path(),
                       save_every=job.save_every, model_path=model_path if job.keep_models else None,
                       fingerprint=fingerprint).train()

    def _rho(self, job: Job, scene) -> float | None:
        if job.scene_path not in self._rhos:
            from strings_bench.scene.difficulty import measured_rho

            self._rhos[job.scene_path] = measured_rho(scene)
        return self._rhos[job.scene_path]

    def _write_cell(self, job: Job, key: CellKey, result, evaluator: Evaluator, describe: dict, scene,
                    budget: dict | str | None = None) -> None:
        t0 = time.perf_counter()
        lpips_here = key.iteration in job.lpips_checkpoints  # the plan's (--lpips-at; the paper reports it at 30K)
        dense = key.iteration in set(job.dense_checkpoints)  # only `every:N` asked for it: word-crop metrics only
        ev = (evaluator.evaluate_words(job.method, result.renders) if dense
              else evaluator.evaluate(job.method, result.renders, with_lpips=lpips_here))
        preprocess = _preprocess_seconds(result)
        record = CellRecord(
            method=job.method, dataset=job.dataset, scene=job.scene, iteration=key.iteration,
            label=job.labels.get(key.iteration, job.labels.get(str(key.iteration), iteration_label(key.iteration))),
            config=CellConfig(
                method=describe, scene={"path": job.scene_path, "settings": job.scene_settings,
                                        "test_views": evaluator.names, "rho": self._rho(job, scene)},
                schedule=job.schedule, method_presets=tuple(job.method_presets), downscale=job.downscale,
                cer_profile=job.cer_profile, checkpoints=tuple(job.checkpoints), budget=budget, versions=versions(),
                metrics=metrics_describe()),
            resumed_from_step=int(getattr(result, "resumed_from_step", 0)),
            device=result.extra.get("device", ""),
            gpu=device_info(result.extra["device"])["gpu"] if result.extra.get("device") else None,
            timings={"train_seconds": result.train_seconds, "preprocess_seconds": preprocess,
                     "total_seconds": result.train_seconds + preprocess,
                     "train_cpu_seconds": getattr(result, "train_cpu_seconds", None),
                     "eval_seconds": time.perf_counter() - t0},
            gaussians=int(result.gaussians), peak_memory_mb=result.peak_memory_mb, extra=result.extra,
            evaluation="words" if dense else "full", scores=ev)
        # the job's folder: absolute when it runs on a Ray worker
        write_cell(key.path(Path(job.run_dir)), record, {n: img for n, img in result.renders.items() if n in evaluator.names})
        if self.results_csv:
            write_results_csv(job.run_dir)


def _preprocess_seconds(result) -> float:
    value = getattr(result, "preprocess_seconds", 0.0)  # adapters written before the field: none
    return 0.0 if value is None else float(value)


EVALUATORS_KEPT = 8  # scenes whose Evaluator a runner keeps (jobs run method by method over the scenes)
POLL_SECONDS = 2.0  # how often the driver looks at the run folder while jobs run elsewhere


def execute(plan: RunPlan, ocr=None, executor: str | Executor = "local", progress: bool = True,
            write_report: bool = True, executor_options: dict | None = None) -> Path:
    """Run every unfinished cell of `plan`, then write results.csv and (optionally) the report.

    `ocr`: None (the jobs' engines) or a backend object used in their place (tests).
    `executor` is a name in EXECUTORS (built with `executor_options`) or an executor object; a name must be
    the one the plan was made for (`RunConfig.executor`: it resolved the device for it). A job
    that fails does not stop the others; once all have ended, one StringsBenchError lists every cell
    that was not written and why. Ctrl-C cancels the running jobs, removes their incomplete cells
    and re-raises KeyboardInterrupt. A second run in the same folder at once stops with an error naming the
    first (store/lock.py).
    """
    plan.run_dir.mkdir(parents=True, exist_ok=True)
    with run_folder_lock(plan.run_dir):
        return _execute(plan, ocr, executor, progress, write_report, executor_options)


def _execute(plan: RunPlan, ocr, executor, progress: bool, write_report: bool, executor_options: dict | None) -> Path:
    run_dir = plan.run_dir
    from strings_bench.core.io import cache_root, sweep_stale_temps

    if isinstance(executor, str):
        factory = executor_factory(executor)
        in_process = factory.in_process
    else:
        factory, in_process = None, executor.in_process
    # Temporary files of runs killed mid-write (kill -9, the OOM killer): finished files are never half-written,
    # but their temporaries would stay for ever. Compiled kernels are numba's own.
    sweep_stale_temps(run_dir)
    sweep_stale_temps(cache_root(), skip=("numba",))

    # The device of the latest execution (a resumed run may continue elsewhere); a distributed executor's
    # workers resolve their own and record it in each result.json.
    resolved = (device_info(plan.device) if in_process and plan.in_process
                else {"device": "on each worker (see result.json)", "gpu": None})
    write_manifest(run_dir, {**check_manifest(run_dir, plan.manifest), "versions": versions(), "resolved_device": resolved})
    cells = plan.cells
    done = sum(is_finished(run_dir, k) for k in cells)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(cells), initial=done, desc="cells", unit="cell")

    def on_cell(key: CellKey) -> None:
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(f"{key.method} {key.dataset}/{key.scene} @{key.iteration}")

    # Jobs run elsewhere get a runner without callbacks into this process; the driver follows them on disk.
    runner = Runner(run_dir, ocr=ocr, on_cell=on_cell if in_process else None,
                    progress=progress if in_process else False, results_csv=in_process)
    ex = factory(runner, **(executor_options or {})) if factory is not None else executor
    pending = []
    for job in plan.jobs:
        if all(is_finished(run_dir, k) for k in job.cells()):
            # A run killed between writing the last cell and removing the training state left the state.
            job.state_path().unlink(missing_ok=True)
        else:
            pending.append(job)
    errors: list[tuple[Job, BaseException]] = []
    try:
        if pending:
            ex.start(run_dir, pending)
        # --budget METHOD: the reference method's jobs first (the others read their counts), then the rest.
        first = [j for j in pending if j.budget is not None and j.budget.is_reference(j.method)]
        stages = [first, [j for j in pending if j not in first]]
        for stage in stages:
            if stage:
                _run_stage(ex, stage, errors, in_process, run_dir, cells, bar)
                if ex.detach:  # submitted, not waited for: a later stage (a --budget's budgeted methods) reads this
                    break      # one's cells, so a later run submits it
    except KeyboardInterrupt:
        ex.cancel()
        discard_incomplete_cells(run_dir, [j for j in pending if not all(is_finished(run_dir, k) for k in j.cells())])
        raise
    finally:
        ex.close()
        if bar is not None:
            bar.close()
        write_results_csv(run_dir)
    if ex.detach and pending:
        left = sum(not is_finished(run_dir, k) for k in cells)
        log.warning("submitted; %d of %d cell(s) still to come. Run the same command again to follow the jobs (it "
                    "submits what is missing) and write the report", left, len(cells))
        return run_dir
    if write_report:
        write_run_report(run_dir)
    if errors:
        raise failure_summary(run_dir, errors, total_jobs=len(pending))
    return run_dir


def _run_stage(ex: Executor, jobs: list[Job], errors: list, in_process: bool, run_dir: Path, cells: list, bar) -> None:
    """Submit `jobs` and wait for all of them; failures are appended to `errors` (the others go on)."""
    done = sum(is_finished(run_dir, k) for k in cells)
    futures = dict(zip(ex.submit_many(jobs), jobs))
    if ex.detach:
        return
    waiting = set(futures)
    note = None
    while waiting:
        finished, waiting = wait(waiting, timeout=POLL_SECONDS, return_when=FIRST_COMPLETED)
        if not in_process:
            now = sum(is_finished(run_dir, k) for k in cells)
            if now != done:  # results.csv follows the cells as they arrive
                done = now
                write_results_csv(run_dir)
                if bar is not None:
                    bar.n = now
                    bar.refresh()
            if bar is not None and ex.progress_note() != note:  # e.g. how many jobs Slurm runs and queues
                note = ex.progress_note()
                bar.set_postfix_str(note or "")
        for fut in finished:
            exc = fut.exception()
            if exc is not None:
                job = futures[fut]
                errors.append((job, exc))
                log.error("%s on %s/%s failed: %s", job.method, job.dataset, job.scene, exc)


def failure_summary(run_dir: Path, errors: list[tuple[Job, BaseException]], total_jobs: int) -> StringsBenchError:
    """One error naming every cell of the failed jobs that was not written, with its job's reason."""
    lines = []
    n_cells = 0
    for job, exc in errors:
        reason = (exc.message if isinstance(exc, StringsBenchError) else f"{type(exc).__name__}: {exc}").strip()
        first, *more = reason.splitlines() or [type(exc).__name__]
        unwritten = []
        for key in job.cells():
            if not is_finished(run_dir, key):
                label = job.labels.get(key.iteration, job.labels.get(str(key.iteration), iteration_label(key.iteration)))
                unwritten.append(f"@{key.iteration} ({label})")
        n_cells += len(unwritten)
        lines.append(f"  {job.method} {job.dataset}/{job.scene} {', '.join(unwritten) or '(all cells written)'}: {first}")
        lines.extend(f"      {line}" for line in more)
    hint = "finished cells are kept; fix the cause and re-run the same command"
    only = errors[0][1]
    if len(errors) == 1 and isinstance(only, StringsBenchError) and only.hint:
        hint = f"{only.hint}; {hint}"
    err = StringsBenchError(f"{len(errors)} of {total_jobs} job(s) failed; {n_cells} cell(s) not written:\n"
                            + "\n".join(lines), hint=hint)
    err.__cause__ = only
    return err


def discard_incomplete_cells(run_dir: Path, jobs: Iterable[Job]) -> list[Path]:
    """Remove what interrupted jobs left half-written: cell folders without result.json and the
    temporary files of unfinished atomic writes in their state and ground-truth folders (the
    training state itself is kept, to resume from). Returns the removed paths."""
    import shutil

    removed: list[Path] = []
    for job in jobs:
        for key in job.cells():
            cell = key.path(run_dir)
            if cell.is_dir() and not is_finished(run_dir, key):
                shutil.rmtree(cell, ignore_errors=True)
                removed.append(cell)
        gt_dir = run_dir / "gt" / safe_name(job.dataset) / safe_name(job.scene)
        for folder in (job.state_path().parent, gt_dir):
            if folder.is_dir():
                for tmp in folder.glob(".*.tmp"):  # core.io.atomic_write's temporary names
                    tmp.unlink(missing_ok=True)
                    removed.append(tmp)
    return removed
