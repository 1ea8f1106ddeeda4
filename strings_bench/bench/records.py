"""What a run writes besides the metrics: PNGs as they are scored, JSON-safe records, versions and device.
Shared by the runner and `strings-bench evaluate`."""

from __future__ import annotations

import math
import platform
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

from strings_bench import __version__
from strings_bench.core.io import atomic_write
from strings_bench.core.results import safe_name
from strings_bench.eval.protocol import to_uint8

if TYPE_CHECKING:
    from strings_bench.eval.protocol import Evaluator

def write_png(path: Path, img: np.ndarray) -> None:
    """`img` as the 8-bit PNG the evaluation scores (eval.protocol.to_uint8), written atomically."""
    def write(tmp: Path) -> None:
        Image.fromarray(to_uint8(img)).save(tmp, format="PNG")

    atomic_write(path, write)


def write_gt_pngs(run_dir: Path, dataset: str, scene_name: str, evaluator: Evaluator) -> None:
    """RUN_DIR/gt/<dataset>/<scene>/<view stem>.png: the ground truth as scored, for the report's crops."""
    folder = Path(run_dir) / "gt" / safe_name(dataset) / safe_name(scene_name)
    for name in evaluator.names:
        path = folder / f"{Path(name).stem}.png"
        if not path.exists():
            write_png(path, evaluator.gt(name))


def _nan_to_none(x):
    if isinstance(x, float) and (math.isnan(x) or math.isinf(x)):
        return None if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.floating,)):
        return _nan_to_none(float(obj))
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, float):
        return _nan_to_none(obj)
    return obj


def versions() -> dict:
    import torch

    out = {"strings_bench": __version__, "python": platform.python_version(), "numpy": np.__version__,
           "torch": torch.__version__, "platform": platform.platform()}
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
