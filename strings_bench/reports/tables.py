"""Tables of a run, laid out like the paper's: LaTeX (booktabs, best three shaded), Markdown, CSV.

Size (~660 lines): every paper table in its three layouts (LaTeX, Markdown, CSV), sharing the shading, n/a and caption rules.

Every dataset figure is the mean over its scenes (OCR-CER: over the scenes where anything could be
scored, as the authors do). Checkpoint columns are labelled by the paper iteration they stand for
("7K", "30K"); the iterations actually trained are given in the caption. Missing values print as
"n/a" (never 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from strings_bench.reports.results import ENGINE_COLUMNS, FORMER_NAMES, READABILITY_COLUMNS, cer_per_script, iteration_label
from strings_bench.core.io import atomic_write_text

# Paper colours (preamble of the paper).
PREAMBLE = r"""\usepackage{booktabs, multirow, xcolor, colortbl, array, makecell}
\definecolor{first}{RGB}{242, 182, 181}
\definecolor{second}{RGB}{249, 218, 184}
\definecolor{third}{RGB}{254, 250, 199}
\definecolor{gray}{RGB}{225, 225, 225}
\definecolor{confgray}{RGB}{128, 128, 128}
\providecommand{\papertable}[1]{{\tiny \color{confgray} {#1}}}
\newcolumntype{C}[1]{>{\centering\arraybackslash}m{#1}}
"""

DATASET_TITLES = {"tandt": "TandT", "dl3dv": "DL3DV-10K", "strings360": "STRinGS-360", "synthetic": "Synthetic"}
# A pseudo-method row: the recogniser on the ground-truth views (the ceiling of word_cer / text_nll); never ranked.
GT_CEILING = "gt-ceiling"
GT_CEILING_TITLE = "GT view (ceiling)"
_RUN_METHODS: dict[str, dict] = {}  # run.json's "methods" of the report being written: title, group, paper


def use_run_methods(manifest: dict | None) -> None:
    """Titles, groups and papers come from the run folder (run.json, written from the method specs when the
    run was planned); methods it does not describe (older folders) from the registered specs."""
    _RUN_METHODS.clear()
    _RUN_METHODS.update({m: dict(v) for m, v in ((manifest or {}).get("methods") or {}).items() if isinstance(v, dict)})


def method_info(method: str) -> dict:
    """{"title", "group", "order", "ablation_of", "ablation_at", "ablation_effect"} of a method: run.json's entry over
    its spec's; unknown methods get their name."""
    from strings_bench.methods.registry import list_methods

    specs = {s.name: (k, s) for k, s in enumerate(list_methods())}
    k, spec = specs.get(method, (len(specs), None))
    info = {"title": (spec.title or spec.name) if spec else method, "group": spec.group if spec else "baseline", "order": k,
            "ablation_of": spec.ablation_of if spec else None, "ablation_at": spec.ablation_at if spec else None,
            "ablation_effect": spec.ablation_effect if spec else ""}
    given = _RUN_METHODS.get(method, {})
    info.update({key: given[key] for key in ("title", "group", "ablation_of", "ablation_at", "ablation_effect")
                 if given.get(key)})
    return info


def is_ablation(method: str) -> bool:
    return method_info(method)["group"] == "ablation"


RANKS = ("first", "second", "third")


def latex_escape(s: str) -> str:
    rep = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
           "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}
    return "".join(rep.get(c, c) for c in str(s))


def label_value(label: str) -> float:
    """'7K' -> 7000, '350' -> 350 (for ordering columns)."""
    s = str(label)
    try:
        return float(s[:-1]) * 1000 if s.endswith("K") else float(s)
    except ValueError:
        return math.inf


def method_order(methods) -> list[str]:
    """Methods in the registry's order (the paper's rows), then any other by name."""
    ms = list(dict.fromkeys(methods))
    return sorted(ms, key=lambda m: (method_info(m)["order"], m))


def short_venue(paper: str) -> str:
    """'... Rendering (SIGGRAPH 2023)' -> "SIGGRAPH'23"; "CVPR'24" stays; '' when no venue/year is found."""
    import re

    paper = str(paper or "").strip()
    if re.fullmatch(r"[\w .-]+'\d\d", paper):
        return paper
    found = re.findall(r"\(([A-Za-z][\w .-]*?)\s+((?:19|20)\d\d)\)", paper)
    if not found:
        return ""
    venue, year = found[-1]
    return f"{venue.strip()}'{year[2:]}"


def method_title(method: str, papers: dict | None = None, latex: bool = False) -> str:
    title = GT_CEILING_TITLE if method == GT_CEILING else method_info(method)["title"]
    if not latex:
        return title
    t = latex_escape(title)
    if method != GT_CEILING and method_info(method)["group"] == "ours":
        t = r"\textbf{" + t + "}"
    paper = short_venue((papers or {}).get(method, ""))
    if paper and not is_ablation(method):
        t += r"~\papertable{" + latex_escape(paper) + "}"
    return t


def dataset_title(dataset: str) -> str:
    return DATASET_TITLES.get(dataset, dataset)


# ---- aggregation -------------------------------------------------------------------------------
def load_results(run_dir: str | Path) -> pd.DataFrame:
    p = Path(run_dir) / "results.csv"
    if not p.exists():
        return pd.DataFrame()
    df = pd.read_csv(p, keep_default_na=True).rename(columns=FORMER_NAMES)  # a results.csv from before issue 41
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


def rank_classes(values: list[float], lower_is_better: bool, decimals: int | None = None) -> list[str | None]:
    """'first'/'second'/'third' for the best three *distinct* values (ties share a place, as in the
    paper's tables); NaN never ranks. Values are compared as printed when `decimals` is given."""
    v = [x if x is not None and not (isinstance(x, float) and math.isnan(x)) else None for x in values]
    cmp = [None if x is None else (round(x, decimals) if decimals is not None else x) for x in v]
    distinct = sorted({x for x in cmp if x is not None}, reverse=not lower_is_better)
    place = {x: RANKS[i] for i, x in enumerate(distinct[:3])}
    return [None if x is None else place.get(x) for x in cmp]


# ---- generic table model ----------------------------------------------------------------------------
@dataclass
class Column:
    group: str  # dataset title (multicolumn header)
    sub: str  # e.g. "7K", "PSNR$\uparrow$"
    sub_plain: str
    lower_is_better: bool
    fmt: str  # format spec, e.g. ".3f"; "K" = thousands with a K suffix
    values: dict = field(default_factory=dict)  # method -> float
    greyed: bool = False  # shown greyed and never ranked (e.g. a text-size bin with too few words)
    na: str = "n/a"  # how a missing value reads (e.g. "not reached")
    prefix: dict = field(default_factory=dict)  # method -> text before its value (e.g. "<=" for an upper bound)
    suffix: dict = field(default_factory=dict)  # method -> text after its value (e.g. " (450)", the step)


@dataclass
class Table:
    name: str
    corner: str  # LaTeX of the top-left cell
    corner_plain: str
    columns: list[Column]
    methods: list[str]
    caption: str
    shade: bool = True
    bold_best_pairs: bool = False
    row_key: str = "method"  # what a row is (the CSV's first column): a method, or e.g. a cell group
    heading: str = ""  # the title where the plain corner is not one ("Method")

    @property
    def title(self) -> str:
        """The table's title as a person reads it: `heading`, else its plain corner ("OCR-CER (lower is better)")."""
        return self.heading or self.corner_plain or self.name.replace("_", " ")

    def fmt(self, col: Column, x, method: str | None = None) -> str:
        if x is None or (isinstance(x, float) and math.isnan(x)):
            return col.na
        if col.fmt == "K":
            return f"{x / 1000:.0f}K" if x >= 1000 else f"{x:.0f}"
        return col.prefix.get(method, "") + format(x, col.fmt) + col.suffix.get(method, "")

    def decimals(self, col: Column) -> int | None:
        if col.fmt == "K":
            return -3
        try:
            return int(col.fmt.strip(".f"))
        except ValueError:
            return None

    def shading(self, col: Column) -> dict[str, str | None]:
        vals = [col.values.get(m, math.nan) for m in self.methods]
        if not self.shade or col.greyed:
            return {m: None for m in self.methods}
        vals = [math.nan if m == GT_CEILING else v for m, v in zip(self.methods, vals)]
        return dict(zip(self.methods, rank_classes(vals, col.lower_is_better, self.decimals(col))))


def _groups(columns: list[Column]) -> list[tuple[str, int]]:
    out: list[tuple[str, int]] = []
    for c in columns:
        if out and out[-1][0] == c.group:
            out[-1] = (c.group, out[-1][1] + 1)
        else:
            out.append((c.group, 1))
    return out


def to_latex(t: Table, papers: dict | None = None) -> str:
    n = len(t.columns)
    lines = [r"\begin{table}[t]", r"\centering", r"\footnotesize", r"\tabcolsep=0.8mm",
             r"\begin{tabular}{l *{%d}{C{0.9cm}}}" % n, r"\toprule"]
    groups = _groups(t.columns)
    head = [r"\multirow{2}{*}{" + t.corner + "}"]
    rules = []
    col = 2
    for g, span in groups:
        head.append(r"\multicolumn{%d}{c}{\makecell{%s}}" % (span, latex_escape(g)))
        rules.append(r"\cmidrule(lr){%d-%d}" % (col, col + span - 1))
        col += span
    lines.append(" & ".join(head) + r" \\")
    lines.append(" ".join(rules))
    lines.append(" & " + " & ".join(c.sub for c in t.columns) + r" \\")
    lines.append(r"\midrule")
    shades = [t.shading(c) for c in t.columns]
    for m in t.methods:
        cells = [method_title(m, papers, latex=True)]
        for c, sh in zip(t.columns, shades):
            s = t.fmt(c, c.values.get(m, math.nan), m).replace("<=", r"$\leq$")
            cls = sh.get(m)
            if c.greyed:
                s = r"\textcolor{gray}{%s}" % s
            cells.append((r"\cellcolor{%s}" % cls if cls else "") + s)
        lines.append(" & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\caption{" + t.caption + "}", r"\label{tab:%s}" % t.name, r"\end{table}"]
    return "\n".join(lines) + "\n"


def to_markdown(t: Table) -> str:
    marks = {"first": " **(1)**", "second": " (2)", "third": " (3)"}
    header = [t.corner_plain] + [f"{c.group} {c.sub_plain}".strip() for c in t.columns]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    shades = [t.shading(c) for c in t.columns]
    for m in t.methods:
        cells = [method_title(m)]
        for c, sh in zip(t.columns, shades):
            v = t.fmt(c, c.values.get(m, math.nan), m)
            cells.append((f"_{v}_" if c.greyed else v) + marks.get(sh.get(m) or "", ""))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def to_csv(t: Table) -> str:
    rows = []
    for m in t.methods:
        row = {t.row_key: m}
        for c in t.columns:
            v = c.values.get(m, math.nan)
            row[f"{c.group} {c.sub_plain}".strip()] = "" if v is None or (isinstance(v, float) and math.isnan(v)) else v
        rows.append(row)
    return pd.DataFrame(rows).to_csv(index=False)


# ---- the paper's tables ------------------------------------------------------------------------------
def main_labels(df: pd.DataFrame) -> list[str]:
    """Checkpoint labels of the tables: every checkpoint the run evaluated fully, in order (the paper's layout
    has 7K and 30K; a run that also evaluated 3K shows it too). The dense checkpoints of `--checkpoints every:N`
    evaluated with the word-crop metrics only (results.csv `evaluation` = words) are not columns: they feed the
    time-to-legibility table and the curves."""
    if df.empty:
        return []
    full = df[df["evaluation"].fillna("full") != "words"] if "evaluation" in df else df
    return sorted(set((full if not full.empty else df)["label"]), key=label_value)


def _checkpoint_table(df, name, value, corner, corner_plain, caption, lower, fmt, scale=1.0, methods=None,
                      ceiling: str | None = None) -> Table:
    """A value per method x (dataset, checkpoint); `ceiling` names a column whose mean becomes an
    unranked GT-ceiling row (e.g. word_cer_gt)."""
    means = dataset_means(df, value)
    ceil = dataset_means(df, ceiling) if ceiling else None
    labels = main_labels(df)
    datasets = list(dict.fromkeys(df["dataset"]))
    methods = methods or method_order(m for m in df["method"] if not is_ablation(m))
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


RANK_NOTE = r" Red, orange and yellow mark the first, second and third best (ties share a place)."


def build_tables(df: pd.DataFrame, manifest: dict | None = None) -> list[Table]:
    if manifest is not None:
        use_run_methods(manifest)
    if df.empty:
        return []
    df = with_total_seconds(df)
    note = schedule_note(df, manifest)
    tables = [
        _checkpoint_table(df, "ocr_cer", "cer", r"OCR-CER $\downarrow$", "OCR-CER (lower is better)",
                          "OCR-based character error rate (CER, lower is better) of rendered test views, mean over the "
                          "scenes of each dataset." + RANK_NOTE + note, True, ".3f"),
        _checkpoint_table(df, "training_time", "total_seconds", r"\makecell[l]{Training time\\(minutes) $\downarrow$}",
                          "Training time, minutes, preprocessing + optimisation (lower is better)",
                          "Training time in minutes, whole run: preprocessing (text masks, 3D text segmentation, "
                          "initial model and text densification where the method has them) plus optimisation "
                          "(results.csv: total_seconds = preprocess_seconds + train_seconds), mean over the scenes "
                          "of each dataset." + RANK_NOTE + note, True,
                          ".2f" if (df["total_seconds"].max() / 60) < 10 else ".1f", 1 / 60),
    ]
    if df["cer_known"].notna().any():
        tables.append(_checkpoint_table(
            df, "known_text_cer", "cer_known", r"\makecell[l]{Known-text\\CER $\downarrow$}", "Known-text CER (lower is better)",
            "CER of the OCR of rendered views against the known strings of the scene (synthetic scenes only)."
            + RANK_NOTE + note, True, ".3f"))
    if "word_cer" in df and df["word_cer"].notna().any():
        tables += readability_tables(df, note)
    tables += ocr_engine_tables(df, manifest, note)
    tables += script_tables(df, note)
    tables.append(metrics_table(df, note))
    paper = paper_comparison_table(df, note)
    if paper is not None:
        tables.append(paper)
    abl = ablation_table(df, note)
    if abl is not None:
        tables.append(abl)
    return tables


# ---- text in several scripts (issue 31) -------------------------------------------------------------------
def script_tables(df: pd.DataFrame, note: str = "") -> list[Table]:
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
    methods = method_order(m for m in df["method"] if not is_ablation(m))
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


# ---- a second OCR opinion (`run --ocr rapidocr,tesseract`) ---------------------------------------------
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


def ocr_engine_tables(df: pd.DataFrame, manifest: dict | None = None, note: str = "") -> list[Table]:
    """With further OCR engines: each engine's OCR-CER per method x (dataset, checkpoint), and their
    agreement per cell group (`ocr_agreement`); [] for a single-engine run."""
    engines = further_engines(df)
    if not engines:
        return []
    primary = primary_engine(df, manifest)
    labels = main_labels(df)
    methods = method_order(m for m in df["method"] if not is_ablation(m))
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


def paper_results(method: str) -> dict:
    """The published figures of a method's spec ({dataset: {"cer": {iteration: v}, ...}}), {} if none."""
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.methods.registry import get_method

    try:
        return get_method(method).paper_results or {}
    except StringsBenchError:  # a method of an old run folder that is no longer registered
        return {}


def paper_comparison_table(df: pd.DataFrame, note: str = "") -> Table | None:
    """Measured OCR-CER next to the paper's (REFERENCE §5) for the datasets the paper reports; None when
    the run has no such dataset (e.g. the synthetic scenes)."""
    means = dataset_means(df, "cer")
    methods = method_order(m for m in df["method"] if not is_ablation(m))
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
                 "(RTX 3090 Ti, Google Cloud Vision OCR; REFERENCE.md section 5), mean over the scenes of each "
                 "dataset. The paper's scenes, OCR engine and schedule may differ from this run's." + RANK_NOTE + note)


READ_NOTE = (" Reference words: the known words at least 6.5 px high and the words the GT view's OCR read; each "
             "is rectified from the render and read by the recogniser alone (docs/ocr.md). The last row reads the "
             "ground-truth views (the ceiling).")


def readability_tables(df: pd.DataFrame, note: str = "") -> list[Table]:
    """Word-crop readability per checkpoint (word_cer, text_nll, each with the GT ceiling row) and the
    text-region table (word_acc, text PSNR/SSIM/LPIPS inside the dilated text mask) at the last checkpoint."""
    out = [
        _checkpoint_table(df, "word_cer", "word_cer", r"Word CER $\downarrow$", "Word CER (lower is better)",
                          "Word-crop CER: edit distance of what the recogniser reads in each reference word's crop, "
                          "over the reference characters, mean over the scenes of each dataset." + READ_NOTE
                          + RANK_NOTE + note, True, ".3f", ceiling="word_cer_gt"),
        _checkpoint_table(df, "text_nll", "text_nll", r"\makecell[l]{Text NLL\\(nats/char) $\downarrow$}",
                          "Text NLL, nats per character (lower is better)",
                          "Text likelihood: CTC negative log-likelihood of each reference word under the recogniser's "
                          "output on its crop, nats per reference character, mean over the scenes of each dataset."
                          + READ_NOTE + RANK_NOTE + note, True, ".3f", ceiling="text_nll_gt"),
    ]
    labels = main_labels(df)
    final = labels[-1]
    sub = df[(df["label"] == final) & ~df["method"].map(is_ablation).astype(bool)]
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
    out.append(Table("text_region", "Method", "Method", cols, method_order(sub["method"]),
                     f"Text regions at {final} iterations: fraction of reference words read exactly (Words), and PSNR "
                     "over the dilated text mask's pixels, the SSIM map's mean over them, LPIPS-VGG of the mask's "
                     "bounding crop; mean over the scenes of each dataset." + RANK_NOTE + note, heading="Text-region image metrics"))
    return out


def metrics_table(df: pd.DataFrame, note: str = "") -> Table:
    labels = main_labels(df)
    final = labels[-1]
    sub = df[(df["label"] == final) & ~df["method"].map(is_ablation).astype(bool)]
    datasets = list(dict.fromkeys(df["dataset"]))
    methods = method_order(sub["method"])
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


def ablation_table(df: pd.DataFrame, note: str = "") -> Table | None:
    """The paper's ablations: each method with `ablation_of` (its spec's, or run.json's) against that method, at
    the checkpoint its spec names (`ablation_at`: w/o text densification at 7K, a phase-1 position LR at 3K)."""
    present = set(df["method"])
    labels = set(df["label"])
    blocks = []
    for m in method_order(present):
        info = method_info(m)
        if info["group"] != "ablation" or info["ablation_of"] not in present:
            continue
        label = iteration_label(int(info["ablation_at"]))
        blocks.append((f"Effect of {info['ablation_effect']}", m, label if label in labels else main_labels(df)[0],
                       info["ablation_of"]))
    if not blocks:
        return None
    means = dataset_means(df, "cer")
    datasets = list(dict.fromkeys(df["dataset"]))
    rows = []
    for title, abl, label, of in blocks:
        vals = []
        for d in datasets:
            def get(m):
                s = means[(means["method"] == m) & (means["dataset"] == d) & (means["label"] == label)]["cer"]
                return float(s.iloc[0]) if len(s) else math.nan
            vals.append((get(abl), get(of)))
        rows.append((title, abl, label, vals))
    compared = list(dict.fromkeys(of for *_, of in blocks))
    t = Table("ablations", "Dataset", "Dataset", [], [*compared, *[r[1] for r in rows]],
              "Ablations: OCR-CER of STRinGS without text densification, and with a non-zero position learning rate "
              "in phase 1, against full STRinGS (the better one in bold), mean over the scenes of each dataset." + note,
              shade=False, heading="Ablations of STRinGS")
    t.ablation_rows = rows  # type: ignore[attr-defined]
    t.ablation_datasets = datasets  # type: ignore[attr-defined]
    return t


def _fmt3(x: float) -> str:
    return "n/a" if x is None or math.isnan(x) else f"{x:.3f}"


def ablation_latex(t: Table) -> str:
    datasets = t.ablation_datasets  # type: ignore[attr-defined]
    n = 1 + 2 * len(datasets)
    lines = [r"\begin{table}[b]", r"\centering", r"\footnotesize", r"\tabcolsep=1mm",
             r"\begin{tabular}{C{2.4cm} *{%d}{C{0.7cm}}}" % (n - 1), r"\toprule",
             "Dataset & " + " & ".join(r"\multicolumn{2}{c}{%s}" % latex_escape(dataset_title(d)) for d in datasets) + r" \\"]
    for title, _abl, label, vals in t.ablation_rows:  # type: ignore[attr-defined]
        lines.append(r"\cmidrule(lr){1-%d}" % n)
        lines.append(r"& \multicolumn{%d}{c}{\cellcolor{gray}{%s}} \\" % (n - 1, title))
        lines.append(r"\multirow{2}{*}{\shortstack{OCR-CER $\downarrow$\\(%s iterations)}} & " % latex_escape(label)
                     + " & ".join("w/o & Ours" for _ in datasets) + r" \\")
        cells = []
        for wo, ours in vals:
            a, b = _fmt3(wo), _fmt3(ours)
            if not (math.isnan(wo) or math.isnan(ours)):
                if round(ours, 3) < round(wo, 3):
                    b = r"\textbf{" + b + "}"
                elif round(wo, 3) < round(ours, 3):
                    a = r"\textbf{" + a + "}"
            cells += [a, b]
        lines.append("& " + " & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\caption{" + t.caption + "}", r"\label{tab:ablations}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def ablation_markdown(t: Table) -> str:
    datasets = t.ablation_datasets  # type: ignore[attr-defined]
    header = ["ablation", "checkpoint"] + [f"{dataset_title(d)} {s}" for d in datasets for s in ("w/o", "Ours")]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for title, _abl, label, vals in t.ablation_rows:  # type: ignore[attr-defined]
        lines.append("| " + " | ".join([title, label] + [_fmt3(x) for pair in vals for x in pair]) + " |")
    return "\n".join(lines) + "\n"


def ablation_csv(t: Table) -> str:
    rows = []
    for title, abl, label, vals in t.ablation_rows:  # type: ignore[attr-defined]
        for d, (wo, ours) in zip(t.ablation_datasets, vals):  # type: ignore[attr-defined]
            rows.append({"ablation": title, "method": abl, "label": label, "dataset": d, "cer_without": wo, "cer_strings": ours})
    return pd.DataFrame(rows).to_csv(index=False)


def write_tables(df: pd.DataFrame, out_dir: Path, manifest: dict | None = None,
                 extra: list[Table] | None = None) -> dict[str, dict[str, Path]]:
    """Write every table (build_tables', then `extra`) as .tex, .md and .csv, plus preamble.tex and a compilable
    tables.tex."""
    out_dir.mkdir(parents=True, exist_ok=True)
    papers = {m: v.get("paper", "") for m, v in ((manifest or {}).get("methods") or {}).items()}
    written: dict[str, dict[str, Path]] = {}
    for t in build_tables(df, manifest) + list(extra or []):
        if t.name == "ablations":
            tex, md, csv_text = ablation_latex(t), ablation_markdown(t), ablation_csv(t)
        else:
            tex, md, csv_text = to_latex(t, papers), to_markdown(t), to_csv(t)
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
