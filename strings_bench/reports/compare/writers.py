"""A comparison written out: Markdown (with the per-scene rows), LaTeX, CSV and an HTML page in the run report's
style (`write_comparison`)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_text
from strings_bench.reports.compare.collect import VALUES
from strings_bench.reports.compare.statistics import CER_VALUES, Comparison, decided_rows, room_draw
from strings_bench.reports.compare.tables import comparison_tables, has_draws
from strings_bench.reports.table_model import PREAMBLE, Table, label_value

DECIDED_CAPTION = ("Decided: both methods have several seeds (or scene draws) and the ranges of their means per seed "
                   "and draw do not overlap; not decided: they overlap. Lower in (paired): in how many of the (seed, "
                   "draw) replicates both have the method's mean is below the reference's (beside the verdict, not "
                   "part of it).")


def _shown(rows: list[dict]) -> tuple[list[dict], str]:
    """The pairs both sides of which have several seeds (or draws), and a sentence on those left out."""
    shown = [r for r in rows if r["verdict"] != "one seed"]
    n = len(rows) - len(shown)
    return shown, (f" {n} pair(s) with a single seed (of a single draw) on one side are not listed." if n else "")


def _decided_markdown(c: Comparison, rows: list[dict]) -> str:
    lines = ["| method | against | CER | checkpoint | difference of means | seeds | verdict | lower in (paired) |",
             "|---|---|---|---|---|---|---|---|"]
    cer_names = dict(CER_VALUES)
    for r in rows:
        lines.append(f"| {c.names.title(r['method'])} | {c.names.title(r['against'])} | {cer_names[r['value']]} | {r['label']} | "
                     f"{r['difference']:+.3f} | {r['seeds']} | {r['verdict']} | {r['paired']} |")
    return "\n".join(lines) + "\n"


def per_scene_table(c: Comparison, value: str = "cer_known") -> str:
    """One row per method and checkpoint: `value` per scene, the seeds' figures joined with '/' (seed order)."""
    if value not in VALUES:
        raise StringsBenchError(f"--per-scene {value}: not a compared value", hint=f"one of: {', '.join(VALUES)}")
    cells = c.cells if c.cells is not None else c.data
    scenes = sorted({sc for per_seed in cells.values() for by_scene in per_seed.values() for sc in by_scene},
                    key=lambda sc: (room_draw(sc)[0], room_draw(sc)[1], sc))  # a room's draws side by side
    first: dict = {}  # label -> the smallest iteration trained for it (checkpoint order)
    for (_, label), per_seed in cells.items():
        for by_scene in per_seed.values():
            for v in by_scene.values():
                first[label] = min(first.get(label, v["iteration"]), v["iteration"])
    lines = [f"{value} per scene; several seeds as seed0 / seed1 / ... (seeds: the cells' own)", "",
             "| method | ckpt | " + " | ".join(scenes) + " |", "|---|---|" + "---|" * len(scenes)]
    for label in sorted(first, key=first.get):
        for m in c.methods:
            per_seed = cells.get((m, label))
            if not per_seed:
                continue
            row = [" / ".join(f"{per_seed[seed][sc][value]:.3f}" for seed in sorted(per_seed) if sc in per_seed[seed])
                     or "-" for sc in scenes]
            lines.append(f"| {c.names.title(m)} | {label} | " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def comparison_markdown(c: Comparison, per_scene: str | None = None) -> str:
    over = "seeds and scene draws" if has_draws(c) else "seeds"
    parts = [f"# Comparison over {over}: {', '.join(str(d) for d in c.run_dirs)}", ""]
    for t in comparison_tables(c):
        parts += [f"## {t.title}", "", t.markdown(), t.caption, ""]
    rows, left = _shown(decided_rows(c))
    if rows or left:
        parts += ["## Decided or not" + ("" if c.against is None else f", against {c.names.title(c.reference)}"), "",
                  _decided_markdown(c, rows),
                  DECIDED_CAPTION + left, ""]
    if c.left_out():
        parts += c.left_out() + [""]
    if per_scene:
        parts += ["## Per scene", "", per_scene_table(c, per_scene)]
    return "\n".join(parts)


def comparison_csv(c: Comparison) -> str:
    """Every summary as a row: method, checkpoint, value, mean, min, max, seeds, scenes, the seeds' means."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["method", "label", "value", "mean", "min", "max", "seeds", "scenes", "per_seed", "draws", "per_draw",
                "draw_min", "draw_max"])
    for m in c.methods:
        for label in sorted(c.numbers[m], key=label_value):
            for value, s in c.numbers[m][label].items():
                if s is not None:
                    per_draw = list(s["per_draw"].values())
                    w.writerow([m, label, value, repr(s["mean"]), repr(s["min"]), repr(s["max"]), s["seeds"], s["scenes"],
                                " ".join(repr(x) for x in s["per_seed"]), s["draws"],
                                " ".join(f"{d}:{x!r}" for d, x in s["per_draw"].items()), repr(min(per_draw)),
                                repr(max(per_draw))])
    return buf.getvalue()


def comparison_html(c: Comparison, tables: list[Table]) -> str:
    from strings_bench.reports.html import esc, html_page, table_html

    title = "strings-bench comparison over seeds" + (" and scene draws" if has_draws(c) else "")
    parts = [f"<header><h1>{esc(title)}</h1><p>Run folders: {esc(', '.join(str(d) for d in c.run_dirs))}</p></header>"
             "<main>", '<p class="legend"><span style="background:var(--first)">first</span><span style="background:'
             'var(--second)">second</span><span style="background:var(--third)">third</span>best of each column by the '
             "seeds' mean (the paper's figures, in grey, never rank). Click a header to sort.</p>"]
    for t in tables:
        parts.append(f"<h2>{esc(t.title)}</h2>{table_html(t)}<p class=\"caption\">{esc(t.caption)}</p>")
    rows, left = _shown(decided_rows(c))
    if rows or left:
        cer_names = dict(CER_VALUES)
        body = "".join(
            f'<tr><td class="name">{esc(c.names.title(r["method"]))}</td><td>{esc(cer_names[r["value"]])}</td>'
            f'<td>{esc(r["label"])}</td><td data-v="{r["difference"]!r}">{r["difference"]:+.3f}</td>'
            f'<td>{esc(r["seeds"])}</td><td class="{"decided" if r["verdict"] == "decided" else "undecided"}">'
            f'{esc(r["verdict"])}</td><td>{esc(r["paired"])}</td></tr>' for r in rows)
        parts.append(f"<h2>Decided or not, against {esc(c.names.title(c.reference))}</h2>"
                     '<table class="data" id="table-decided"><thead><tr>'
                     '<th class="name" data-col="0" data-type="text">method</th><th data-col="1" data-type="text">CER</th>'
                     '<th data-col="2" data-type="text">checkpoint</th><th data-col="3" data-type="num">difference</th>'
                     '<th data-col="4" data-type="text">seeds</th><th data-col="5" data-type="text">verdict</th>'
                     '<th data-col="6" data-type="text">lower in (paired)</th>'
                     f"</tr></thead><tbody>{body}</tbody></table>"
                     f'<p class="caption">{esc(DECIDED_CAPTION + left)}</p>')
    for line in c.left_out():
        parts.append(f'<p class="note">{esc(line)}</p>')
    return html_page(title, "\n".join(parts) + "</main>")


def write_comparison(c: Comparison, out: str | Path, per_scene: str | None = None) -> dict[str, Path]:
    """Write comparison.md, comparison.tex (with tables' preamble.tex), comparison.csv and index.html into `out`."""
    out = Path(out)
    tables = comparison_tables(c)
    tex = "\n".join(t.latex() for t in tables)
    doc = "\n".join([r"\documentclass{article}", r"\usepackage[margin=1.5cm]{geometry}", PREAMBLE,
                     r"\begin{document}", tex, r"\end{document}"]) + "\n"
    return {"md": atomic_write_text(out / "comparison.md", comparison_markdown(c, per_scene)),
            "tex": atomic_write_text(out / "comparison.tex", doc),
            "csv": atomic_write_text(out / "comparison.csv", comparison_csv(c)),
            "html": atomic_write_text(out / "index.html", comparison_html(c, tables))}


def comparison_from_csv(path: str | Path, paper_dataset: str | None = None) -> Comparison:
    """The Comparison a comparison.csv (`comparison_csv`, what `strings-bench compare` banks) holds: every summary
    as written, so that `comparison_tables` makes the tables compare printed from the run folders. The cells
    themselves are not in the CSV: the per-room tables over draws (`draws_tables`) and the paired counts of
    "Decided or not" need the folders; the method names are the specs' (the folders' run.json is not in it)."""
    from strings_bench.reports.compare.statistics import PAPER_DATASET
    from strings_bench.reports.table_model import MethodNames

    path = Path(path)
    if not path.is_file():
        raise StringsBenchError(f"comparison CSV {path} does not exist")
    with path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    needed = {"method", "label", "value", "mean", "min", "max", "seeds", "scenes", "per_seed"}  # draws: since draws
    if not rows or not needed <= set(rows[0]):
        raise StringsBenchError(f"{path} is not a comparison.csv of `strings-bench compare`",
                                hint=f"it needs the columns {', '.join(sorted(needed))}")
    numbers: dict = {}
    for r in rows:
        seeds, draws = int(r["seeds"]), int(r.get("draws") or 1)
        per_draw = ({int(d): float(x) for d, _, x in (w.partition(":") for w in r["per_draw"].split())}
                    if r.get("per_draw") else {0: float(r["mean"])})  # a CSV from before draws: one draw
        numbers.setdefault(r["method"], {}).setdefault(r["label"], {})[r["value"]] = {
            "mean": float(r["mean"]), "min": float(r["min"]), "max": float(r["max"]), "seeds": seeds,
            "draws": draws, "replicates": seeds * draws, "scenes": int(r["scenes"]),
            "per_seed": [float(x) for x in r["per_seed"].split()], "per_draw": per_draw, "left_out": {}}
    for by_label in numbers.values():
        for by_value in by_label.values():
            for v in VALUES:
                by_value.setdefault(v, None)
    names = MethodNames()
    methods = names.order(numbers)
    return Comparison({}, numbers, methods, [path], names, paper_dataset or PAPER_DATASET)
