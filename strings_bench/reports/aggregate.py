"""Aggregation of a run's results.csv for the tables: the cells read as a DataFrame, means over the scenes of a
dataset, the checkpoints the tables show."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import pandas as pd

from strings_bench.store import ENGINE_COLUMNS, FORMER_NAMES, READABILITY_COLUMNS
from strings_bench.reports.table_model import label_value


def load_results(run_dir: str | Path) -> pd.DataFrame:
    p = Path(run_dir) / "results.csv"
    if not p.exists():
        return pd.DataFrame()
    df = pd.read_csv(p, keep_default_na=True).rename(columns=FORMER_NAMES)  # a results.csv of an older version (FORMER_NAMES)
    for c in ("cer", "cer_known", "psnr", "ssim", "lpips", "train_seconds", "preprocess_seconds", "total_seconds",
              "gaussians", *READABILITY_COLUMNS):
        if c in df:
            df[c] = pd.to_numeric(df[c], errors="coerce")
    for c in df.columns:
        if any(c.startswith(col.format(engine="")) for col in ENGINE_COLUMNS):
            df[c] = pd.to_numeric(df[c], errors="coerce")
    df["label"] = df["label"].astype(str)
    return with_total_seconds(df)


def with_total_seconds(df: pd.DataFrame) -> pd.DataFrame:
    """`df` with a total_seconds column. Results from before the preprocess/total columns (a
    results.csv with no cells/ to rebuild it from) recorded no preprocess time: total = train there."""
    if "total_seconds" in df or "train_seconds" not in df:
        return df
    df = df.copy()
    pre = df["preprocess_seconds"].fillna(0.0) if "preprocess_seconds" in df else 0.0
    df["total_seconds"] = df["train_seconds"] + pre
    return df


def dataset_means(df: pd.DataFrame, value: str) -> pd.DataFrame:
    """Mean of `value` over scenes, per (method, dataset, label); NaN scenes are skipped, all-NaN stays NaN."""
    if df.empty:
        return pd.DataFrame(columns=["method", "dataset", "label", value, "n_scenes"])
    g = df.groupby(["method", "dataset", "label"], sort=False)[value]
    out = g.mean().rename(value).to_frame()  # pandas mean skips NaN
    out["n_scenes"] = g.count()
    return out.reset_index()



def common_scenes(df: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """The cells of the scenes every method has at its (dataset, checkpoint), and one line per method whose other
    cells are left out. A mean over different scenes would rank methods on different rooms (a run still under way,
    or scene draws trained for some methods only): the report's tables and figures average the common scenes. Where
    the methods share no scene, the cells stay and the line says their means are not comparable."""
    if df.empty or not {"method", "dataset", "label", "scene"} <= set(df.columns):
        return df, []
    keep = pd.Series(True, index=df.index)
    notes = []
    for (dataset, label), group in df.groupby(["dataset", "label"], sort=False):
        by_method = {m: set(g["scene"]) for m, g in group.groupby("method", sort=False)}
        common = set.intersection(*by_method.values())
        if not common:
            if len(by_method) > 1:
                notes.append(f"{dataset} {label}: no scene is common to every method; each method's mean is over "
                             "its own scenes (not comparable)")
            continue
        for m, scenes in by_method.items():
            extra = sorted(scenes - common)
            if extra:
                notes.append(f"{m} {dataset} {label}: {', '.join(extra)} left out of the means (not every method "
                             "has them yet)")
        keep &= ~(((df["dataset"] == dataset) & (df["label"] == label)) & ~df["scene"].isin(common))
    return df[keep], notes


def main_labels(df: pd.DataFrame) -> list[str]:
    """Checkpoint labels of the tables: every checkpoint the run evaluated fully, in order (the paper's layout
    has 7K and 30K; a run that also evaluated 3K shows it too). The dense checkpoints of `--checkpoints every:N`
    evaluated with the word-crop metrics only (results.csv `evaluation` = words) are not columns: they feed the
    time-to-legibility table and the curves."""
    if df.empty:
        return []
    full = df[df["evaluation"].fillna("full") != "words"] if "evaluation" in df else df
    return sorted(set((full if not full.empty else df)["label"]), key=label_value)


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
