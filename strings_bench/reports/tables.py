"""The paper's tables of a run: which tables a report has and what each holds (`build_tables`), written as LaTeX,
Markdown and CSV (`write_tables`). The table model and its renderers are table_model.py, the aggregation
aggregate.py, the OCR-agreement statistics ocr_agreement.py, the ablation table ablations.py.

Every dataset figure is the mean over its scenes (OCR-CER: over the scenes where anything could be
scored, as the authors do). Checkpoint columns are labelled by the paper iteration they stand for
("7K", "30K"); the iterations actually trained are given in the caption. Missing values print as
"n/a" (never 0).
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from strings_bench.core.io import atomic_write_text
from strings_bench.reports.ablations import ablation_table
from strings_bench.reports.aggregate import cer_per_script, dataset_means, main_labels, with_total_seconds
from strings_bench.reports.ocr_agreement import ocr_engine_tables
from strings_bench.reports.table_model import (GT_CEILING, PREAMBLE, RANK_NOTE, REGISTERED, Column, MethodNames, Table,
                                               dataset_title, label_value, latex_escape)


# ---- the paper's tables ------------------------------------------------------------------------------
def _checkpoint_table(df, name, value, corner, corner_plain, caption, lower, fmt, scale=1.0, methods=None,
                      ceiling: str | None = None, names: MethodNames = REGISTERED) -> Table:
    """A value per method x (dataset, checkpoint); `ceiling` names a column whose mean becomes an
    unranked GT-ceiling row (e.g. word_cer_gt)."""
    means = dataset_means(df, value)
    ceil = dataset_means(df, ceiling) if ceiling else None
    labels = main_labels(df)
    datasets = list(dict.fromkeys(df["dataset"]))
    methods = methods or names.order(m for m in df["method"] if not names.is_ablation(m))
    cols = []
    for d in datasets:
        for l in labels:
            sel = means[(means["dataset"] == d) & (means["label"] == l)]
            vals = {r.method: (getattr(r, value) * scale) for r in sel.itertuples()}
            if ceil is not None:
                # The GT side does not depend on the method: any method's cells give it (mean over them).
                c = ceil[(ceil["dataset"] == d) & (ceil["label"] == l)][ceiling]
                vals[GT_CEILING] = float(c.mean()) if c.notna().any() else math.nan
            cols.append(Column(dataset_title(d), l, l, lower, fmt, vals))
    if ceiling:
        methods = [*methods, GT_CEILING]
    return Table(name, corner, corner_plain, cols, methods, caption)


def schedule_note(df: pd.DataFrame, manifest: dict | None) -> str:
    if df.empty:
        return ""
    pairs = sorted({(l, int(i)) for l, i in zip(df["label"], df["iteration"])}, key=lambda p: label_value(p[0]))
    shown = [f"{l} = {i} iterations" for l, i in pairs if str(i) != l and label_value(l) != i]
    schedule = (manifest or {}).get("schedule", {})
    if not shown:
        return ""
    return (f" Checkpoints are labelled by the paper iteration they stand for; this run (schedule "
            f"{latex_escape(schedule.get('name', '?'))}, steps scale {schedule.get('steps_scale', '?')}) trained "
            + "; ".join(shown) + ".")


def build_tables(df: pd.DataFrame, manifest: dict | None = None) -> list[Table]:
    """The report's tables; methods are named as run.json (`manifest`) recorded them, then as their specs do."""
    if df.empty:
        return []
    names = MethodNames.of(manifest)
    df = with_total_seconds(df)
    note = schedule_note(df, manifest)
    tables = [
        _checkpoint_table(df, "ocr_cer", "cer", r"OCR-CER $\downarrow$", "OCR-CER (lower is better)",
                          "OCR-based character error rate (CER, lower is better) of rendered test views, mean over the "
                          "scenes of each dataset." + RANK_NOTE + note, True, ".3f", names=names),
        _checkpoint_table(df, "training_time", "total_seconds", r"\makecell[l]{Training time\\(minutes) $\downarrow$}",
                          "Training time, minutes, preprocessing + optimisation (lower is better)",
                          "Training time in minutes, whole run: preprocessing (text masks, 3D text segmentation, "
                          "initial model and text densification where the method has them) plus optimisation "
                          "(results.csv: total_seconds = preprocess_seconds + train_seconds), mean over the scenes "
                          "of each dataset." + RANK_NOTE + note, True,
                          ".2f" if (df["total_seconds"].max() / 60) < 10 else ".1f", 1 / 60, names=names),
    ]
    if df["cer_known"].notna().any():
        tables.append(_checkpoint_table(
            df, "known_text_cer", "cer_known", r"\makecell[l]{Known-text\\CER $\downarrow$}", "Known-text CER (lower is better)",
            "CER of the OCR of rendered views against the known strings of the scene (synthetic scenes only)."
            + RANK_NOTE + note, True, ".3f", names=names))
    if "word_cer" in df and df["word_cer"].notna().any():
        tables += readability_tables(df, note, names)
    tables += ocr_engine_tables(df, manifest, note, names)
    tables += script_tables(df, note, names)
    tables.append(metrics_table(df, note, names))
    paper = paper_comparison_table(df, note, names)
    if paper is not None:
        tables.append(paper)
    abl = ablation_table(df, note, names)
    if abl is not None:
        tables.append(abl)
    for t in tables:
        t.names = names  # the rows are titled as this run names its methods
    return tables


