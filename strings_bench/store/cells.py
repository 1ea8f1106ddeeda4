"""A run folder's cells: `CellRecord` (with its `CellConfig`) written by `write_cell`, and read back, checked, by
`read_cell` and `iter_cells`.

The runner and `strings-bench evaluate` write cells (`cells/<method>/<dataset>/<scene>/<iteration>/result.json`)
through the one `write_cell`; the reports and the benchmark scripts read them back through this module. The path and
file names of a cell live in `strings_bench.core.results` (CellKey, RESULT_FILE).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Iterable

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write, atomic_write_json, jsonable
from strings_bench.core.results import RESULT_FILE, CellKey
from strings_bench.store.schema import WORDS_FILE
from strings_bench.store.words import write_words_csv


def render_file_name(view: str) -> str:
    """The PNG a test view is written to, in a cell's renders/ and in gt/<dataset>/<scene>/: the view's name
    without its suffix, sub-folders joined with '_' ("left/0001.jpg" -> "left_0001.png")."""
    return PurePosixPath(str(view).replace("\\", "/")).with_suffix("").as_posix().replace("/", "_") + ".png"


def write_png(path: Path, img) -> None:
    """`img` as the 8-bit PNG the evaluation scores (eval.protocol.to_uint8), written atomically."""
    from PIL import Image

    from strings_bench.eval.protocol import to_uint8

    def write(tmp: Path) -> None:
        Image.fromarray(to_uint8(img)).save(tmp, format="PNG")

    atomic_write(path, write)



@dataclass(frozen=True, kw_only=True)
class CellConfig:
    """How a cell was made: result.json's `config`.

    schedule: the run's schedule (core/schedules.py); None for an evaluation of given renders.
    downscale, cer_profile: the image scale and the OCR-CER profile it was scored at.
    scene: {"path", "settings", "test_views"} (an evaluation: no path).
    versions, metrics: the software versions (bench/records.py) and the metrics' description (eval.metrics).
    A run's cell: method (the method's describe()), method_presets, checkpoints (the job's) and budget (the equal
    Gaussian budget: {"rule", "count", "reference"}, "max_gaussians" for "count" before the rename; "reference" for
    the reference of `--budget METHOD`, trained without a budget; None without one). An evaluation's cell: evaluate (what was evaluated) in their place.
    """

    schedule: str | None
    downscale: float
    cer_profile: str = "paper"
    scene: dict = field(default_factory=dict)
    versions: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    method: dict | None = None
    method_presets: tuple[str, ...] = ()
    checkpoints: tuple[int, ...] = ()
    budget: dict | str | None = None
    evaluate: dict | None = None

    def to_json(self) -> dict:
        out = {"schedule": self.schedule, "downscale": self.downscale, "cer_profile": self.cer_profile,
               "scene": self.scene, "versions": self.versions, "metrics": self.metrics}
        if self.evaluate is not None:
            return {**out, "evaluate": self.evaluate}
        return {**out, "method": self.method, "method_presets": list(self.method_presets),
                "checkpoints": list(self.checkpoints), "budget": self.budget}


@dataclass(kw_only=True)
class CellRecord:
    """Everything about one cell, as result.json holds it (`check_cell` reads it back).

    config: how it was made (`CellConfig`).
    timings: train_seconds, preprocess_seconds, total_seconds (None where not known), eval_seconds.
    scores: what eval.protocol.Evaluator returned: metrics, cer, cer_known, ocr, readability, text, ... (top-level
        keys of result.json).
    evaluation: "full", or "words" for a dense checkpoint of `--checkpoints every:N` (word-crop metrics only).
    """

    method: str
    dataset: str
    scene: str
    iteration: int
    label: str
    config: CellConfig
    timings: dict
    scores: dict
    evaluation: str = "full"
    gaussians: int | None = None
    peak_memory_mb: float | None = None
    resumed_from_step: int = 0
    device: str = ""  # as resolved by the training loop ("" for adapters and evaluations)
    gpu: str | None = None
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """result.json's object (JSON-safe)."""
        return jsonable({
            "method": self.method, "dataset": self.dataset, "scene": self.scene, "iteration": self.iteration,
            "label": self.label, "config": self.config.to_json(), "resumed_from_step": self.resumed_from_step,
            "device": self.device, "gpu": self.gpu, "timings": self.timings, "gaussians": self.gaussians,
            "peak_memory_mb": self.peak_memory_mb, "extra": self.extra, "evaluation": self.evaluation, **self.scores,
        })


