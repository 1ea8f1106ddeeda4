"""Running the benchmark: a run planned (plan.py, with its equal Gaussian budget in budget.py), its jobs executed
(runner.py, executors.py, ray_executor.py), predictions made elsewhere evaluated (evaluate.py), and the methods'
self-check (check.py).

    from strings_bench.bench import run
    run(["3dgs"], ["synthetic/books"], schedule="tiny")
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["run"]


def run(config=None, datasets=None, **given) -> Path:
    """Plan and execute a run: `strings-bench run` from Python.

    Args:
        config: a `RunConfig`, or the method names (`--methods`).
        datasets: registry ids or scene folders (`--datasets`; None: the schedule's scenes).
        **given: `RunConfig` fields (`schedule="tiny"`, `run_dir=...`), over `config`'s.
    Returns:
        the run folder (results.csv, cells/, report/). Finished cells of an earlier run in the same folder are kept
        and skipped: a run resumes.
    Raises:
        TypeError: an unknown keyword, naming the `RunConfig` fields.
        StringsBenchError: anything refused before training starts (an unknown method, setting, preset, scene,
            OCR engine or device; a folder made under other settings), each with a hint; or a failure of a job.

    Example:
        ``run(["3dgs"], ["synthetic/books"], schedule="tiny", run_dir="runs/smoke")``
    """
    from strings_bench.bench.executors import executor_factory
    from strings_bench.bench.plan import RunConfig, plan_run
    from strings_bench.bench.runner import execute

    c = RunConfig.of(config, datasets, **given)
    plan = plan_run(c)  # every value checked and resolved, before any scene is built
    return execute(plan, ocr=c.ocr_backend, executor=c.executor, progress=c.progress, write_report=c.write_report,
                   executor_options=c.executor_options)
