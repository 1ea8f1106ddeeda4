"""The table model of the reports and its renderers: `Column`, `Table` (LaTeX in the paper's booktabs layout with
the best three shaded, Markdown, CSV), and how rows and datasets are named (method titles, groups and order from
the run folder, then the method specs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

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


@dataclass(frozen=True)
class MethodNames:
    """How the reports name, group and order methods: a run folder's record of them (run.json's "methods": title,
    group, ablation, written from the specs when the run was planned) over the registered specs'; methods neither
    describes (a plug-in no longer installed) get their name. Built per report (`MethodNames.of(manifest)`) and
    handed to whatever names a method: no module-level state."""

    recorded: dict = field(default_factory=dict)  # method -> run.json's entry

    @classmethod
    def of(cls, manifest: dict | None) -> "MethodNames":
        methods = (manifest or {}).get("methods") or {}
        return cls({m: dict(v) for m, v in methods.items() if isinstance(v, dict)})

    def info(self, method: str) -> dict:
        """{"title", "group", "order", "ablation_of", "ablation_at", "ablation_effect"} of a method."""
        from strings_bench.methods.registry import list_methods

        specs = {s.name: (k, s) for k, s in enumerate(list_methods())}
        k, spec = specs.get(method, (len(specs), None))
        info = {"title": (spec.title or spec.name) if spec else method, "group": spec.group if spec else "baseline",
                "order": k, "ablation_of": spec.ablation_of if spec else None,
                "ablation_at": spec.ablation_at if spec else None, "ablation_effect": spec.ablation_effect if spec else ""}
        given = self.recorded.get(method, {})
        info.update({key: given[key] for key in ("title", "group", "ablation_of", "ablation_at", "ablation_effect")
                     if given.get(key)})
        return info

    def is_ablation(self, method: str) -> bool:
        return self.info(method)["group"] == "ablation"

    def order(self, methods) -> list[str]:
        """Methods in the registry's order (the paper's rows), then any other by name."""
        ms = list(dict.fromkeys(methods))
        return sorted(ms, key=lambda m: (self.info(m)["order"], m))

    def title(self, method: str, papers: dict | None = None, latex: bool = False) -> str:
        """The row title of a method (the GT-ceiling row's too); in LaTeX, ours in bold and the venue beside."""
        title = GT_CEILING_TITLE if method == GT_CEILING else self.info(method)["title"]
        if not latex:
            return title
        t = latex_escape(title)
        if method != GT_CEILING and self.info(method)["group"] == "ours":
            t = r"\textbf{" + t + "}"
        paper = short_venue((papers or {}).get(method, ""))
        if paper and not self.is_ablation(method):
            t += r"~\papertable{" + latex_escape(paper) + "}"
        return t


REGISTERED = MethodNames()  # the registered specs' names alone (no run folder's record); immutable


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


def dataset_title(dataset: str) -> str:
    return DATASET_TITLES.get(dataset, dataset)



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
    names: MethodNames = REGISTERED  # how its rows' methods are titled

    def latex(self, papers: dict | None = None) -> str:
        return to_latex(self, papers)

    def markdown(self) -> str:
        return to_markdown(self)

    def csv(self) -> str:
        return to_csv(self)

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
        cells = [t.names.title(m, papers, latex=True)]
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
        cells = [t.names.title(m)]
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



RANK_NOTE = r" Red, orange and yellow mark the first, second and third best (ties share a place)."

