"""What a run writes besides its cells (store/cells.py: `write_cell`): the ground-truth PNGs as they are
scored, the versions, the device, and the report (`write_run_report`: bench/'s one way into reports/). Shared by
the runner and `strings-bench evaluate`."""

from __future__ import annotations

import functools
import platform
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from strings_bench import __version__
from strings_bench.core.cpus import isa_record
from strings_bench.core.results import safe_name
from strings_bench.store import render_file_name, write_png

if TYPE_CHECKING:
    from strings_bench.eval.protocol import Evaluator


def write_gt_pngs(run_dir: Path, dataset: str, scene_name: str, evaluator: Evaluator) -> None:
    """RUN_DIR/gt/<dataset>/<scene>/<view stem>.png: the ground truth as scored, for the report's crops."""
    folder = Path(run_dir) / "gt" / safe_name(dataset) / safe_name(scene_name)
    for name in evaluator.names:
        path = folder / render_file_name(name)
        if not path.exists():
            write_png(path, evaluator.gt(name))


@functools.lru_cache(maxsize=None)
def source_revision(package_dir: str) -> dict:
    """{"source_commit": the git commit of the checkout holding package_dir, "source_modified": whether files
    under package_dir differ from that commit}, or {} when package_dir's files are not tracked by a git checkout
    (an installed wheel, also in a virtual environment inside some repository) or git is missing. A figure can then
    be traced to the code that made it, which the version number alone does not tell apart between commits."""
    def git(*args):
        return subprocess.run(["git", "-C", package_dir, *args], capture_output=True, text=True, timeout=30)

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0 or not git("ls-files", "--", ".").stdout.strip():
            return {}
        status = git("status", "--porcelain", "--untracked-files=no", "--", ".")
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"source_commit": head.stdout.strip(), "source_modified": bool(status.stdout.strip())}


def versions() -> dict:
    import torch

    out = {"strings_bench": __version__, **source_revision(str(Path(__file__).resolve().parents[1])),
           "python": platform.python_version(), "numpy": np.__version__, "torch": torch.__version__,
           "platform": platform.platform(), "cpu_kernels": isa_record()}
    try:
        from importlib.metadata import version

        out["rapidocr"] = version("rapidocr")
    except Exception:  # noqa: BLE001 - optional
        pass
    return out


def device_info(device: str) -> dict:
    """The device a job ran on, as recorded in result.json and run.json: {"device", "gpu"} (the GPU's
    name from torch.cuda.get_device_name on CUDA, else None)."""
    import torch

    gpu = None
    if str(device).startswith("cuda") and torch.cuda.is_available():
        gpu = torch.cuda.get_device_name(torch.device(device))
    return {"device": str(device), "gpu": gpu}


def write_run_report(run_dir: Path) -> Path:
    """RUN_DIR/report/ (strings_bench.reports.write_report); returns report.md's path."""
    from strings_bench.reports import write_report

    return write_report(run_dir)
