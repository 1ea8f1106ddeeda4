"""Readability analysis of a run: CER by text size, time to legibility, and the speed/accuracy front.

The paper argues three things its tables do not measure: that STRinGS reconstructs *small* text better (its
Appendix D.2), that text becomes readable *early* (its text-evolution figure), and that it is best in both
efficiency and accuracy (its teaser scatter). Each becomes a measured table here, for any method and scene:

- **CER by text size** (`cer_by_size`): word-crop CER (eval/readability.py) of the headline reference words,
  pooled over the scenes of a dataset, per word-height bin (`HEIGHT_BINS`, the height of the word's box at the
  evaluated resolution, words.csv's `height_px`) at one checkpoint (`size_label`), with the known-text words' CER
  per bin where the scene knows its text, the word count of each bin and the GT ceiling (the same words read on
  the ground-truth views). A bin with fewer than `MIN_BIN_WORDS` words is shown greyed and never ranked.
- **Time to legibility** (`time_to_threshold`): per method and scene, the training time (preprocessing +
  optimisation, results.csv's total_seconds) and the trained step at which word CER and OCR-CER first fall below
  each of `THRESHOLDS`, linearly interpolated between the two evaluated checkpoints that straddle it; "not reached"
  when no checkpoint is below. A value below the threshold at the first checkpoint is reported at that
  checkpoint (an upper bound; marked "<=").
- **Speed/accuracy front** (`pareto_front`): at each checkpoint, the methods that no other method beats on both
  mean training time and mean CER (lower is better on both; a method equal on both to another is on the front
  with it).
- **Size/accuracy front** (`fronts(..., x="gaussians")`): the same with the mean Gaussian count at the
  checkpoint in place of the training time: which methods read best for their model size (the question of an
  equal-budget run, `run --budget`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import pandas as pd

from strings_bench.core.io import atomic_write_text
from strings_bench.core.results import CellKey
from strings_bench.store import WORDS_FILE, read_words_csv
from strings_bench.reports.aggregate import main_labels, with_total_seconds
from strings_bench.reports.table_model import (GT_CEILING, RANK_NOTE, REGISTERED, Column, MethodNames, Table,
                                               dataset_title)

# Word-height bins in pixels at the evaluated resolution: [lower, upper). At 320x240 the synthetic scenes' words
# are ~5 px high (docs/ocr.md); the recogniser's input is 48 px high; 6.5 px is the known-text CER's legibility
# floor (eval/cer.py KNOWN_TEXT_MIN_HEIGHT_PX), so known words land from the 6-9 bin up.
HEIGHT_BINS: tuple[tuple[str, float, float], ...] = (
    ("<6", 0.0, 6.0), ("6-9", 6.0, 9.0), ("9-13", 9.0, 13.0), ("13-20", 13.0, 20.0), (">=20", 20.0, math.inf))
MIN_BIN_WORDS = 10  # a bin with fewer reference words is greyed and never ranked
# Time to legibility: when a CER first falls below each. 0.5 and 0.2 are the design's (half the characters, and
# most words, read); 0.8 is added because CPU schedules rarely get below 0.5 (docs/readability.md).
THRESHOLDS = (0.8, 0.5, 0.2)
LEGIBILITY_METRICS = {"word_cer": "word CER", "cer": "OCR-CER"}
FRONT_METRICS = {"cer": "OCR-CER", "word_cer": "word CER"}
# The fronts' x axes: results.csv's column (per cell) -> (what the report calls it, the unit it prints, its format).
FRONT_AXES = {"minutes": ("training time", "min", "{:.2f}"), "gaussians": ("Gaussian count", "Gaussians", "{:,.0f}")}


def size_bin(height_px: float | None) -> str | None:
    """The HEIGHT_BINS label of a word height (None for an unknown height)."""
    if height_px is None or math.isnan(height_px):
        return None
    for name, lo, hi in HEIGHT_BINS:
        if lo <= height_px < hi:
            return name
    return None


# ---- the words of a run ------------------------------------------------------------------------------------
def load_words(run_dir: str | Path, df: pd.DataFrame) -> pd.DataFrame:
    """Every cell's words.csv rows, with the cell's method, dataset, scene, iteration and label, and `bin`."""
    frames = []
    for r in df[["method", "dataset", "scene", "iteration", "label"]].itertuples(index=False):
        p = CellKey(r.method, r.dataset, r.scene, int(r.iteration)).path(Path(run_dir)) / WORDS_FILE
        if not p.exists():
            continue
        rows = read_words_csv(p)
        if rows:
            frames.append(pd.DataFrame(rows).assign(method=r.method, dataset=r.dataset, scene=r.scene,
                                                    iteration=int(r.iteration), label=str(r.label)))
    if not frames:
        return pd.DataFrame()
    w = pd.concat(frames, ignore_index=True)
    w["bin"] = [size_bin(h) for h in w["height_px"]]
    return w


# ---- CER by text size ----------------------------------------------------------------------------------------
def size_label(df: pd.DataFrame) -> str | None:
    """The checkpoint of the CER-by-size tables: the latest fully evaluated one (tables.main_labels) among those
    that the most methods reached (a run stopped early for some methods still compares them all)."""
    labels = main_labels(df)
    if not labels:
        return None
    full = df[df["evaluation"].fillna("full") != "words"] if "evaluation" in df else df
    n = {lab: full[full["label"] == lab]["method"].nunique() for lab in labels}
    best = max(n.values())
    return [lab for lab in labels if n[lab] == best][-1]


def cer_by_size(words: pd.DataFrame, label: str, known: bool = False, names: MethodNames = REGISTERED) -> pd.DataFrame:
    """CER per (dataset, method, height bin) at checkpoint `label`, pooled over the dataset's scenes: errors over
    reference characters of the headline words (`known`: of the known-text words only), rows for the GT ceiling
    (method GT_CEILING: the same words on the GT views, which do not depend on the method; taken from the first
    method's cells of each scene). Columns: dataset, method, bin, words, chars, errors, cer, greyed."""
    cols = ["dataset", "method", "bin", "words", "chars", "errors", "cer", "greyed"]
    if words.empty:
        return pd.DataFrame(columns=cols)
    w = words[(words["label"] == label) & words["bin"].notna()]
    w = w[w["source"] == "known"] if known else w[w["headline"] == 1]
    out = []
    for d in dict.fromkeys(w["dataset"]):
        wd = w[w["dataset"] == d]
        methods = [m for m in names.order(wd["method"]) if not names.is_ablation(m)]
        # the GT side: one method's cells per scene (every method's cells hold the same reference words and GT reads)
        gt_parts = [wd[(wd["scene"] == s) & (wd["method"] == wd[wd["scene"] == s]["method"].iloc[0])]
                    for s in dict.fromkeys(wd["scene"])]
        gt = pd.concat(gt_parts) if gt_parts else wd.iloc[:0]
        for name, _lo, _hi in HEIGHT_BINS:
            g = gt[gt["bin"] == name]
            n = len(g)
            for m in [*methods, GT_CEILING]:
                sel, side = (g, "gt") if m == GT_CEILING else (wd[(wd["method"] == m) & (wd["bin"] == name)], "render")
                chars, errors = int(sel["chars"].sum()), int(sel[f"{side}_errors"].sum())
                out.append({"dataset": d, "method": m, "bin": name, "words": n, "chars": chars, "errors": errors,
                            "cer": errors / chars if chars else math.nan, "greyed": n < MIN_BIN_WORDS})
    return pd.DataFrame(out, columns=cols)


def size_table(by_size: pd.DataFrame, label: str, known: bool, note: str = "",
               names: MethodNames = REGISTERED) -> Table | None:
    if by_size.empty or not (by_size["words"] > 0).any():
        return None
    cols = []
    methods: list[str] = []
    for d in dict.fromkeys(by_size["dataset"]):
        sub = by_size[by_size["dataset"] == d]
        methods += [m for m in dict.fromkeys(sub["method"]) if m not in methods and m != GT_CEILING]
        for name, _lo, _hi in HEIGHT_BINS:
            b = sub[sub["bin"] == name]
            n = int(b["words"].iloc[0]) if len(b) else 0
            if n == 0:
                continue
            sub_plain = f"{name} px (n={n})"
            cols.append(Column(dataset_title(d), sub_plain.replace(">=", r"$\geq$").replace("<", r"$<$"), sub_plain,
                               True, ".3f", {r.method: r.cer for r in b.itertuples()},
                               greyed=bool(b["greyed"].iloc[0])))
    if not cols:
        return None
    what = "Known-text word CER" if known else "Word CER"
    name = "known_cer_by_size" if known else "word_cer_by_size"
    return Table(name, what + r" by text height $\downarrow$", f"{what} by text height (lower is better)", cols,
                 [*names.order(methods), GT_CEILING],
                 f"{what} at {label} iterations per word-height bin (the height of the word's box in pixels at the "
                 "evaluated resolution; bins [lower, upper) px), errors over reference characters pooled over the "
                 f"scenes of each dataset; n = reference words in the bin. "
                 + ("Known words only (synthetic scenes; those at least 6.5 px high). " if known else
                    "Headline reference words (known words and the GT view's OCR words; eval/readability.py). ")
                 + f"The last row reads the same words on the ground-truth views (the ceiling: a bin the GT view "
                 f"cannot be read in measures the recogniser, not the method). Bins with fewer than {MIN_BIN_WORDS} "
                 "words are greyed and not ranked." + RANK_NOTE + note, heading=f"{what} by text size")


def size_spread(by_size: pd.DataFrame) -> pd.DataFrame:
    """Per (dataset, bin) of at least MIN_BIN_WORDS words: the spread of the methods' CER (max - min, GT row
    excluded): how much a bin separates the methods."""
    rows = []
    for (d, b), g in by_size[(~by_size["greyed"]) & (by_size["method"] != GT_CEILING)].groupby(["dataset", "bin"], sort=False):
        v = g["cer"].dropna()
        if len(v) >= 2:
            rows.append({"dataset": d, "bin": b, "words": int(g["words"].iloc[0]), "spread": float(v.max() - v.min()),
                         "best": g.loc[v.idxmin(), "method"], "worst": g.loc[v.idxmax(), "method"]})
    return pd.DataFrame(rows, columns=["dataset", "bin", "words", "spread", "best", "worst"])


# ---- time to legibility -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Crossing:
    """Where a CER curve first falls below a threshold: the step and the training seconds (interpolated), and
    whether the first evaluated checkpoint was already below (then both are that checkpoint's: an upper bound)."""

    step: float
    seconds: float
    at_first: bool = False


def time_to_threshold(steps: Sequence[float], seconds: Sequence[float], values: Sequence[float],
                      threshold: float) -> Crossing | None:
    """The first point at which `values` (a CER per checkpoint, in step order) falls below `threshold` (strictly),
    linearly interpolated in step and in seconds between the last checkpoint at or above it and the first one
    below; None when no checkpoint is below. NaN values are skipped."""
    pts = sorted((float(s), float(t), float(v)) for s, t, v in zip(steps, seconds, values)
                 if v is not None and not math.isnan(float(v)))
    prev = None
    for s, t, v in pts:
        if v < threshold:
            if prev is None:
                return Crossing(s, t, at_first=True)
            s0, t0, v0 = prev
            f = (v0 - threshold) / (v0 - v)  # v0 >= threshold > v, so 0 <= f < 1
            return Crossing(s0 + f * (s - s0), t0 + f * (t - t0))
        prev = (s, t, v)
    return None


def legibility(df: pd.DataFrame, thresholds: Iterable[float] = THRESHOLDS) -> pd.DataFrame:
    """Time to legibility per (dataset, scene, method, metric, threshold): step, minutes, at_first, reached."""
    df = with_total_seconds(df)
    rows = []
    for (d, s, m), g in df.groupby(["dataset", "scene", "method"], sort=False):
        g = g.sort_values("iteration")
        for metric in LEGIBILITY_METRICS:
            if metric not in g or pd.to_numeric(g[metric], errors="coerce").isna().all():
                continue
            for thr in thresholds:
                c = time_to_threshold(g["iteration"], g["total_seconds"], pd.to_numeric(g[metric], errors="coerce"), thr)
                rows.append({"dataset": d, "scene": s, "method": m, "metric": metric, "threshold": thr,
                             "reached": c is not None, "step": math.nan if c is None else c.step,
                             "minutes": math.nan if c is None else c.seconds / 60, "at_first": bool(c and c.at_first),
                             "last_step": int(g["iteration"].max()), "last_value": float(pd.to_numeric(g[metric], errors="coerce").iloc[-1])})
    return pd.DataFrame(rows)


def legibility_table(leg: pd.DataFrame, note: str = "", names: MethodNames = REGISTERED) -> Table | None:
    if leg.empty:
        return None
    cols = []
    for (d, s), g in leg.groupby(["dataset", "scene"], sort=False):
        for metric in LEGIBILITY_METRICS:
            for thr in dict.fromkeys(g["threshold"]):
                sel = g[(g["metric"] == metric) & (g["threshold"] == thr)]
                if sel.empty:
                    continue
                name = f"{LEGIBILITY_METRICS[metric]}<{thr:g}"
                cols.append(Column(f"{dataset_title(d)} {s}", name.replace("<", "$<$"), name, True, ".2f",
                                   {r.method: r.minutes for r in sel.itertuples()}, na="not reached",
                                   prefix={r.method: "<=" for r in sel.itertuples() if r.at_first},
                                   suffix={r.method: f" ({r.step:.0f})" for r in sel.itertuples() if r.reached}))
    methods = names.order(m for m in leg["method"] if not names.is_ablation(m))
    thr = ", ".join(f"{t:g}" for t in dict.fromkeys(leg["threshold"]))
    return Table("time_to_legibility", "Method", "Method", cols, methods,
                 f"Time to legibility: training minutes (preprocessing + optimisation) and, in parentheses, the trained "
                 f"step at which word CER and OCR-CER first fall below {thr}, linearly interpolated between the two "
                 "evaluated checkpoints that straddle the threshold; not reached: no evaluated checkpoint is below. A "
                 "value marked <= was already below at the first evaluated checkpoint (an upper bound)." + RANK_NOTE
                 + note, heading="Time to legibility")


# ---- speed/accuracy front ----------------------------------------------------------------------------------------
def pareto_front(points: dict[str, tuple[float, float]]) -> list[str]:
    """The names whose (time, value) no other point dominates (lower is better on both: another point at most as
    large on both and smaller on one dominates); NaN points are never on the front. In input order."""
    ok = {k: (float(t), float(v)) for k, (t, v) in points.items() if not (math.isnan(float(t)) or math.isnan(float(v)))}
    front = []
    for k, (t, v) in ok.items():
        if not any((t2 <= t and v2 <= v) and (t2 < t or v2 < v) for k2, (t2, v2) in ok.items() if k2 != k):
            front.append(k)
    return front


def front_points(df: pd.DataFrame, label: str, metric: str, names: MethodNames = REGISTERED,
                 x: str = "minutes") -> dict[str, tuple[float, float]]:
    """Per method at checkpoint `label`: (mean x, mean `metric`) over the scenes; x (FRONT_AXES): "minutes" (total
    training minutes, preprocessing + optimisation) or "gaussians" (the Gaussian count at the checkpoint)."""
    if x not in FRONT_AXES:
        raise ValueError(f"unknown front axis {x!r}; one of {', '.join(FRONT_AXES)}")
    sub = with_total_seconds(df[(df["label"] == label) & ~df["method"].map(names.is_ablation).astype(bool)])
    if sub.empty or metric not in sub or (x == "gaussians" and "gaussians" not in sub):
        return {}
    xs = sub["total_seconds"] / 60 if x == "minutes" else pd.to_numeric(sub["gaussians"], errors="coerce")
    sub = sub.assign(_v=pd.to_numeric(sub[metric], errors="coerce"), _x=xs)
    g = sub.groupby("method").agg(v=("_v", "mean"), m=("_x", "mean"))
    return {m: (float(g.loc[m, "m"]), float(g.loc[m, "v"])) for m in names.order(g.index)}


def fronts(df: pd.DataFrame, names: MethodNames = REGISTERED, x: str = "minutes") -> list[dict]:
    """The front of every checkpoint and FRONT_METRICS metric the run has against x (FRONT_AXES):
    {label, metric, x, points, front}."""
    out = []
    for label in main_labels(df):
        for metric in FRONT_METRICS:
            pts = front_points(df, label, metric, names, x)
            if any(not (math.isnan(v) or math.isnan(t)) for t, v in pts.values()):
                out.append({"label": label, "metric": metric, "x": x, "points": pts, "front": pareto_front(pts)})
    return out


def front_member(f: dict, m: str, names: MethodNames = REGISTERED, metric_name: bool = True) -> str:
    """'STRinGS (12.30 min, OCR-CER 0.327)' / 'STRinGS (31,200 Gaussians, 0.327)': one method of a front."""
    _what, unit, fmt = FRONT_AXES[f.get("x", "minutes")]
    value = f"{FRONT_METRICS[f['metric']]} " if metric_name else ""
    return f"{names.title(m)} ({fmt.format(f['points'][m][0])} {unit}, {value}{f['points'][m][1]:.3f})"


def front_lines(fr: list[dict], names: MethodNames = REGISTERED) -> list[str]:
    """The fronts as Markdown lines (the report lists them)."""
    lines = []
    for f in fr:
        members = ", ".join(front_member(f, m, names) for m in f["front"])
        what = FRONT_AXES[f.get("x", "minutes")][0]
        lines.append(f"- {f['label']}, {FRONT_METRICS[f['metric']]} vs {what}: {members or 'none'}")
    return lines


# ---- the report's part ---------------------------------------------------------------------------------------------
@dataclass
class Analysis:
    """The readability part of a report: its tables, the speed/accuracy fronts, and the per-bin data."""

    tables: list[Table]
    fronts: list[dict]
    by_size: pd.DataFrame  # cer_by_size at `label`
    spread: pd.DataFrame
    label: str | None
    size_fronts: list[dict] = dataclasses.field(default_factory=list)  # CER against the Gaussian count


def analyse(run_dir: str | Path, df: pd.DataFrame, note: str = "", names: MethodNames = REGISTERED) -> Analysis:
    """The tables (CER by size and known-text CER by size at `size_label`, time to legibility) and the
    speed/accuracy fronts of a run."""
    if df.empty:
        return Analysis([], [], pd.DataFrame(), pd.DataFrame(), None)
    label = size_label(df)
    words = load_words(run_dir, df)
    by_size = cer_by_size(words, label, names=names)
    tables: list[Table] = []
    for known in (False, True):
        t = size_table(cer_by_size(words, label, known=True, names=names) if known else by_size, label, known, note, names)
        if t is not None:
            tables.append(t)
    t = legibility_table(legibility(df), note, names)
    if t is not None:
        tables.append(t)
    for t in tables:
        t.names = names
    return Analysis(tables, fronts(df, names), by_size, size_spread(by_size), label, fronts(df, names, "gaussians"))


def fronts_csv(fr: list[dict]) -> str:
    """The fronts as CSV: label, metric, method, the x column ("minutes" or "gaussians", FRONT_AXES), value, on_front."""
    x = fr[0].get("x", "minutes") if fr else "minutes"
    rows = [{"label": f["label"], "metric": f["metric"], "method": m, x: t, "value": v,
             "on_front": m in f["front"]} for f in fr for m, (t, v) in f["points"].items()]
    return pd.DataFrame(rows, columns=["label", "metric", "method", x, "value", "on_front"]).to_csv(index=False)


def write_fronts(fr: list[dict], path: Path) -> Path:
    return atomic_write_text(path, fronts_csv(fr))


__all__ = ["HEIGHT_BINS", "MIN_BIN_WORDS", "THRESHOLDS", "Crossing", "analyse", "cer_by_size", "fronts", "legibility",
           "load_words", "pareto_front", "size_bin", "time_to_threshold"]
