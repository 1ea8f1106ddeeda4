"""Test helpers that Ray workers import (the tests put this folder on the workers' PYTHONPATH)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import strings_bench.store.cells as cell_writer  # write_cell writes result.json through its atomic_write_json
from strings_bench.bench.runner import Runner
from strings_bench.core.results import RESULT_FILE


class PausingRunner(Runner):
    """A Runner whose jobs stop mid-job until the file `released` appears in `pause_dir`, after writing
    `paused-<pid>` there, so that the test knows a worker is mid-job and can kill or cancel it.

    They stop at training step `pause_step` (between two saves of the training state), or, with
    `pause_cell`, when cell `pause_cell` has its renders on disk but not yet its result.json. `only`
    (method, scene name) limits the pause to one job.
    """

    def __init__(self, *args, pause_dir: str, pause_step: int | None = None, pause_cell: int | None = None,
                 only: tuple[str, str] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.pause_dir = str(pause_dir)
        self.pause_step = pause_step
        self.pause_cell = pause_cell
        self.pause_only = tuple(only) if only else None

    def run_job(self, job):
        from strings_bench.engine.splatting import GaussianSplatting

        pause_dir = Path(self.pause_dir)
        here = self.pause_only in (None, (job.method, job.scene))

        def pause():
            if here and not (pause_dir / "released").exists():
                (pause_dir / f"paused-{os.getpid()}").write_text(f"{job.method} {job.scene}")
                while not (pause_dir / "released").exists():
                    time.sleep(0.05)

        real_step = GaussianSplatting.train_step
        real_json = cell_writer.atomic_write_json

        def train_step(method, step):
            if step == self.pause_step:
                pause()
            return real_step(method, step)

        def atomic_write_json(path, obj):
            if Path(path).name == RESULT_FILE and Path(path).parent.name == str(self.pause_cell):
                pause()
            return real_json(path, obj)

        GaussianSplatting.train_step = train_step
        cell_writer.atomic_write_json = atomic_write_json
        try:
            return super().run_job(job)
        finally:
            GaussianSplatting.train_step = real_step
            cell_writer.atomic_write_json = real_json


def is_time_column(column: str) -> bool:
    """results.csv's timings (wall and CPU seconds) and memory, which differ between any two runs of a grid."""
    return column.endswith("_seconds") or column == "peak_memory_mb"
