"""Fixtures of the executor tests (test_ray.py, test_slurm.py): the grid's scenes, the workers' PYTHONPATH and
SIGINT as in a terminal."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def scenes() -> list[Path]:
    """Two small synthetic scenes (books, globe at 96x72, 12 views), built here on the driver before any job runs."""
    from strings_bench.datasets.synthetic import build_scene, settings_with

    settings = settings_with(width=96, height=72, n_views=12)
    return [build_scene(name, settings, progress=False) for name in ("books", "globe")]


@pytest.fixture(scope="module")
def worker_pythonpath():
    """PYTHONPATH with the repository and tests/ first, for the module: Ray workers and Slurm tasks (sbatch exports
    this environment) import the tests' helpers (runner_fakes.FakeOCR, _ray_helpers.PausingRunner)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("PYTHONPATH", os.pathsep.join([str(TESTS.parent), str(TESTS), os.environ.get("PYTHONPATH", "")]))
        yield


@pytest.fixture
def sigint_raises():
    """SIGINT raises KeyboardInterrupt during the test, as in a terminal, even where the suite was started with
    SIGINT ignored (a background job of a non-interactive shell): Python keeps an inherited SIG_IGN, and the Ctrl-C
    tests would then wait forever."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)
