"""The method protocol, and the interface for models trained outside the suite.

Two kinds of method:

- `Method`: a method the suite trains. The framework (`strings_bench.engine.trainer.Trainer`) owns
  the step loop, the device, the timing, checkpoint evaluation and the resumable training state;
  the method provides only what makes it different. The loop calls, in this order::

      method.setup(scene, downscale=..., device=..., seed=...)  # once; timed as preprocess_seconds
      for step in 1..last checkpoint:                      # steps are 1-based, as in 3DGS
          loss = method.train_step(step)                   # render, loss, backward, optimizer step
          if step is a checkpoint:
              method.render(view) for every test view      # the model after the update...
              method.checkpoint_extra(step), method.num_gaussians()
          method.refine(step)                              # ...but before densification / resets
      method.state_dict() / method.load_state_dict(state)  # saved at checkpoints and every N minutes

  This is the protocol of nerfbaselines' methods. 3DGS (`engine.splatting.GaussianSplatting`) is
  the reference implementation, and every built-in method is a plain subclass of it.

- `MethodAdapter`: a source of checkpoints for models the suite does not train (PLY files from
  elsewhere, an external program). Its `train()` yields one `CheckpointResult` per checkpoint.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Iterator

import numpy as np

from strings_bench.core.results import CheckpointResult

if TYPE_CHECKING:
    from strings_bench.scene.scene import Scene

__all__ = ["CheckpointResult", "Method", "MethodAdapter"]


class Method(ABC):
    """A method trained by the framework's loop (see the module docstring for the call order).

    Subclasses set `name`; a method's citation is its spec's (`MethodSpec.instantiate` sets `paper`). The method spec (`methods.spec.MethodSpec`) builds the
    object from its defaults, the preset and `--set`: with `cls.from_settings(**settings)` when the
    class has it (`GaussianSplatting` does), else `cls(**settings)`; the spec then sets `name` to its
    own. A class may describe its settings with `settings_schema()` (a list of `core.settings.Setting`):
    `strings-bench methods show` prints it, and `--set` keys are checked against it before a run
    starts."""

    name: str = "method"
    paper: str = ""
    progress: bool = True  # whether it may show progress bars (the loop sets it)

    @abstractmethod
    def setup(self, scene: "Scene", *, downscale: float = 1.0, device: str = "cpu", seed: int | None = None) -> None:
        """Prepare training on `scene`: preprocessing, the initial model, the optimizer.

        Args:
            scene: the scene; training views are `scene.train_idx`, images loaded at `downscale`.
            downscale: image downscale factor (2 = half width and height).
            device: torch device string ("cpu", "cuda", "cuda:1").
            seed: overrides the method's own seed setting when given.
        """

    @abstractmethod
    def train_step(self, step: int) -> float:
        """One optimisation step (1-based): render a training view, loss, backward, optimizer step.
        Returns the loss. Densification and other model changes belong in `refine`."""

    def refine(self, step: int) -> None:
        """Model changes after step `step` (densify, prune, opacity reset). The loop evaluates a
        checkpoint between `train_step` and `refine`, as the 3DGS reference saves before it densifies."""

    @abstractmethod
    def render(self, view_idx: int) -> np.ndarray:
        """The current model's render of scene view `view_idx`: (H, W, 3) float32 in [0, 1]."""

    @abstractmethod
    def num_gaussians(self) -> int:
        """Primitives in the current model (-1 when the notion does not apply)."""

    def checkpoint_extra(self, step: int) -> dict:
        """Method statistics stored with a checkpoint's results (JSON-serialisable)."""
        return {}

    @abstractmethod
    def state_dict(self) -> dict:
        """Everything needed to continue training bit for bit: parameters, optimizer and strategy
        state, the method's random generators and phase. Tensors may be on any device."""

    @abstractmethod
    def load_state_dict(self, state: dict) -> None:
        """Restore `state_dict()` after `setup()` on the same scene and settings."""

    def save_model(self, path) -> None:
        """Write the current model (3DGS PLY layout for Gaussian methods)."""
        raise NotImplementedError(f"method {self.name} cannot save its model")

    @classmethod
    def fixed_checkpoints(cls, settings: dict) -> list[int] | None:
        """Iterations this method must be evaluated at whatever the schedule says, from its settings (None: the
        schedule's). A class method: a run plans its checkpoints without building the method."""
        return None

    def describe(self) -> dict:
        """Name, paper and settings, as stored with every cell (JSON-serialisable)."""
        return {"name": self.name, "paper": self.paper, "settings": dict(getattr(self, "settings", {}))}


class MethodAdapter(ABC):
    """Checkpoints of a model the suite does not train (PLY files, an external program)."""

    name: str = "method"
    paper: str = ""
    progress: bool = True  # whether it may show progress bars (the runner sets it from --no-progress)

    def __init__(self, **settings):
        """Keep the flat settings (`--set` values over the spec's defaults and preset)."""
        self.settings = dict(settings)

    @abstractmethod
    def train(self, scene: "Scene", checkpoints: list[int], downscale: float = 1) -> Iterator[CheckpointResult]:
        """Yield one CheckpointResult per checkpoint, in increasing order; renders are of
        `scene.test_idx` views at `downscale`."""

    @classmethod
    def fixed_checkpoints(cls, settings: dict) -> list[int] | None:
        """Iterations to evaluate whatever the schedule says, from the adapter's settings (the `ply` adapter: the
        model's own); None: the schedule's. A class method: a run plans its checkpoints without building it."""
        return None

    def describe(self) -> dict:
        """Name, paper and settings, as stored with every cell."""
        return {"name": self.name, "paper": self.paper, "settings": self.settings}