# ---- text in several scripts -------------------------------------------------------------------------------
def script_tables(df: pd.DataFrame, note: str = "", names: MethodNames = REGISTERED) -> list[Table]:
    """When the run's scenes are in more than one script (results.csv `script`): OCR-CER, and known-text CER
    where there is one, per script x checkpoint, mean over the scenes of that script; [] otherwise."""
    if "script" not in df or df["script"].isna().all():
        return []
    main = df["script"].fillna("").astype(str).str.split("+").str[0]
    scripts = [s for s in dict.fromkeys(main) if s]
    if len(scripts) < 2:
        return []
    rows = df.assign(script=main).to_dict("records")
    labels = main_labels(df)
    methods = names.order(m for m in df["method"] if not names.is_ablation(m))
    out = []
    for value, name, corner, what in (("cer", "ocr_cer_by_script", "OCR-CER by script (lower is better)", "OCR-CER"),
                                      ("cer_known", "known_cer_by_script", "Known-text CER by script (lower is better)",
                                       "known-text CER")):
        if value not in df or df[value].isna().all():
            continue
        per = cer_per_script(rows, value)
        cols = []
        for sc in scripts:
            for l in labels:
                vals = {r["method"]: r[value] for r in per if r["script"] == sc and r["label"] == l}
                n = max([r["scenes"] for r in per if r["script"] == sc and r["label"] == l] or [0])
                cols.append(Column(f"{sc} ({n} scene{'s' if n != 1 else ''})", l, l, True, ".3f", vals))
        out.append(Table(name, corner.replace("(lower is better)", r"$\downarrow$"), corner, cols, methods,
                         f"{what} per script of the scenes' text (results.csv `script`: from the known words, else the GT "
                         "OCR), mean over the scenes in that script across datasets." + RANK_NOTE + note))
    return out



def paper_results(method: str) -> dict:
    """The published figures of a method's spec ({dataset: {"cer": {iteration: v}, ...}}), {} if none."""
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.methods.registry import get_method

    try:
        return get_method(method).paper_results or {}
    except StringsBenchError:  # a method of an old run folder that is no longer registered
        return {}


def paper_comparison_table(df: pd.DataFrame, note: str = "", names: MethodNames = REGISTERED) -> Table | None:
    """Measured OCR-CER next to the paper's (docs/sources.md §5) for the datasets the paper reports; None when
    the run has no such dataset (e.g. the synthetic scenes)."""
    means = dataset_means(df, "cer")
    methods = names.order(m for m in df["method"] if not names.is_ablation(m))
    published = {m: paper_results(m) for m in methods}
    cols = []
    for d in dict.fromkeys(df["dataset"]):
        for label in main_labels(df):
            paper_vals = {m: published[m].get(d, {}).get("cer", {}).get(int(label_value(label))) for m in methods}
            paper_vals = {m: v for m, v in paper_vals.items() if v is not None}
            if not paper_vals:
                continue
            sel = means[(means["dataset"] == d) & (means["label"] == label)]
            cols.append(Column(dataset_title(d), f"{label} ours", f"{label} measured", True, ".3f",
                               {r.method: r.cer for r in sel.itertuples()}))
            cols.append(Column(dataset_title(d), f"{label} paper", f"{label} paper", True, ".3f", paper_vals))
    if not cols:
        return None
    return Table("paper_comparison", r"OCR-CER $\downarrow$", "OCR-CER, measured and published",
                 cols, methods, "OCR-CER measured in this run next to the figures published in the STRinGS paper "
                 "(RTX 3090 Ti, Google Cloud Vision OCR; the paper's Tables 1 and 2), mean over the scenes of each "
                 "dataset. The paper's scenes, OCR engine and schedule may differ from this run's." + RANK_NOTE + note)


READ_NOTE = (" Reference words: the known words at least 6.5 px high and the words the GT view's OCR read; each "
             "is rectified from the render and read by the recogniser alone (docs/ocr.md). The last row reads the "
             "ground-truth views (the ceiling).")


