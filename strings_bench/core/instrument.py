"""Stage timings for profiling tools: where a training step's time goes, without replacing any function.

The trainer's step and the CPU rasterizer mark their stages: `with timed("backward"): ...` around a block,
`@stage("adam")` on a function, `note("render", color=...)` to hand a tool a value it needs (the tensor whose
gradient ends the loss's backward, the blend's inputs). With no recorder installed, which is always the case
outside a profiling tool, each mark is one check of a module global: the step runs as before, same bits.
A tool installs one for a block:

    times = StageTimes()
    with recording(times):
        method.train_step(step)
    times.seconds["backward"]        # wall seconds in the stage, summed over its calls

Stages (strings_bench/raster/cpu.py, engine/optim.py, engine/splatting.py): `preprocess.forward`,
`preprocess.backward` (projection and SH), `tiles.forward` (binning, sort and the blend), `blend.forward` (the
blend kernel alone, inside `tiles.forward`), `tiles.backward` (the backward blend and its reduction), `loss` (the
method's loss), `backward` (loss.backward(): every backward stage above runs inside it), `adam` (the optimizer
step). Notes: `render` (color: the rendered image, before the loss) and `blend.forward` (the blend kernel's
arguments after it ran: tile_start, lst, P, BB, W, H, tiles_x, out_last).
"""

from __future__ import annotations

import functools
import time
from contextlib import contextmanager, nullcontext
from typing import Any, Callable, Iterator, Protocol


class Recorder(Protocol):
    def add(self, stage: str, start: float, seconds: float, cpu_seconds: float) -> None:
        """One call of `stage`: its start (time.perf_counter), wall and process CPU seconds."""

    def note(self, name: str, values: dict[str, Any]) -> None:
        """Values a stage hands over (see the module's docstring)."""


class StageTimes:
    """A recorder that sums each stage's wall and CPU seconds and counts its calls; notes are kept, the last of
    each name (`notes`), and passed to `on_note` if given."""

    def __init__(self, on_note: Callable[[str, dict[str, Any]], None] | None = None):
        self.seconds: dict[str, float] = {}
        self.cpu_seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.notes: dict[str, dict[str, Any]] = {}
        self.on_note = on_note

    def add(self, stage: str, start: float, seconds: float, cpu_seconds: float) -> None:
        self.seconds[stage] = self.seconds.get(stage, 0.0) + seconds
        self.cpu_seconds[stage] = self.cpu_seconds.get(stage, 0.0) + cpu_seconds
        self.calls[stage] = self.calls.get(stage, 0) + 1

    def note(self, name: str, values: dict[str, Any]) -> None:
        self.notes[name] = values
        if self.on_note is not None:
            self.on_note(name, values)


_recorder: Recorder | None = None
_OFF = nullcontext()


@contextmanager
def recording(recorder: Recorder) -> Iterator[Recorder]:
    """Install `recorder` for the block (the one installed before it is restored after)."""
    global _recorder
    previous, _recorder = _recorder, recorder
    try:
        yield recorder
    finally:
        _recorder = previous


def active() -> bool:
    """Whether a recorder is installed (to skip building a note's values when none is)."""
    return _recorder is not None


@contextmanager
def _timing(stage: str, recorder: Recorder) -> Iterator[None]:
    start, cpu0 = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        recorder.add(stage, start, time.perf_counter() - start, time.process_time() - cpu0)


def timed(stage: str):
    """A context manager that times its block as `stage` for the installed recorder; a no-op without one."""
    recorder = _recorder
    return _OFF if recorder is None else _timing(stage, recorder)


def stage(name: str):
    """Decorator: every call of the function is timed as stage `name` (see `timed`)."""
    def decorate(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            if _recorder is None:
                return fn(*args, **kwargs)
            with _timing(name, _recorder):
                return fn(*args, **kwargs)
        return wrapper
    return decorate


def note(name: str, **values: Any) -> None:
    """Hand `values` to the installed recorder as note `name`; nothing without one."""
    recorder = _recorder
    if recorder is not None:
        recorder.note(name, values)
