"""Shared pytest setup.

Layout: one folder per layer of strings_bench/ (tests/core/ ... tests/cli/), plus tests/docs/, tests/tools/
(tools/, studies/ and scripts/), tests/integration/ (end to end) and tests/lint/ (the layout and docs rules). Every
folder is a package (`tests.engine.test_engine`), so a module's basename may repeat across folders and a test
imports another folder's test module by its full name (`from tests.raster.test_raster import random_scene`).
The helper modules of this folder (runner_fakes, _engine_helpers, ...) are imported by their plain names from
any folder: this file appends tests/ to sys.path (appended, so that tests/tools/ never shadows the repository's
own top-level names).
- STRINGS_BENCH_CACHE points at a per-session temporary folder unless the caller already set it,
  so tests never write into (or read stale scenes from) the user's cache.
- STRINGS_BENCH_KERNEL_WARMUP=0: no run of a test starts the kernel warm-up's second process.
- `synthetic_books_small`: the `books` synthetic scene at 160x120 with 24 views, built once per
  session (a few seconds) and shared by every test that needs a real scene folder (images,
  sparse/0 from pycolmap, masks, text_annotations.json). Treat it as read-only.
- `private_cache`: STRINGS_BENCH_CACHE in the test's own tmp_path (for the modules whose tests must build their
  scenes afresh: `pytestmark = pytest.mark.usefixtures("private_cache")`).
- `scene_dir`: the 9-view toy scene of runner_fakes (the fake methods registered), built once per module.
- `fake_run`: a finished `tiny` run folder (fake methods fake-a/b/c on the 9-view toy scene of
  runner_fakes with "hello" written in its text block, the fake OCR; no LPIPS), with its report.
  Shared by the report tests (tables, figures, HTML, the browser test); a test may rewrite its
  report, but nothing else in it.
"""

from __future__ import annotations

import strings_bench.bench as bench

import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
if str(TESTS) not in sys.path:
    sys.path.append(str(TESTS))

# Compiled numba kernels are safe to share and slow to build (tens of seconds): keep them in the
# user's persistent cache even though everything else goes to the per-session folder.
os.environ.setdefault("NUMBA_CACHE_DIR", str(Path.home() / ".cache" / "strings-bench" / "numba"))

# The runs of tests compile no kernels in a second process (bench/warmup.py): tests/bench/test_warmup.py turns it on.
os.environ.setdefault("STRINGS_BENCH_KERNEL_WARMUP", "0")

_OWN_CACHE: str | None = None
if not os.environ.get("STRINGS_BENCH_CACHE"):
    _OWN_CACHE = tempfile.mkdtemp(prefix="strings-bench-test-cache-")
    os.environ["STRINGS_BENCH_CACHE"] = _OWN_CACHE

# Settings of the shared small scene (also reachable from the CLI:
# `strings-bench datasets prepare synthetic/books --width 160 --height 120 --views 24`).
SMALL_BOOKS = {"width": 160, "height": 120, "n_views": 24}


def _workers(config) -> int:
    n = getattr(config.option, "numprocesses", None)  # pytest-xdist's -n (None without it)
    return n if isinstance(n, int) else 0


@pytest.hookimpl(wrapper=True)
def pytest_runtestloop(session):
    """Before the first test is handed to a worker (in the controller of a run on two or more xdist workers, whose
    workers are then starting and collecting): compile the CPU kernels of every trained method once, in two
    processes at once, where numba's cache does not hold them yet (a fresh clone). Inside the session, so that the
    seconds pytest reports include it.

    Each worker would otherwise compile the kernels its first trainings call, and both workers call most of the
    same ones: on a 2-core Intel Xeon the default suite took 456 s of tests from an empty numba cache against 365 s
    with it filled, the difference spread over the first training test of each file; side by side from fresh
    clones, 515.6 s without this and 481.6 s with it (docs/results/engine-speed.md, "The tests from an empty numba
    cache"). The warm-up processes (`strings_bench.bench.warmup`, the one a run uses)
    write the same cache the workers read. STRINGS_BENCH_TEST_PREWARM=0 turns this off."""
    config = session.config
    if not hasattr(config, "workerinput") and _workers(config) >= 2 and not config.option.collectonly and \
            os.environ.get("STRINGS_BENCH_TEST_PREWARM", "1").strip().lower() not in ("0", "false", "no", "off"):
        _compile_kernels_once(config)
    return (yield)


def _compile_kernels_once(config) -> None:
    import subprocess
    import time

    from strings_bench.bench import warmup
    from strings_bench.methods.registry import list_methods

    trained = [s.name for s in list_methods() if s.group != "adapter" and s.ablation_of is None]
    try:
        todo = [m for m in trained if not warmup.marker(m).exists()]
    except (ImportError, OSError):
        return
    if not todo:
        return
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    began = time.monotonic()
    halves = [todo[0::2], todo[1::2]]
    procs = [subprocess.Popen([sys.executable, "-m", "strings_bench.bench.warmup", *half], env=env,
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for half in halves if half]
    failed = []
    for proc in procs:
        try:
            _, err = proc.communicate(timeout=warmup.WAIT_LIMIT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            err = f"timed out after {warmup.WAIT_LIMIT_S:.0f} s"
        if proc.returncode:
            failed.append(err.strip().splitlines()[-1] if err and err.strip() else f"exit {proc.returncode}")
    # the tests compile whatever a failed warm-up left out; the failure itself is for the user to see
    note = f"; failed: {'; '.join(failed)}" if failed else ""
    line = (f"[strings-bench] compiled the CPU kernels of {len(todo)} methods in {time.monotonic() - began:.0f} s "
            f"before the tests (numba's cache did not hold them{note})")
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    reporter.write_line(line) if reporter is not None else sys.stderr.write(line + "\n")


def pytest_unconfigure(config):
    if _OWN_CACHE is not None:
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)


@pytest.fixture(scope="session")
def synthetic_small_settings():
    from strings_bench.datasets.synthetic import settings_with

    return settings_with(**SMALL_BOOKS)


@pytest.fixture(scope="session")
def synthetic_books_small(synthetic_small_settings) -> Path:
    """Path of the small `books` scene folder (loadable with Scene.load)."""
    from strings_bench.datasets.synthetic import build_scene

    return build_scene("books", synthetic_small_settings, progress=False)


@pytest.fixture
def private_cache(tmp_path, monkeypatch) -> Path:
    """STRINGS_BENCH_CACHE set to the test's own folder: nothing cached by another test is read, nothing left."""
    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    """The toy scene of runner_fakes (9 views), with the fake methods registered; one per module."""
    import runner_fakes as rf

    rf.register_fakes()
    return rf.make_scene(tmp_path_factory.mktemp("scenes") / "toyset")


@pytest.fixture(scope="session")
def fake_run(tmp_path_factory) -> Path:
    """Path of a finished tiny run folder with its report (see the module docstring)."""
    import runner_fakes as rf
    import strings_bench.bench.runner as runner

    rf.register_fakes()
    root = tmp_path_factory.mktemp("fake_run")
    scene = rf.make_scene(root / "scenes" / "toyset", glyphs=True)
    out = root / "run"
    bench.run(["fake-a", "fake-b", "fake-c"], [str(scene)], run_dir=out, schedule="tiny", ocr="fake",
               ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False)
    return out
