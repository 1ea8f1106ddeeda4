"""The run folder's cell schema and its `results.csv`: write a cell, read cells, turn a cell into a CSV row,
write the CSV.

Size (~470 lines): the run folder's one schema, written and read in one place (a cell's record, result.json's checks,
results.csv's and words.csv's rows), so that the writers and the readers cannot drift apart.

The runner and `strings-bench evaluate` write cells (`cells/<method>/<dataset>/<scene>/<iteration>/result.json`)
through one `write_cell(CellRecord)`; the reports and benchmark scripts read them back through this module. It imports nothing of the runner or the
reports, so both can depend on it (docs/architecture.md). The path and file names of a cell live in
`strings_bench.core.results` (CellKey, RESULT_FILE, RUN_FILE, RESULTS_CSV) and are re-exported here.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Iterable

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write, atomic_write_json, atomic_write_text, jsonable
from strings_bench.core.schedules import iteration_label
from strings_bench.core.results import RESULT_FILE, RESULTS_CSV, RUN_FILE, CellKey, is_finished, safe_name

__all__ = [
    "CellRecord", "write_cell", "render_file_name", "write_png", "CSV_COLUMNS", "ENGINE_COLUMNS", "READABILITY_COLUMNS", "engine_columns", "CellKey", "RESULT_FILE", "RESULTS_CSV",
    "RUN_FILE", "FORMER_NAMES", "upgrade_names", "cell_row", "is_finished", "iter_cells", "iteration_label", "read_cell", "read_manifest", "check_cell",
    "safe_name", "timing_columns", "write_results_csv", "script_columns", "cer_per_script",
]

# Word-crop readability (eval.readability) of the render, its GT-view ceiling (_gt), and the text-region image
# metrics (eval.metrics.text_region_metrics); read_words / read_oov_chars count the reference words and the
# reference characters outside the recogniser's dictionary.
READABILITY_COLUMNS = ["word_cer", "word_acc", "text_nll", "text_psnr", "text_ssim", "text_lpips", "word_cer_gt",
                       "text_nll_gt", "read_words", "read_oov_chars"]
CSV_COLUMNS = [
    "method", "dataset", "scene", "iteration", "label", "cer", "cer_known", "psnr", "ssim", "lpips",
    *READABILITY_COLUMNS,
    "train_seconds", "preprocess_seconds", "total_seconds", "gaussians", "budget", "peak_gaussians", "budget_reached_at",
    "peak_memory_mb", "cer_errors", "cer_chars", "cer_views", "ocr_failed",
    "gt_empty_ignored", "known_views", "eval_seconds", "schedule", "downscale", "ocr_backend",
]
# Names of the run folder's fields before issue 41, when "preset" named the run's schedule (run.json, result.json's
# config, results.csv's column): the readers of this module take such folders as today's.
FORMER_NAMES = {"preset": "schedule"}


def upgrade_names(d: dict) -> dict:
    """`d` (run.json, a cell's config, a results.csv row) with its former field names as today's (FORMER_NAMES);
    a field present under both names keeps today's."""
    out = dict(d)
    for old, new in FORMER_NAMES.items():
        if old in out:
            value = out.pop(old)
            out.setdefault(new, value)
    return out


# ---- writing a cell ------------------------------------------------------------------------------------
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


@dataclass(kw_only=True)
class CellRecord:
    """Everything about one cell, as result.json holds it (`check_cell` reads it back).

    config: how it was made: "method" (the method's describe()), "scene", "schedule" (the run's; None for
        `evaluate`), "downscale", "cer_profile", "versions", "metrics", and "method_presets"/"checkpoints" (a run)
        or "evaluate" (an evaluation of given renders).
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
    config: dict
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
            "label": self.label, "config": self.config, "resumed_from_step": self.resumed_from_step,
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


def _read_json(p: Path, what: str):
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
        yield check_cell(_read_json(p, "cell result"), p)


def read_cell(run_dir: str | Path, key: CellKey) -> dict | None:
    """One cell's result.json (checked), or None when the cell is not finished."""
    p = key.path(Path(run_dir)) / RESULT_FILE
    return check_cell(_read_json(p, "cell result"), p) if p.exists() else None


def read_manifest(run_dir: str | Path) -> dict | None:
    """RUN_DIR/run.json, checked for the fields a resumed run and the report read; None when there is
    none. A malformed file is a StringsBenchError naming it."""
    p = Path(run_dir) / RUN_FILE
    if not p.exists():
        return None
    m = _read_json(p, "run settings")

    def need(cond: bool, what: str) -> None:
        if not cond:
            raise StringsBenchError(f"run settings {p} are malformed: {what}",
                                    hint="restore it from a backup, or use another --out folder (the cells are kept)")
    need(isinstance(m, dict), f"a JSON {type(m).__name__}, not an object")
    m = upgrade_names(m)  # a folder written before issue 41 names the schedule "preset"
    need(isinstance(m.get("schedule"), dict) and isinstance(m["schedule"].get("name"), str),
         "'schedule' is missing or not an object with a name")
    need(isinstance(m.get("methods"), dict) and all(isinstance(v, dict) for v in m["methods"].values()),
         "'methods' is missing or not an object of objects")
    need(isinstance(m.get("datasets"), list), "'datasets' is missing or not a list")
    need(m.get("method_overrides") is None or isinstance(m["method_overrides"], dict), "'method_overrides' is not an object")
    need(isinstance(m.get("ocr"), str), "'ocr' is missing or not a string")
    need(isinstance(m.get("downscale"), _NUMBER), "'downscale' is missing or not a number")
    return m


def timing_columns(rec: dict) -> dict:
    """train/preprocess/total seconds of a cell. Cells written before preprocess time was recorded
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
    return {"train_seconds": "" if train is None else train, "preprocess_seconds": "" if pre is None else pre,
            "total_seconds": "" if total is None else total}


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
    """results.csv's `budget`: the cell's Gaussian cap (run --budget), "reference" for the uncapped reference of
    --budget METHOD, "" without a budget (and for cells written before budgets existed)."""
    b = (rec.get("config") or {}).get("budget")
    if isinstance(b, dict):
        return int(b["max_gaussians"])
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
# and on the GT views.
ENGINE_COLUMNS = ["cer_{engine}", "cer_known_{engine}", "ocr_failed_{engine}", "agree_words_{engine}",
                  "agree_identical_{engine}", "agree_gt_words_{engine}", "agree_gt_identical_{engine}"]


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


# ---- scripts and languages (issue 31) ------------------------------------------------------------------
def script_columns(rec: dict) -> dict:
    """`script` and `language` of a cell: the scripts of its scene's text, most frequent first, joined with
    '+' (from the known words, else from the GT OCR; the result's `text`), and the annotated languages.
    {} for cells written before they were recorded."""
    t = rec.get("text")
    if not isinstance(t, dict):
        return {}
    return {"script": "+".join(t.get("scripts") or []), "language": "+".join(t.get("languages") or [])}


def cer_per_script(rows: Iterable[dict], value: str = "cer") -> list[dict]:
    """Mean `value` (a results.csv column: cer, cer_known, ...) per script x method x checkpoint label, over
    the scenes of that script (every dataset together): [{"script", "method", "label", value, "scenes"}],
    sorted by script, method, label. A scene's script is its main one (the first of `script`); rows without
    a script or a number are left out."""
    groups: dict[tuple, list[float]] = {}
    for r in rows:
        script = str(r.get("script") or "").split("+")[0]
        v = r.get(value)
        try:
            v = float(v)
        except (TypeError, ValueError):
            continue
        if not script or v != v:  # no script recorded, or NaN
            continue
        groups.setdefault((script, r["method"], str(r["label"])), []).append(v)
    return [{"script": s, "method": m, "label": l, value: sum(vs) / len(vs), "scenes": len(vs)}
            for (s, m, l), vs in sorted(groups.items())]


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


# ---- words.csv: the per-word records of a cell (issue 30) --------------------------------------------------
# One row per reference word and view of the word-crop readability (eval.readability): the word, where it came
# from, its box's size at the evaluated resolution, the viewing angle and distance where the scene knows them
# (synthetic scenes; "n/a" elsewhere), and what the recogniser read on the GT crop and on the render crop. The
# cell's word-crop figures (results.csv: word_cer, word_acc, text_nll and their _gt ceilings) are sums over these
# rows (`words_summary`); floats are written with repr, so they read back exactly.
WORDS_FILE = "words.csv"
WORDS_COLUMNS = ["view", "word", "source", "headline", "height_px", "width_px", "angle_deg", "distance", "turn",
                 "chars", "oov_chars", "gt_read", "gt_errors", "gt_nll", "gt_nll_chars", "render_read",
                 "render_errors", "render_nll", "render_nll_chars"]
NA = "n/a"


def _float_text(x) -> str:
    """A float as words.csv writes it: repr (exact round trip), 'inf', 'nan'; None -> 'n/a'."""
    if x is None:
        return NA
    if x in ("inf", "-inf"):  # result.json spells the infinities so
        return x
    return repr(float(x))


def word_rows(rec: dict) -> list[dict]:
    """The words.csv rows of a cell's result.json (`rec`), [] when it has no word-crop readability.
    Cells written before the height/width were recorded get them from the stored reading-order box."""
    import math

    rd = rec.get("readability") or {}
    rows = []
    for view, words in (rd.get("views") or {}).items():
        for w in words:
            h, wd = w.get("height_px"), w.get("width_px")
            if h is None or wd is None:
                from strings_bench.eval.cer import text_height_px
                from strings_bench.eval.readability import box_size

                h, wd = text_height_px(w["polygon"]), box_size(w["polygon"])[0]
            g, r = w.get("gt") or {}, w.get("render") or {}
            chars, oov = int(w["chars"]), int(w.get("oov_chars", 0))

            def nll_chars(side: dict) -> int:
                # Readings store nll_chars since issue 30; before, it was chars - oov_chars (eval.readability.score).
                return int(side["nll_chars"]) if "nll_chars" in side else chars - oov

            rows.append({
                "view": view, "word": w["text"], "source": w["source"], "headline": int(bool(w.get("headline", True))),
                "height_px": _float_text(None if h is None or (isinstance(h, float) and math.isnan(h)) else h),
                "width_px": _float_text(wd), "angle_deg": _float_text(w.get("angle_deg")),
                "distance": _float_text(w.get("distance")), "turn": int(w.get("turn") or 0), "chars": chars,
                "oov_chars": oov, "gt_read": g.get("read", ""), "gt_errors": int(g["errors"]),
                "gt_nll": _float_text(math.nan if g.get("nll") is None else g["nll"]), "gt_nll_chars": nll_chars(g),
                "render_read": r.get("read", ""), "render_errors": int(r["errors"]),
                "render_nll": _float_text(math.nan if r.get("nll") is None else r["nll"]), "render_nll_chars": nll_chars(r),
            })
    return rows


def words_csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=WORDS_COLUMNS, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def write_words_csv(cell_dir: str | Path, rec: dict) -> Path | None:
    """Write CELL_DIR/words.csv (atomically) from the cell's record; None (nothing written) when the cell has no
    word-crop readability. Called before result.json is written, so a finished cell has its words.csv."""
    if not (rec.get("readability") or {}).get("views"):
        return None
    return atomic_write_text(Path(cell_dir) / WORDS_FILE, words_csv_text(word_rows(rec)))


def ensure_words_csv(run_dir: str | Path) -> int:
    """Write words.csv for every finished cell that lacks one (cells written before issue 30); returns how many."""
    n = 0
    for p in sorted((Path(run_dir) / "cells").glob(f"*/*/*/*/{RESULT_FILE}")):
        if not (p.parent / WORDS_FILE).exists():
            n += write_words_csv(p.parent, check_cell(_read_json(p, "cell result"), p)) is not None
    return n


def read_words_csv(path: str | Path) -> list[dict]:
    """words.csv's rows with numbers parsed (float for height/width/angle/distance/NLLs, None for n/a; int counts)."""
    ints = ("headline", "turn", "chars", "oov_chars", "gt_errors", "gt_nll_chars", "render_errors", "render_nll_chars")
    floats = ("height_px", "width_px", "angle_deg", "distance", "gt_nll", "render_nll")
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except OSError as exc:
        raise StringsBenchError(f"cannot read {path}: {exc}", hint="re-run `strings-bench report` to rewrite it") from exc
    out = []
    for i, r in enumerate(rows, start=2):
        try:
            out.append({**r, **{k: int(r[k]) for k in ints},
                        **{k: None if r[k] in (NA, "") else float(r[k]) for k in floats}})
        except (KeyError, ValueError, TypeError) as exc:
            raise StringsBenchError(f"{path} line {i} is malformed: {exc}",
                                    hint="delete it; `strings-bench report` writes it again from result.json") from exc
    return out


def words_summary(rows: list[dict], side: str = "render", source: str | None = None) -> dict:
    """word_cer, word_acc, text_nll and the counts of eval.readability.summarize, recomputed from words.csv rows
    (`read_words_csv`) of one `side` ("render" or "gt"): over the headline words, or over one `source`'s."""
    import math

    sel = [r for r in rows if (r["headline"] if source is None else r["source"] == source)]
    chars = sum(r["chars"] for r in sel)
    feasible = [r for r in sel if math.isfinite(r[f"{side}_nll"])]
    nll_chars = sum(r[f"{side}_nll_chars"] for r in feasible)
    return {
        "word_cer": sum(r[f"{side}_errors"] for r in sel) / chars if chars else math.nan,
        "word_acc": sum(r[f"{side}_errors"] == 0 for r in sel) / len(sel) if sel else math.nan,
        "text_nll": sum(r[f"{side}_nll"] for r in feasible) / nll_chars if nll_chars else math.nan,
        "words": len(sel), "chars": chars, "nll_chars": nll_chars, "oov_chars": sum(r["oov_chars"] for r in sel),
        "infeasible_words": sum(1 for r in sel if r[f"{side}_nll"] == math.inf),
    }
