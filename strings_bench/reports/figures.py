"""Figures of a run (matplotlib, Agg): the teaser's CER-vs-time scatter, CER over iterations, and a
qualitative grid of text crops with the OCR strings under each crop."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from strings_bench.reports.readability_analysis import (HEIGHT_BINS, MIN_BIN_WORDS, THRESHOLDS, cer_by_size, load_words,
                                                        pareto_front, size_label)
from strings_bench.reports.aggregate import main_labels, with_total_seconds
from strings_bench.reports.table_model import GT_CEILING, REGISTERED, MethodNames, dataset_title
from strings_bench.store import read_cell, render_file_name
from strings_bench.core.io import atomic_write
from strings_bench.core.results import CellKey, safe_name

CROP_PAD = 0.25  # fraction of the text box added on every side of a crop

# Metrics that the scatter and over-iterations plots can show (results.csv columns): axis name, whether
# lower is better, and whether the axis is a rate that starts at 0 and shows at least up to 1.
METRICS: dict[str, tuple[str, bool, bool]] = {
    "cer": ("OCR-CER", True, True), "cer_known": ("known-text CER", True, True),
    "word_cer": ("word CER", True, True), "word_acc": ("words read exactly", False, True),
    "text_nll": ("text NLL (nats/char)", True, False), "text_psnr": ("text PSNR (dB)", False, False),
    "text_ssim": ("text SSIM", False, False), "text_lpips": ("text LPIPS", True, False),
    "psnr": ("PSNR (dB)", False, False), "ssim": ("SSIM", False, False), "lpips": ("LPIPS", True, False),
}
DEFAULT_METRICS = ("cer", "word_cer", "text_nll")  # plotted by default (each when the run has it)
SIZE_FRONT_METRICS = ("cer", "cer_known", "word_cer")  # also plotted against the Gaussian count (of those plotted)


def check_metric(metric: str) -> None:
    from strings_bench.core.errors import StringsBenchError

    if metric not in METRICS:
        raise StringsBenchError(f"unknown metric {metric!r} for the figures", hint=f"one of: {', '.join(METRICS)}")


def _has(df: pd.DataFrame, metric: str) -> bool:
    return metric in df and pd.to_numeric(df[metric], errors="coerce").notna().any()


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    # OCR of blurred renders sometimes returns CJK glyphs the default font lacks; they show as boxes.
    warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from font", category=UserWarning)

    return plt


def _save(fig, path: Path) -> Path:
    def write(tmp: Path) -> None:
        fig.savefig(tmp, format=path.suffix.lstrip("."), dpi=150, bbox_inches="tight")

    atomic_write(path, write)
    _plt().close(fig)
    return path


def _colors(methods: list[str]) -> dict[str, tuple]:
    plt = _plt()
    cmap = plt.get_cmap("tab10")
    return {m: cmap(i % 10) for i, m in enumerate(methods)}


def cer_vs_time(df: pd.DataFrame, out: Path, label: str | None = None, names: MethodNames = REGISTERED) -> Path | None:
    """Teaser scatter of OCR-CER (see `metric_vs_time`)."""
    return metric_vs_time(df, out, label, "cer", names)


def metric_vs_gaussians(df: pd.DataFrame, out: Path, label: str | None = None, metric: str = "cer",
                        names: MethodNames = REGISTERED) -> Path | None:
    """A metric's mean over all scenes against the mean Gaussian count at one checkpoint, with the size/accuracy
    front circled (`metric_vs_time`'s figure with the count on x)."""
    return metric_vs_time(df, out, label, metric, names, x="gaussians")


def metric_vs_time(df: pd.DataFrame, out: Path, label: str | None = None, metric: str = "cer",
                   names: MethodNames = REGISTERED, x: str = "minutes") -> Path | None:
    """Teaser scatter: a metric's mean over all scenes against mean whole-run training minutes
    (total_seconds = preprocessing + optimisation) at one checkpoint; x="gaussians": against the mean Gaussian
    count instead (`metric_vs_gaussians`)."""
    check_metric(metric)
    if df.empty or not _has(df, metric) or (x == "gaussians" and not _has(df, "gaussians")):
        return None
    name, lower, rate = METRICS[metric]
    label = label or main_labels(df)[0]
    sub = with_total_seconds(df[df["label"] == label])
    if sub.empty:
        return None
    xs = sub["total_seconds"] / 60 if x == "minutes" else pd.to_numeric(sub["gaussians"], errors="coerce")
    sub = sub.assign(_v=pd.to_numeric(sub[metric], errors="coerce"), _x=xs)
    g = sub.groupby("method").agg(v=("_v", "mean"), along=("_x", "mean")).reset_index()  # along: minutes or count
    g = g.dropna(subset=["along"])
    if g.empty:
        return None
    plt = _plt()
    methods = names.order(g["method"])
    colors = _colors(methods)
    fig, ax = plt.subplots(figsize=(4.8, 3.6))
    # The front: the methods no other beats on both the x axis (time or Gaussian count) and the metric (circled).
    sign = 1 if lower else -1
    front = pareto_front({r.method: (r.along, sign * r.v) for r in g.itertuples()})
    fr = g[g["method"].isin(front)].sort_values("along")
    if len(fr):
        ax.scatter(fr["along"], fr["v"], s=260, facecolors="none", edgecolors="k", linewidths=1.0, zorder=4,
                   label="Pareto front")
        ax.step(fr["along"], fr["v"], where="post", color="k", linewidth=0.8, linestyle=":", zorder=2)
    for r in g.itertuples():
        y = r.v if not math.isnan(r.v) else np.nan
        ax.scatter([r.along], [y], s=90 if r.method == "strings" else 60, color=colors[r.method],
                   marker="*" if r.method == "strings" else "o", zorder=3, label=names.title(r.method))
        if not math.isnan(y):
            ax.annotate(names.title(r.method), (r.along, y), textcoords="offset points", xytext=(6, 4), fontsize=8)
    if x == "minutes":
        ax.set_xlabel(f"training time at {label}, preprocessing + optimisation (minutes)", fontsize=8)
    else:
        ax.set_xlabel(f"Gaussians at {label} (mean over the scenes)", fontsize=8)
    ax.set_ylabel(f"{name} at {label} ({'lower' if lower else 'higher'} is better)", fontsize=8)
    if rate:
        _cer_axis(ax, g["v"])
    ax.grid(True, alpha=0.3)
    what = "training time" if x == "minutes" else "Gaussian count"
    ax.set_title(f"Readability vs {what} ({label})" if metric == "cer" else f"{name} vs {what} ({label})",
                 fontsize=10)
    if len(fr):
        ax.legend(handles=[ax.collections[0]], labels=["Pareto front (circled)"], fontsize=7, loc="best")
    return _save(fig, out)


def _cer_axis(ax, values) -> None:
    """CER axes start at 0 and show at least up to 1, so that 0.996 vs 1.0 does not look like a gap."""
    top = np.nanmax(np.asarray(values, dtype=float)) if len(values) else np.nan
    ax.set_ylim(0.0, max(1.02, float(top) * 1.02) if np.isfinite(top) else 1.02)


def cer_over_iterations(df: pd.DataFrame, out: Path, names: MethodNames = REGISTERED) -> Path | None:
    """OCR-CER over iterations (see `metric_over_iterations`)."""
    return metric_over_iterations(df, out, "cer", names)


def metric_over_iterations(df: pd.DataFrame, out: Path, metric: str = "cer",
                           names: MethodNames = REGISTERED) -> Path | None:
    """A metric against the trained iteration: one panel per scene plus the mean over scenes."""
    check_metric(metric)
    if df.empty or not _has(df, metric):
        return None
    name, _lower, rate = METRICS[metric]
    df = df.assign(**{metric: pd.to_numeric(df[metric], errors="coerce")})
    plt = _plt()
    scenes = list(dict.fromkeys(zip(df["dataset"], df["scene"])))
    methods = names.order(df["method"])
    colors = _colors(methods)
    n = len(scenes) + (1 if len(scenes) > 1 else 0)
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), squeeze=False)
    panels = [(f"{d}/{s}", df[(df["dataset"] == d) & (df["scene"] == s)]) for d, s in scenes]
    if len(scenes) > 1:
        mean = df.groupby(["method", "iteration"], as_index=False)[metric].mean()
        panels.append(("mean over scenes", mean))
    for ax, (title, sub) in zip(axes.flat, panels):
        for m in methods:
            s = sub[sub["method"] == m].sort_values("iteration").dropna(subset=[metric])  # dense checkpoints have no OCR-CER
            if s.empty:
                continue
            ax.plot(s["iteration"], s[metric], marker="o", color=colors[m], label=names.title(m),
                    linestyle="--" if names.is_ablation(m) else "-")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("iteration")
        ax.set_ylabel(name)
        if rate:
            _cer_axis(ax, sub[metric])
        ax.grid(True, alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), fontsize=8, bbox_to_anchor=(0.5, -0.02))
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return _save(fig, out)


