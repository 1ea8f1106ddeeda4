"""Running the benchmark: a run planned (plan.py, with its equal Gaussian cap in budget.py), its jobs executed
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
    factory = executor_factory(c.executor)
    if factory.in_process:  # jobs run here: a missing GPU is refused before any scene is built
        from strings_bench.engine.trainer import resolve_device

        resolve_device(c.device)
    # e.g. Ray not installed, --device cuda:1, or options the executor does not take: refused before any scene is built
    factory.check_options(device=c.device, **(c.executor_options or {}))
    if c.ocr_backend is None:  # the engines are built from the names: an unknown one fails before any training
        from strings_bench.eval.ocr import parse_engines

        parse_engines(c.ocr)
    plan = plan_run(c)
    return execute(plan, ocr=c.ocr_backend, executor=c.executor, with_lpips=c.with_lpips, progress=c.progress,
                   write_report=c.write_report, lpips_at=c.lpips_at, executor_options=c.executor_options)