def write_cell(cell_dir: str | Path, record: CellRecord, renders: dict | None = None) -> dict:
    """Write a cell: its renders (renders/<render_file_name>), words.csv, then result.json, last and atomically
    (a cell is finished when result.json exists, so a killed write leaves an unfinished cell). The record is
    checked as a reader would check it before anything is written. Returns result.json's object."""
    cell_dir = Path(cell_dir)
    rec = check_cell(record.to_json(), cell_dir / RESULT_FILE)
    for name, img in (renders or {}).items():
        write_png(cell_dir / "renders" / render_file_name(name), img)
    write_words_csv(cell_dir, rec)  # before result.json: a finished cell has its words.csv
    atomic_write_json(cell_dir / RESULT_FILE, rec)
    return rec


_NUMBER = (int, float)


def _is_number(v) -> bool:
    """A metric as result.json stores it: a number, null (NaN) or "inf"/"-inf" (JSON has no infinities)."""
    return v is None or v in ("inf", "-inf") or (isinstance(v, _NUMBER) and not isinstance(v, bool))


def _check(cond: bool, path: Path, what: str) -> None:
    if not cond:
        raise StringsBenchError(f"cell result {path} is malformed: {what}",
                                hint="delete that cell's folder and re-run to recompute it")


def check_cell(rec, path: str | Path) -> dict:
    """`rec` (a parsed result.json) when it has the fields results.csv and the reports read, with the
    right types; otherwise a StringsBenchError naming the file and the field."""
    path = Path(path)
    _check(isinstance(rec, dict), path, f"a JSON {type(rec).__name__}, not an object")
    for key in ("method", "dataset", "scene"):
        _check(isinstance(rec.get(key), str), path, f"{key!r} is missing or not a string")
    it = rec.get("iteration")
    _check(isinstance(it, int) and not isinstance(it, bool) and it >= 0, path, "'iteration' is missing or not an integer")
    for key in ("metrics", "timings", "config"):
        _check(isinstance(rec.get(key), dict), path, f"{key!r} is missing or not an object")
    for key in ("psnr", "ssim", "lpips"):
        v = rec["metrics"].get(key)
        _check(_is_number(v), path, f"metrics.{key} is not a number")
    for key in ("cer", "cer_known", "readability", "ocr", "extra"):
        _check(rec.get(key) is None or isinstance(rec[key], dict), path, f"{key!r} is not an object")
    for key in ("cer", "cer_known"):
        v = (rec.get(key) or {}).get("cer")
        _check(_is_number(v), path, f"{key}.cer is not a number")
    views = (rec.get("ocr") or {}).get("views", {})
    _check(isinstance(views, dict), path, "ocr.views is not an object")
    g = rec.get("gaussians")
    _check(g is None or (isinstance(g, int) and not isinstance(g, bool)), path, "'gaussians' is not an integer")
    return rec


def read_json(p: Path, what: str):
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # a UnicodeDecodeError is a ValueError
        raise StringsBenchError(f"{what} {p} is unreadable: {exc}",
                                hint="delete that cell's folder and re-run to recompute it" if what == "cell result"
                                else "delete it, or use another --out folder") from exc


def iter_cells(run_dir: str | Path) -> Iterable[dict]:
    """Every finished cell's result.json under RUN_DIR/cells, parsed and checked (`check_cell`), in path order."""
    root = Path(run_dir) / "cells"
    if not root.is_dir():
        return
    for p in sorted(root.glob(f"*/*/*/*/{RESULT_FILE}")):
        yield check_cell(read_json(p, "cell result"), p)


def read_cell(run_dir: str | Path, key: CellKey) -> dict | None:
    """One cell's result.json (checked), or None when the cell is not finished."""
    p = key.path(Path(run_dir)) / RESULT_FILE
    return check_cell(read_json(p, "cell result"), p) if p.exists() else None


def ensure_words_csv(run_dir: str | Path) -> int:
    """Write words.csv for every finished cell that lacks one (cells written before words.csv existed); returns how
    many."""
    n = 0
    for p in sorted((Path(run_dir) / "cells").glob(f"*/*/*/*/{RESULT_FILE}")):
        if not (p.parent / WORDS_FILE).exists():
            n += write_words_csv(p.parent, check_cell(read_json(p, "cell result"), p)) is not None
    return n