# ---- readability analysis (reports/readability_analysis.py) ---------------------------------------
def size_figure(by_size: pd.DataFrame, label: str, out: Path, names: MethodNames = REGISTERED) -> Path | None:
    """Word CER per height bin, one line per method and a dashed GT ceiling, one panel per dataset; greyed bins
    have a grey background."""
    if by_size.empty or not (by_size["words"] > 0).any():
        return None
    plt = _plt()
    datasets = list(dict.fromkeys(by_size["dataset"]))
    fig, axes = plt.subplots(1, len(datasets), figsize=(4.8 * len(datasets), 3.6), squeeze=False)
    for ax, d in zip(axes.flat, datasets):
        sub = by_size[(by_size["dataset"] == d) & (by_size["words"] > 0)]
        bins = [b for b, _lo, _hi in HEIGHT_BINS if b in set(sub["bin"])]
        x = {b: i for i, b in enumerate(bins)}
        for b in bins:
            if bool(sub[sub["bin"] == b]["greyed"].iloc[0]):
                ax.axvspan(x[b] - 0.5, x[b] + 0.5, color="0.85", zorder=0)
        methods = [m for m in names.order(sub["method"]) if m != GT_CEILING]
        colors = _colors(methods)
        for m in [*methods, GT_CEILING]:
            s = sub[sub["method"] == m]
            ax.plot([x[b] for b in s["bin"]], s["cer"], marker="o", color="k" if m == GT_CEILING else colors[m],
                    linestyle="--" if m == GT_CEILING else "-", label="GT view (ceiling)" if m == GT_CEILING else names.title(m))
        n = {r.bin: r.words for r in sub.drop_duplicates("bin").itertuples()}
        ax.set_xticks(range(len(bins)), [f"{b}\n(n={n[b]})" for b in bins], fontsize=7)
        ax.set_xlabel("word height (px at the evaluated resolution)", fontsize=8)
        ax.set_ylabel(f"word CER at {label}", fontsize=8)
        ax.set_ylim(0, 1.05)
        ax.set_title(dataset_title(d), fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"Word CER by text size (grey: fewer than {MIN_BIN_WORDS} words, not ranked)", fontsize=9)
    fig.tight_layout()
    return _save(fig, out)


