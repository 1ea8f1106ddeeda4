"""words.csv: the per-word records of a cell (its columns: store/schema.py WORDS_COLUMNS), written from result.json
before it, read back with numbers parsed, and summed into the cell's word-crop figures."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_text
from strings_bench.store.schema import NA, WORDS_COLUMNS, WORDS_FILE


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
                # Readings store nll_chars; older ones did not: it was chars - oov_chars (eval.readability.score).
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
