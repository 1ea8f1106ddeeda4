"""results.csv: one row per cell (`cell_row`), rebuilt from the cells' result.json (`write_results_csv`). Its columns
are store/schema.py's CSV_COLUMNS, then the ENGINE_COLUMNS of each further OCR engine, `script` and `language`."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from strings_bench.core.io import atomic_write_text
from strings_bench.core.schedules import iteration_label
from strings_bench.store.cells import iter_cells
from strings_bench.store.schema import CSV_COLUMNS, ENGINE_COLUMNS, RESULTS_CSV, upgrade_names


def timing_columns(rec: dict) -> dict:
    """train/preprocess/total seconds and training CPU seconds of a cell. Cells written before preprocess time was recorded
    (no `timings.preprocess_seconds`) take STRinGS' extra["preprocess_seconds"] (masks and Algorithm
    1, all it measured then; its Eq. 1 time was not measured) or else 0 (other methods had none)."""
    t = rec.get("timings") or {}
    train = t.get("train_seconds")
    pre = t.get("preprocess_seconds")
    if pre is None:
        pre = (rec.get("extra") or {}).get("preprocess_seconds", 0.0)
    total = t.get("total_seconds")
    if total is None and train is not None:
        total = train + pre
    cpu = t.get("train_cpu_seconds")  # cells written before it was measured have none
    return {"train_seconds": "" if train is None else train, "preprocess_seconds": "" if pre is None else pre,
            "total_seconds": "" if total is None else total, "train_cpu_seconds": "" if cpu is None else cpu}


def readability_columns(rec: dict) -> dict:
    """The READABILITY_COLUMNS of a cell ("" where the cell has none, e.g. written before they existed)."""
    m = rec.get("metrics") or {}
    rd = rec.get("readability") or {}
    render, gt = rd.get("render") or {}, rd.get("gt") or {}

    def num(x):
        return "" if x is None else x

    return {"word_cer": num(render.get("word_cer")), "word_acc": num(render.get("word_acc")),
            "text_nll": num(render.get("text_nll")), "text_psnr": num(m.get("text_psnr")),
            "text_ssim": num(m.get("text_ssim")), "text_lpips": num(m.get("text_lpips")),
            "word_cer_gt": num(gt.get("word_cer")), "text_nll_gt": num(gt.get("text_nll")),
            "read_words": num(render.get("words")), "read_oov_chars": num(render.get("oov_chars"))}


def budget_column(rec: dict) -> int | str:
    """results.csv's `budget`: the cell's Gaussian budget, a count (run --budget), "reference" for the
    reference of --budget METHOD (trained without one), "" without a budget (and for cells written before budgets existed)."""
    b = (rec.get("config") or {}).get("budget")
    if isinstance(b, dict):
        return int(b["count"] if "count" in b else b["max_gaussians"])  # "max_gaussians": cells before the rename
    return b if b == "reference" else ""


def cell_row(rec: dict) -> dict:
    """A cell's result.json as one results.csv row (keys: CSV_COLUMNS, plus ENGINE_COLUMNS for each further OCR
    engine; missing values are "")."""
    c = rec.get("cer") or {}
    k = rec.get("cer_known")
    ignored = c.get("ignored") or {}

    def num(x):
        return "" if x is None else x

    return {
        "method": rec["method"], "dataset": rec["dataset"], "scene": rec["scene"], "iteration": rec["iteration"],
        "label": rec.get("label", iteration_label(rec["iteration"])),
        "cer": num(c.get("cer")), "cer_known": "" if not k else num(k.get("cer")),
        "psnr": num(rec["metrics"].get("psnr")), "ssim": num(rec["metrics"].get("ssim")),
        "lpips": num(rec["metrics"].get("lpips")),
        **readability_columns(rec),
        **timing_columns(rec),
        "gaussians": "" if rec.get("gaussians") is None or rec["gaussians"] < 0 else rec["gaussians"],
        "budget": budget_column(rec),
        # the most Gaussians held before this checkpoint, and the step the budget was first filled ("" when it never
        # was, or without a budget; cells written before the record existed leave both empty)
        "peak_gaussians": num((rec.get("extra") or {}).get("peak_gaussians")),
        "budget_reached_at": num((rec.get("extra") or {}).get("budget_reached_at")),
        "peak_memory_mb": num(rec.get("peak_memory_mb")),
        # empty for cells that record none: written before the peak was reset per training (theirs is the
        # process's peak), or by a method that trains itself and reports its own figure
        "peak_memory_scope": (rec.get("extra") or {}).get("peak_memory_scope") or "",
        # the scene's rho (one early 3DGS position step in text strokes, docs/difficulty.md; "" where not measured)
        "rho": num(((rec.get("config") or {}).get("scene") or {}).get("rho")),
        "cer_errors": c.get("errors", ""), "cer_chars": c.get("chars", ""), "cer_views": len(c.get("images") or {}),
        "ocr_failed": len(ignored.get("failed") or []), "gt_empty_ignored": len(ignored.get("empty_gt") or []),
        "known_views": "" if not k else len(k.get("images") or {}),
        "eval_seconds": num(rec["timings"].get("eval_seconds")),
        "schedule": upgrade_names(rec["config"]).get("schedule") or "", "downscale": rec["config"].get("downscale", ""),
        "ocr_backend": (rec.get("ocr") or {}).get("backend", {}).get("name", ""),
        # "words": a dense checkpoint of `--checkpoints every:N`, word-crop metrics only (no OCR-CER); else "full"
        "evaluation": rec.get("evaluation", "full"),
        **engine_columns(rec),
        **script_columns(rec),
    }


# Per further OCR engine E of `run --ocr PRIMARY,E` (its name replaces {engine}): its CER and known-text CER
# (the primary's keep the names cer / cer_known), the views it failed on, and its agreement with the
# primary engine (cer.word_agreement): text regions and those read identically, on the render views
def engine_columns(rec: dict) -> dict:
    """The ENGINE_COLUMNS of every further OCR engine of a cell ({} for a single-engine cell)."""
    out: dict = {}
    for engine, e in (rec.get("ocr_engines") or {}).items():
        c, k, agree = e.get("cer") or {}, e.get("cer_known"), e.get("agreement") or {}
        ren, gt = agree.get("renders") or {}, agree.get("gt") or {}
        values = [c.get("cer"), None if not k else k.get("cer"), len((c.get("ignored") or {}).get("failed") or []),
                  ren.get("words"), ren.get("identical"), gt.get("words"), gt.get("identical")]
        for col, v in zip(ENGINE_COLUMNS, values):
            out[col.format(engine=engine)] = "" if v is None else v
    return out


def script_columns(rec: dict) -> dict:
    """`script` and `language` of a cell: the scripts of its scene's text, most frequent first, joined with
    '+' (from the known words, else from the GT OCR; the result's `text`), and the annotated languages.
    {} for cells written before they were recorded."""
    t = rec.get("text")
    if not isinstance(t, dict):
        return {}
    return {"script": "+".join(t.get("scripts") or []), "language": "+".join(t.get("languages") or [])}



def write_results_csv(run_dir: str | Path) -> Path:
    """Rebuild RUN_DIR/results.csv from the cell files (atomically); one row per cell, sorted by
    dataset, scene, method, iteration; CSV_COLUMNS, then the ENGINE_COLUMNS of each further OCR engine
    of the run. Returns the CSV's path."""
    rows = [cell_row(r) for r in iter_cells(run_dir)]
    rows.sort(key=lambda r: (r["dataset"], r["scene"], r["method"], int(r["iteration"])))
    extra = list(dict.fromkeys(k for r in rows for k in r if k not in CSV_COLUMNS))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_COLUMNS + extra, restval="", lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return atomic_write_text(Path(run_dir) / RESULTS_CSV, buf.getvalue())
