"""The method adapter interface.

An adapter trains (or loads) a scene representation and, at each requested checkpoint iteration,
hands back the test-view renders and its stats. The runner does everything else (metrics, OCR,
CER, writing results), so an adapter only has to say what makes its method different.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Iterator

import numpy as np

if TYPE_CHECKING:
    from ..scene import Scene


@dataclass
class CheckpointResult:
    iteration: int
    renders: dict[str, np.ndarray]  # test-view image name -> (H, W, 3) float32 in [0, 1]
    train_seconds: float  # optimisation time only, cumulative up to this checkpoint
    gaussians: int
    peak_memory_mb: float = float("nan")
    extra: dict = field(default_factory=dict)  # method-specific stats (e.g. text Gaussians, fallback flags)
    # The method's work before its first optimisation step (initial model; STRinGS: masks, Algorithm 1,
    # Eq. 1); 0 when there is none. The runner reports total_seconds = preprocess + train.
    preprocess_seconds: float = 0.0


class MethodAdapter(ABC):
    """One method, configured. Subclasses set `name`, `paper` and `settings`."""

    name: str = "method"
    paper: str = ""
    # Whether the method may show progress bars (the runner sets it from --no-progress).
    progress: bool = True

    def __init__(self, **settings):
        self.settings = dict(settings)

    @abstractmethod
    def train(self, scene: "Scene", checkpoints: list[int], downscale: float = 1) -> Iterator[CheckpointResult]:
        """Train on `scene` and yield one CheckpointResult per checkpoint, in increasing order.

        Renders are of `scene.test_idx` views at `downscale`.
        """

    def describe(self) -> dict:
        return {"name": self.name, "paper": self.paper, "settings": self.settings}
