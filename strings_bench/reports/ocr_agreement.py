"""A second OCR opinion (`run --ocr rapidocr,tesseract`): each engine's OCR-CER per method, and the engines'
agreement per cell group (Spearman across methods, words read identically)."""

from __future__ import annotations

import math

import pandas as pd

from strings_bench.reports.aggregate import dataset_means, main_labels
from strings_bench.reports.table_model import (RANK_NOTE, REGISTERED, Column, MethodNames, Table, dataset_title,
                                               latex_escape)


def further_engines(df: pd.DataFrame) -> list[str]:
    """The further OCR engines of a run (results.csv has agree_words_<engine> for each), in column order."""
    prefix = "agree_words_"
    return [c[len(prefix):] for c in df.columns if c.startswith(prefix)]


def primary_engine(df: pd.DataFrame, manifest: dict | None = None) -> str:
    """The primary OCR engine: the first of run.json's `ocr`, else results.csv's ocr_backend."""
    ocr = str((manifest or {}).get("ocr") or "")
    if ocr:
        return ocr.split(",")[0]
    names = df["ocr_backend"].dropna().astype(str) if "ocr_backend" in df else pd.Series(dtype=str)
    return names.mode().iloc[0] if len(names) else "primary"


def _spearman(x: pd.Series, y: pd.Series) -> float:
    """Spearman's rank correlation of paired values (ties: average ranks); NaN with fewer than 2 pairs
    or when either side is constant (no ranking to compare)."""
    from scipy.stats import spearmanr

    ok = x.notna() & y.notna()
    x, y = x[ok].astype(float), y[ok].astype(float)
    if len(x) < 2 or x.nunique() < 2 or y.nunique() < 2:
        return math.nan
    return float(spearmanr(x.to_numpy(), y.to_numpy()).statistic)


def ocr_agreement(df: pd.DataFrame) -> pd.DataFrame:
    """The two engines' agreement per cell group (dataset, scene, checkpoint label) and further engine.

    Columns: dataset, scene, label, engine, methods (methods with both CERs), spearman (rank correlation
    across those methods of the primary's `cer` and the engine's `cer_<engine>`; NaN below 2 methods or
    when either is constant), words / identical / share (text regions on the methods' render views and
    those both engines read identically, summed over the group's methods; `cer.word_agreement`), and
    gt_words / gt_identical / gt_share (the same on the GT views, which every method of a group shares:
    taken from one of its cells)."""
    cols = ["dataset", "scene", "label", "engine", "methods", "spearman", "words", "identical", "share",
            "gt_words", "gt_identical", "gt_share"]
    rows = []
    if df.empty:
        return pd.DataFrame(columns=cols)
    for engine in further_engines(df):
        for (dataset, scene, label), g in df.groupby(["dataset", "scene", "label"], sort=False):
            g = g[g[f"agree_words_{engine}"].notna()]
            if g.empty:
                continue
            both = g["cer"].notna() & g[f"cer_{engine}"].notna()
            words, identical = int(g[f"agree_words_{engine}"].sum()), int(g[f"agree_identical_{engine}"].sum())
            gt = g.iloc[0]
            gt_words, gt_identical = gt[f"agree_gt_words_{engine}"], gt[f"agree_gt_identical_{engine}"]
            rows.append({"dataset": dataset, "scene": scene, "label": label, "engine": engine,
                         "methods": int(both.sum()), "spearman": _spearman(g["cer"], g[f"cer_{engine}"]),
                         "words": words, "identical": identical, "share": identical / words if words else math.nan,
                         "gt_words": gt_words, "gt_identical": gt_identical,
                         "gt_share": gt_identical / gt_words if gt_words else math.nan})
    return pd.DataFrame(rows, columns=cols)


AGREEMENT_NOTE = (" Words are text regions: the words of both engines joined where their polygons overlap with IoU "
                  ">= 0.1, as the CER matches words; a region is read identically when both engines' texts there, "
                  "normalised as for the CER and concatenated in reading order, are equal (docs/ocr.md).")


def ocr_engine_tables(df: pd.DataFrame, manifest: dict | None = None, note: str = "",
                      names: MethodNames = REGISTERED) -> list[Table]:
    """With further OCR engines: each engine's OCR-CER per method x (dataset, checkpoint), and their
    agreement per cell group (`ocr_agreement`); [] for a single-engine run."""
    engines = further_engines(df)
    if not engines:
        return []
    primary = primary_engine(df, manifest)
    labels = main_labels(df)
    methods = names.order(m for m in df["method"] if not names.is_ablation(m))
    cols = []
    for d in dict.fromkeys(df["dataset"]):
        for l in labels:
            for engine, value in [(primary, "cer"), *[(e, f"cer_{e}") for e in engines]]:
                means = dataset_means(df, value)
                sel = means[(means["dataset"] == d) & (means["label"] == l)]
                cols.append(Column(dataset_title(d), f"{l} {latex_escape(engine)}", f"{l} {engine}", True, ".3f",
                                   {r.method: getattr(r, value) for r in sel.itertuples()}))
    by_engine = Table("ocr_cer_by_engine", r"OCR-CER $\downarrow$", "OCR-CER by engine (lower is better)", cols, methods,
                      f"OCR-CER of each OCR engine (the first, {latex_escape(primary)}, is the primary engine of the other "
                      "tables), mean over the scenes of each dataset; each engine reads the GT and the render views "
                      "itself." + RANK_NOTE + note)
    agree = ocr_agreement(df)
    keys, cols = [], []
    for engine in engines:
        sub = agree[agree["engine"] == engine]
        group = f"{primary} vs {engine}"
        values: dict[str, dict] = {"spearman": {}, "methods": {}, "share": {}, "gt_share": {}}
        for r in sub.itertuples():
            key = f"{r.dataset}/{r.scene} @{r.label}"
            if key not in keys:
                keys.append(key)
            for v in values:
                values[v][key] = getattr(r, v)
        cols += [Column(group, r"Spearman $\rho$", "Spearman rho", False, ".2f", values["spearman"]),
                 Column(group, "methods", "methods", False, ".0f", values["methods"]),
                 Column(group, "same words (renders)", "same words (renders)", False, ".3f", values["share"]),
                 Column(group, "same words (GT)", "same words (GT)", False, ".3f", values["gt_share"])]
    agreement = Table("ocr_agreement", "Cell group", "Cell group (dataset/scene @checkpoint)", cols, keys,
                      "Agreement of the OCR engines per cell group: Spearman's rank correlation across methods of the "
                      "primary engine's OCR-CER and the other engine's (n/a below 2 methods or when either engine "
                      "gives every method the same CER), and the share of words both engines read identically on "
                      "the methods' render views and on the GT views." + AGREEMENT_NOTE + note,
                      shade=False, row_key="cell_group", heading="Agreement of the OCR engines")
    return [by_engine, agreement]

