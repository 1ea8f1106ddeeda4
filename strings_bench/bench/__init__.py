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
    """Plan and execute a run. Takes a RunConfig (bench/plan.py: every option, documented there), or
    methods, datasets and RunConfig fields as keywords: `run(["3dgs"], ["synthetic/books"], schedule="tiny")`."""
    from strings_bench.bench.plan import RunConfig, plan_run
    from strings_bench.bench.runner import execute

    c = RunConfig.of(config, datasets, **given)
    plan = plan_run(c)  # every value checked and resolved, before any scene is built
    return execute(plan, ocr=c.ocr_backend, executor=c.executor, progress=c.progress, write_report=c.write_report,
                   executor_options=c.executor_options)
