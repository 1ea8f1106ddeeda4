"""Banked records: one compact row per cell, made from the cells' `result.json` committed under docs/results/data/
(tools/bank_cells.py banks them), so that every figure a verdict reads can be made again from the repository.

A record holds what a table reads of a cell and where it came from, not its renders: method, dataset, scene, draw,
seed, checkpoint (its label and the steps trained), every scalar metric (OCR-CER with its GT characters and errors,
known-text CER, word CER, PSNR, SSIM, LPIPS), training wall and CPU seconds, Gaussians, the commit of the code that
made it and the CPU kernel record of the machine (`config.versions.cpu_kernels`).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from strings_bench.core.io import atomic_write_text
from strings_bench.reports.compare.collect import cell_seed
from strings_bench.reports.compare.statistics import room_draw
from strings_bench.store import cell_row, iter_cells

RECORD_FIELDS = ("method", "dataset", "scene", "draw", "seed", "checkpoint", "iteration", "cer", "cer_chars",
                 "cer_errors", "cer_known", "word_cer", "psnr", "ssim", "lpips", "train_seconds", "train_cpu_seconds",
                 "gaussians", "source_commit", "kernels", "run_folder")


def kernel_record(rec: dict) -> str:
    """The machine's CPU kernel record of a cell, one string ("" for cells written before it was recorded)."""
    k = ((rec.get("config") or {}).get("versions") or {}).get("cpu_kernels") or {}
    return "; ".join(f"{key}={k[key]}" for key in sorted(k))


def cell_record(rec: dict, run_folder: str = "") -> dict:
    """One banked record (RECORD_FIELDS) of a cell's result.json."""
    r = cell_row(rec)
    room, draw = room_draw(r["scene"])
    versions = (rec.get("config") or {}).get("versions") or {}
    commit = (versions.get("source_commit") or "")[:12] + ("+modified" if versions.get("source_modified") else "")
    return {"method": r["method"], "dataset": r["dataset"], "scene": room, "draw": draw, "seed": cell_seed(rec),
            "checkpoint": r["label"], "iteration": r["iteration"], "cer": r["cer"], "cer_chars": r["cer_chars"],
            "cer_errors": r["cer_errors"], "cer_known": r["cer_known"], "word_cer": r["word_cer"], "psnr": r["psnr"],
            "ssim": r["ssim"], "lpips": r["lpips"], "train_seconds": r["train_seconds"],
            "train_cpu_seconds": r["train_cpu_seconds"], "gaussians": r["gaussians"], "source_commit": commit,
            "kernels": kernel_record(rec), "run_folder": run_folder}


def bank_records(bank: Path) -> list[dict]:
    """The records of every fully evaluated cell banked under `bank` (one sub-folder per run folder), sorted by
    dataset, scene, method, draw, seed and steps."""
    rows = []
    for run_dir in sorted(p for p in Path(bank).iterdir() if (p / "cells").is_dir()):
        for rec in iter_cells(run_dir):
            if rec.get("evaluation", "full") == "full":
                rows.append(cell_record(rec, run_dir.name))
    rows.sort(key=lambda r: (r["dataset"], r["scene"], r["method"], r["draw"], r["seed"], int(r["iteration"])))
    return rows


def _text(v) -> str:
    return "" if v in ("", None) else (repr(v) if isinstance(v, float) else str(v))


def records_csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(RECORD_FIELDS)
    w.writerows([[_text(r[f]) for f in RECORD_FIELDS] for r in rows])
    return buf.getvalue()


def read_records(path: Path) -> list[dict]:
    with Path(path).open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def write_records(bank: Path, out: Path) -> Path:
    atomic_write_text(out, records_csv(bank_records(bank)))
    return out