def readability_vs_time(df: pd.DataFrame, out: Path, metric: str = "word_cer",
                        names: MethodNames = REGISTERED) -> Path | None:
    """A CER against training minutes, one line per method (a point per evaluated checkpoint), one panel per
    scene, with the THRESHOLDS as dotted lines: the paper's text-evolution figure, for any method and scene."""
    df = with_total_seconds(df)
    if df.empty or metric not in df or pd.to_numeric(df[metric], errors="coerce").isna().all():
        return None
    df = df.assign(_v=pd.to_numeric(df[metric], errors="coerce"), _min=df["total_seconds"] / 60)
    plt = _plt()
    scenes = list(dict.fromkeys(zip(df["dataset"], df["scene"])))
    cols = min(3, len(scenes))
    rows = math.ceil(len(scenes) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    methods = names.order(df["method"])
    colors = _colors(methods)
    for ax, (d, s) in zip(axes.flat, scenes):
        sub = df[(df["dataset"] == d) & (df["scene"] == s)]
        for m in methods:
            g = sub[sub["method"] == m].sort_values("iteration").dropna(subset=["_v", "_min"])
            if not g.empty:
                ax.plot(g["_min"], g["_v"], marker="o", ms=3, color=colors[m], label=names.title(m),
                        linestyle="--" if names.is_ablation(m) else "-")
        for thr in THRESHOLDS:
            ax.axhline(thr, color="0.5", linestyle=":", linewidth=0.8)
        ax.set_ylim(0, 1.05)
        ax.set_title(f"{d}/{s}", fontsize=9)
        ax.set_xlabel("training time, preprocessing + optimisation (minutes)", fontsize=7)
        ax.set_ylabel(METRICS[metric][0], fontsize=8)
        ax.grid(True, alpha=0.3)
    for ax in list(axes.flat)[len(scenes):]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), fontsize=8, bbox_to_anchor=(0.5, -0.03))
    fig.suptitle(f"{METRICS[metric][0]} against training time (dotted: thresholds {', '.join(f'{t:g}' for t in THRESHOLDS)})",
                 fontsize=9)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return _save(fig, out)