def readability_tables(df: pd.DataFrame, note: str = "", names: MethodNames = REGISTERED) -> list[Table]:
    """Word-crop readability per checkpoint (word_cer, text_nll, each with the GT ceiling row) and the
    text-region table (word_acc, text PSNR/SSIM/LPIPS inside the dilated text mask) at the last checkpoint."""
    out = [
        _checkpoint_table(df, "word_cer", "word_cer", r"Word CER $\downarrow$", "Word CER (lower is better)",
                          "Word-crop CER: edit distance of what the recogniser reads in each reference word's crop, "
                          "over the reference characters, mean over the scenes of each dataset." + READ_NOTE
                          + RANK_NOTE + note, True, ".3f", ceiling="word_cer_gt", names=names),
        _checkpoint_table(df, "text_nll", "text_nll", r"\makecell[l]{Text NLL\\(nats/char) $\downarrow$}",
                          "Text NLL, nats per character (lower is better)",
                          "Text likelihood: CTC negative log-likelihood of each reference word under the recogniser's "
                          "output on its crop, nats per reference character, mean over the scenes of each dataset."
                          + READ_NOTE + RANK_NOTE + note, True, ".3f", ceiling="text_nll_gt", names=names),
    ]
    labels = main_labels(df)
    final = labels[-1]
    sub = df[(df["label"] == final) & ~df["method"].map(names.is_ablation).astype(bool)]
    specs = [("word_acc", r"Words$\uparrow$", "Words read", False, ".3f"),
             ("text_psnr", r"PSNR$\uparrow$", "text PSNR", False, ".2f"),
             ("text_ssim", r"SSIM$\uparrow$", "text SSIM", False, ".4f"),
             ("text_lpips", r"LPIPS$\downarrow$", "text LPIPS", True, ".4f")]
    cols = []
    for d in dict.fromkeys(df["dataset"]):
        for value, sub_l, sub_p, lower, fmt in specs:
            if value not in sub:
                continue
            means = dataset_means(sub[sub["dataset"] == d], value)
            cols.append(Column(dataset_title(d), sub_l, sub_p, lower, fmt, {r.method: getattr(r, value) for r in means.itertuples()}))
    out.append(Table("text_region", "Method", "Method", cols, names.order(sub["method"]),
                     f"Text regions at {final} iterations: fraction of reference words read exactly (Words), and PSNR "
                     "over the dilated text mask's pixels, the SSIM map's mean over them, LPIPS-VGG of the mask's "
                     "bounding crop; mean over the scenes of each dataset." + RANK_NOTE + note, heading="Text-region image metrics"))
    return out


def metrics_table(df: pd.DataFrame, note: str = "", names: MethodNames = REGISTERED) -> Table:
    labels = main_labels(df)
    final = labels[-1]
    sub = df[(df["label"] == final) & ~df["method"].map(names.is_ablation).astype(bool)]
    datasets = list(dict.fromkeys(df["dataset"]))
    methods = names.order(sub["method"])
    specs = [("psnr", r"PSNR$\uparrow$", "PSNR", False, ".2f"), ("ssim", r"SSIM$\uparrow$", "SSIM", False, ".4f"),
             ("lpips", r"LPIPS$\downarrow$", "LPIPS", True, ".4f"), ("gaussians", r"Points$\downarrow$", "Points", True, "K")]
    cols = []
    for d in datasets:
        for value, sub_l, sub_p, lower, fmt in specs:
            means = dataset_means(sub[sub["dataset"] == d], value)
            cols.append(Column(dataset_title(d), sub_l, sub_p, lower, fmt, {r.method: getattr(r, value) for r in means.itertuples()}))
    return Table("metrics", "Method", "Method", cols, methods,
                 f"Reconstruction quality and number of Gaussians (Points) at {final} iterations, mean over the scenes "
                 "of each dataset. LPIPS is LPIPS-VGG v0.1; n/a where its weights are not installed." + RANK_NOTE + note, heading="Image metrics")



def write_tables(df: pd.DataFrame, out_dir: Path, manifest: dict | None = None,
                 extra: list[Table] | None = None) -> dict[str, dict[str, Path]]:
    """Write every table (build_tables', then `extra`) as .tex, .md and .csv, plus preamble.tex and a compilable
    tables.tex."""
    out_dir.mkdir(parents=True, exist_ok=True)
    papers = {m: v.get("paper", "") for m, v in ((manifest or {}).get("methods") or {}).items()}
    written: dict[str, dict[str, Path]] = {}
    for t in build_tables(df, manifest) + list(extra or []):
        tex, md, csv_text = t.latex(papers), t.markdown(), t.csv()
        written[t.name] = {
            "title": t.title,
            "tex": atomic_write_text(out_dir / f"{t.name}.tex", tex),
            "md": atomic_write_text(out_dir / f"{t.name}.md", md),
            "csv": atomic_write_text(out_dir / f"{t.name}.csv", csv_text),
        }
    atomic_write_text(out_dir / "preamble.tex", PREAMBLE)
    doc = [r"\documentclass{article}", r"\usepackage[margin=1.5cm]{geometry}", r"\input{preamble}", r"\begin{document}"]
    doc += [r"\input{%s}" % name for name in written]
    doc.append(r"\end{document}")
    atomic_write_text(out_dir / "tables.tex", "\n".join(doc) + "\n")
    return written

