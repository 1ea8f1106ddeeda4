"""The paper's ablation table: each method whose spec names `ablation_of`, beside that method, at the checkpoint
its spec names (`ablation_at`); an `AblationTable` renders itself (LaTeX, Markdown, CSV, HTML)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pandas as pd

from strings_bench.reports.aggregate import dataset_means, main_labels
from strings_bench.store import iteration_label
from strings_bench.reports.table_model import REGISTERED, MethodNames, Table, dataset_title, latex_escape


def fmt3(x: float) -> str:
    return "n/a" if x is None or math.isnan(x) else f"{x:.3f}"


@dataclass
class AblationTable(Table):
    """The ablation table: per block (an ablation), its checkpoint and per dataset (w/o, full method) OCR-CER."""

    # (title, ablation, checkpoint label, [(w/o, full) per dataset])
    rows: list[tuple[str, str, str, list[tuple[float, float]]]] = field(default_factory=list)
    datasets: list[str] = field(default_factory=list)

    def latex(self, papers: dict | None = None) -> str:
        n = 1 + 2 * len(self.datasets)
        lines = [r"\begin{table}[b]", r"\centering", r"\footnotesize", r"\tabcolsep=1mm",
                 r"\begin{tabular}{C{2.4cm} *{%d}{C{0.7cm}}}" % (n - 1), r"\toprule",
                 "Dataset & " + " & ".join(r"\multicolumn{2}{c}{%s}" % latex_escape(dataset_title(d))
                                           for d in self.datasets) + r" \\"]
        for title, _abl, label, vals in self.rows:
            lines.append(r"\cmidrule(lr){1-%d}" % n)
            lines.append(r"& \multicolumn{%d}{c}{\cellcolor{gray}{%s}} \\" % (n - 1, title))
            lines.append(r"\multirow{2}{*}{\shortstack{OCR-CER $\downarrow$\\(%s iterations)}} & " % latex_escape(label)
                         + " & ".join("w/o & Ours" for _ in self.datasets) + r" \\")
            cells = []
            for wo, ours in vals:
                a, b = fmt3(wo), fmt3(ours)
                if not (math.isnan(wo) or math.isnan(ours)):
                    if round(ours, 3) < round(wo, 3):
                        b = r"\textbf{" + b + "}"
                    elif round(wo, 3) < round(ours, 3):
                        a = r"\textbf{" + a + "}"
                cells += [a, b]
            lines.append("& " + " & ".join(cells) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}", r"\caption{" + self.caption + "}", r"\label{tab:ablations}",
                  r"\end{table}"]
        return "\n".join(lines) + "\n"

    def markdown(self) -> str:
        header = ["ablation", "checkpoint"] + [f"{dataset_title(d)} {s}" for d in self.datasets for s in ("w/o", "Ours")]
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for title, _abl, label, vals in self.rows:
            lines.append("| " + " | ".join([title, label] + [fmt3(x) for pair in vals for x in pair]) + " |")
        return "\n".join(lines) + "\n"

    def csv(self) -> str:
        rows = []
        for title, abl, label, vals in self.rows:
            for d, (wo, ours) in zip(self.datasets, vals):
                rows.append({"ablation": title, "method": abl, "label": label, "dataset": d, "cer_without": wo,
                             "cer_strings": ours})
        return pd.DataFrame(rows).to_csv(index=False)


def ablation_table(df: pd.DataFrame, note: str = "", names: MethodNames = REGISTERED) -> AblationTable | None:
    """The paper's ablations: each method with `ablation_of` (its spec's, or run.json's) against that method, at
    the checkpoint its spec names (`ablation_at`: w/o text densification at 7K, a phase-1 position LR at 3K)."""
    present = set(df["method"])
    labels = set(df["label"])
    blocks = []
    for m in names.order(present):
        info = names.info(m)
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
    return AblationTable("ablations", "Dataset", "Dataset", [], [*compared, *[r[1] for r in rows]],
                         "Ablations: OCR-CER of STRinGS without text densification, and with a non-zero position learning "
                         "rate in phase 1, against full STRinGS (the better one in bold), mean over the scenes of each "
                         "dataset." + note, shade=False, heading="Ablations of STRinGS", rows=rows, datasets=datasets,
                         names=names)