# ---- qualitative ---------------------------------------------------------------------------------
def _read_cell(run_dir: Path, method: str, dataset: str, scene: str, iteration: int) -> dict | None:
    return read_cell(run_dir, CellKey(method, dataset, scene, int(iteration)))


def _words_text(words: list | None) -> str:
    if words is None:
        return "(OCR failed)"
    if not words:
        return "(nothing read)"
    ordered = sorted(words, key=lambda w: (np.mean([p[1] for p in w["polygon"]]) // 20, np.mean([p[0] for p in w["polygon"]])))
    return " ".join(w["text"] for w in ordered)


def _in_box(words: list | None, box) -> list | None:
    if words is None:
        return None
    x0, y0, x1, y1 = box
    out = []
    for w in words:
        c = np.mean(np.asarray(w["polygon"], dtype=float), axis=0)
        if x0 <= c[0] <= x1 and y0 <= c[1] <= y1:
            out.append(w)
    return out


def _recognised(rec: dict | None, view: str, box, side: str) -> str:
    """What the recogniser alone read in the crop (word-crop readability), side "gt" or "render"; "" if none."""
    if not rec:
        return ""
    words = ((rec.get("readability") or {}).get("views") or {}).get(view)
    if not words:
        return ""
    inside = [w for w in _in_box([{"text": w["text"], "polygon": w["polygon"], "read": w[side]["read"]}
                                  for w in words if w.get("headline", True)], box) or []]
    if not inside:
        return ""
    ordered = sorted(inside, key=lambda w: (np.mean([p[1] for p in w["polygon"]]) // 20, np.mean([p[0] for p in w["polygon"]])))
    return "rec: " + " ".join(w["read"] or "∅" for w in ordered)


def _pick_view(rec: dict) -> tuple[str, list] | None:
    """The test view with the most text, and the word polygons to crop around (known words first)."""
    best = None
    for name, v in (rec.get("ocr") or {}).get("views", {}).items():
        words = v.get("known_words") or v.get("gt_words") or []
        chars = sum(len(w["text"]) for w in words)
        if words and (best is None or chars > best[0]):
            best = (chars, name, words)
    return None if best is None else (best[1], best[2])


def _crop_box(words: list, shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """Box around the first line of text (words whose centre is near the top-most word's), padded."""
    h, w = shape
    polys = [np.asarray(wd["polygon"], dtype=float) for wd in words]
    # Biggest word decides the line to show; crops stay readable on a page.
    areas = [np.ptp(p[:, 0]) * np.ptp(p[:, 1]) for p in polys]
    ref = polys[int(np.argmax(areas))]
    rc, rh = ref[:, 1].mean(), max(np.ptp(ref[:, 1]), 1.0)
    line = [p for p in polys if abs(p[:, 1].mean() - rc) < rh]
    pts = np.concatenate(line)
    x0, y0 = pts.min(0)
    x1, y1 = pts.max(0)
    pw, ph = (x1 - x0) * CROP_PAD + 4, (y1 - y0) * CROP_PAD * 2 + 4
    return (int(max(0, x0 - pw)), int(max(0, y0 - ph)), int(min(w, x1 + pw)), int(min(h, y1 + ph)))


def qualitative(df: pd.DataFrame, run_dir: Path, out: Path, label: str, max_scenes: int = 6,
                names: MethodNames = REGISTERED) -> Path | None:
    """Rows = scenes, columns = methods then ground truth (as the paper's comparison figures); under
    every crop, what OCR read in it and the view's OCR-CER."""
    from PIL import Image

    sub = df[df["label"] == label]
    if sub.empty:
        return None
    methods = names.order(m for m in sub["method"] if not names.is_ablation(m)) or names.order(sub["method"])
    scenes = list(dict.fromkeys(zip(sub["dataset"], sub["scene"])))[:max_scenes]
    rows = []
    for d, s in scenes:
        recs = {}
        for m in methods:
            r = sub[(sub["method"] == m) & (sub["dataset"] == d) & (sub["scene"] == s)]
            if len(r):
                recs[m] = _read_cell(run_dir, m, d, s, int(r["iteration"].iloc[0]))
        recs = {m: r for m, r in recs.items() if r is not None}
        if not recs:
            continue
        pick = _pick_view(next(iter(recs.values())))
        if pick is None:
            continue
        rows.append((d, s, pick, recs))
    if not rows:
        return None
    plt = _plt()
    ncols = len(methods) + 1
    fig, axes = plt.subplots(len(rows), ncols, figsize=(2.6 * ncols, 2.2 * len(rows)), squeeze=False)
    for ri, (d, s, (view, words), recs) in enumerate(rows):
        gt_path = run_dir / "gt" / safe_name(d) / safe_name(s) / render_file_name(view)
        gt = np.asarray(Image.open(gt_path).convert("RGB")) if gt_path.exists() else None
        shape = gt.shape[:2] if gt is not None else (10**6, 10**6)
        box = _crop_box(words, shape)
        x0, y0, x1, y1 = box
        any_rec = next(iter(recs.values()))
        for ci, m in enumerate(methods + ["__gt__"]):
            ax = axes[ri, ci]
            ax.set_xticks([])
            ax.set_yticks([])
            if m == "__gt__":
                img = gt
                v = any_rec["ocr"]["views"].get(view, {})
                caption = _words_text(_in_box(v.get("gt_words"), box))
                read = _recognised(any_rec, view, box, "gt")
                caption = caption[:40] + (f"\n{read[:40]}" if read else "")
                title = "Ground Truth"
            else:
                rec = recs.get(m)
                img, caption, title = None, "(not run)", names.title(m)
                if rec is not None:
                    p = CellKey(m, d, s, int(rec["iteration"])).path(run_dir) / "renders" / render_file_name(view)
                    img = np.asarray(Image.open(p).convert("RGB")) if p.exists() else None
                    v = rec["ocr"]["views"].get(view, {})
                    caption = _words_text(_in_box(v.get("render_words"), box))[:40]
                    read = _recognised(rec, view, box, "render")
                    caption += f"\n{read[:40]}" if read else ""
                    ic = (rec.get("cer") or {}).get("images", {}).get(view)
                    if ic and ic.get("cer") is not None:
                        caption += f"\nCER {ic['cer']:.2f}"
            if img is not None:
                ax.imshow(img[y0:y1, x0:x1])
            else:
                ax.axis("off")
            if ri == 0:
                ax.set_title(title, fontsize=9, fontweight="bold" if m == "strings" else "normal")
            if ci == 0:
                ax.set_ylabel(f"{s}\n{view}", fontsize=7)
            ax.set_xlabel(caption, fontsize=7)
    fig.suptitle(f"Text crops at {label}; under each crop: what OCR read there, and (rec:) what the recogniser "
                 "alone read in each reference word's crop", fontsize=9)
    fig.tight_layout()
    return _save(fig, out)


def write_figures(df: pd.DataFrame, run_dir: Path, out_dir: Path, metrics: list[str] | None = None,
                  names: MethodNames = REGISTERED) -> dict[str, Path]:
    """The scatter (per main checkpoint) and over-iterations plots of each metric in `metrics` (default:
    DEFAULT_METRICS that the run has; names: METRICS), and the qualitative grid. The OCR-CER files keep
    their names (cer_vs_time_<label>.png, cer_over_iterations.png); others are <metric>_vs_time_<label>.png ..."""
    for m in metrics or ():
        check_metric(m)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    if df.empty:
        return written
    chosen = list(metrics) if metrics else [m for m in DEFAULT_METRICS if _has(df, m)]
    for label in main_labels(df):
        for metric in chosen:
            p = metric_vs_time(df, out_dir / f"{metric}_vs_time_{label}.png", label, metric, names)
            if p:
                written[f"{metric}_vs_time_{label}"] = p
            if metric in SIZE_FRONT_METRICS:  # CER against the Gaussian count
                p = metric_vs_gaussians(df, out_dir / f"{metric}_vs_gaussians_{label}.png", label, metric, names)
                if p:
                    written[f"{metric}_vs_gaussians_{label}"] = p
        p = qualitative(df, run_dir, out_dir / f"qualitative_{label}.png", label, names=names)
        if p:
            written[f"qualitative_{label}"] = p
    for metric in chosen:
        p = metric_over_iterations(df, out_dir / f"{metric}_over_iterations.png", metric, names)
        if p:
            written[f"{metric}_over_iterations"] = p
    # The readability analysis: CER by text size at the last checkpoint, CER against training time.
    label = size_label(df)
    p = size_figure(cer_by_size(load_words(run_dir, df), label, names=names), label,
                    out_dir / f"word_cer_by_size_{label}.png", names)
    if p:
        written[f"word_cer_by_size_{label}"] = p
    for metric in [m for m in ("word_cer", "cer") if m in chosen]:
        p = readability_vs_time(df, out_dir / f"{metric}_vs_training_time.png", metric, names)
        if p:
            written[f"{metric}_vs_training_time"] = p
    return written
