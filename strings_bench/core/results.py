"""Result types shared by the engine, the methods and the bench: a checkpoint's outcome and the
run folder's cell schema."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

RESULT_FILE = "result.json"  # a cell is finished when this file exists (written last, atomically)
RUN_FILE = "run.json"
RESULTS_CSV = "results.csv"


@dataclass
class CheckpointResult:
    """What a method hands back at one checkpoint iteration."""

    iteration: int
    renders: dict[str, np.ndarray]  # test-view image name -> (H, W, 3) float32 in [0, 1]
    train_seconds: float  # optimisation time only, cumulative up to this checkpoint
    gaussians: int
    peak_memory_mb: float = float("nan")
    extra: dict = field(default_factory=dict)  # method-specific stats (e.g. text Gaussians, fallback flags)
    # The method's work before its first optimisation step (initial model; STRinGS: masks, Algorithm 1,
    # Eq. 1); 0 when there is none. The runner reports total_seconds = preprocess + train.
    preprocess_seconds: float = 0.0
    resumed_from_step: int = 0  # the saved training state this run continued from (0: trained from the start)
    # The process's CPU time (all threads) over the same steps as train_seconds; None where not measured.
    train_cpu_seconds: float | None = None


def safe_name(name: str) -> str:
    """A file-name-safe form of a method, dataset or scene name."""
    return "".join(c if c.isalnum() or c in "-_.+" else "_" for c in str(name)) or "_"


@dataclass(frozen=True)
class CellKey:
    """One cell of a run: (method, dataset, scene, checkpoint iteration)."""

    method: str
    dataset: str
    scene: str
    iteration: int

    def path(self, run_dir: Path) -> Path:
        return (Path(run_dir) / "cells" / safe_name(self.method) / safe_name(self.dataset) / safe_name(self.scene)
                / str(self.iteration))


def is_finished(run_dir: Path, key: CellKey) -> bool:
    return (key.path(run_dir) / RESULT_FILE).is_file()
