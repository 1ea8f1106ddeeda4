"""The report of a run: tables (LaTeX/Markdown/CSV), figures, a report.md index and a static HTML page.

    from strings_bench.reports import write_report
    write_report("runs/default")      # -> runs/default/report/report.md (and report/index.html)

Everything is rebuilt from RUN_DIR/results.csv and the cell result files, so a report can be
regenerated at any time (`strings-bench report RUN_DIR`), also for a partly finished run.
"""

from __future__ import annotations

from pathlib import Path

from strings_bench.store import RESULTS_CSV, read_manifest
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_text

__all__ = ["write_report"]


def write_report(run_dir: str | Path, metrics: list[str] | None = None) -> Path:
    """Write RUN_DIR/report/ (tables, figures, report.md, index.html with its word-crop galleries);
    `metrics` picks the metrics of the scatter and over-iterations figures (default: OCR-CER, word CER
    and text NLL where the run has them). Returns report.md's path."""
    from strings_bench.reports.figures import write_figures
    from strings_bench.reports.html import write_html
    from strings_bench.reports.aggregate import load_results
    from strings_bench.reports.tables import build_tables, write_tables

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise StringsBenchError(f"run folder {run_dir} does not exist", hint="give the --out folder of a `strings-bench run`")
    if not (run_dir / RESULTS_CSV).exists():
        raise StringsBenchError(f"{run_dir} has no {RESULTS_CSV} and no cells/", hint="is this a run folder? run `strings-bench run` first")
    manifest = read_manifest(run_dir) or {}
    from strings_bench.reports.table_model import MethodNames

    names = MethodNames.of(manifest)  # method titles and groups as the run recorded them, then the specs'
    from strings_bench.reports.aggregate import common_scenes

    all_cells = load_results(run_dir)
    df, left_out = common_scenes(all_cells)  # the tables and figures rank methods on the same scenes
    out = run_dir / "report"
    from strings_bench.reports.readability_analysis import analyse, front_lines, write_fronts
    from strings_bench.reports.tables import schedule_note

    analysis = analyse(run_dir, df, schedule_note(df, manifest), names)  # CER by text size, time to legibility, fronts
    tables = write_tables(df, out / "tables", manifest, extra=analysis.tables)
    figures = write_figures(df, run_dir, out / "figures", metrics, names)
    if analysis.fronts:
        write_fronts(analysis.fronts, out / "tables" / "pareto_front.csv")
    if analysis.size_fronts:
        write_fronts(analysis.size_fronts, out / "tables" / "size_front.csv")
    lines = [f"# strings-bench report: {run_dir.name}", ""]
    schedule = manifest.get("schedule") or {}
    if schedule:
        lines.append(f"Schedule **{schedule.get('name')}** (steps scale {schedule.get('steps_scale')}), downscale "
                     f"{manifest.get('downscale')}, OCR backend `{manifest.get('ocr')}`.")
    lines.append(f"{len(all_cells)} cell(s) (method x scene x checkpoint) in `{RESULTS_CSV}`. Checkpoint columns are labelled "
                 "by the paper iteration they stand for (see `iteration` in the CSV for the iterations trained).")
    notes = []
    if not all_cells.empty and all_cells["ocr_failed"].fillna(0).astype(int).sum():
        notes.append(f"OCR failed on {int(all_cells['ocr_failed'].fillna(0).astype(int).sum())} view evaluation(s); "
                     "those views are left out of CER (see `ocr_failed` in results.csv).")
    if not all_cells.empty and {"cer", "cer_chars"} <= set(all_cells.columns):  # folders made before cer_chars lack it
        import pandas as pd

        chars = pd.to_numeric(all_cells["cer_chars"], errors="coerce")
        floored = all_cells[all_cells["cer"].isna() & (chars > 0)]
        if not floored.empty:  # GT read, CER withheld: the scene's floor on GT characters (min_gt_chars)
            scenes = floored.assign(chars=chars).groupby(["dataset", "scene"])["chars"].max()
            notes.append("OCR-CER is not scored on " + "; ".join(f"{d}/{s} (its GT reads {int(n)} characters on the "
                                                                    "test views)" for (d, s), n in scenes.items())
                         + ": below the floor on GT characters of a scene without known text, 50 by default (docs/guide/datasets.md, "
                         "'Too little text for a CER'); the "
                         "OCR-CER tables leave it out.")
    if not all_cells.empty and all_cells["lpips"].isna().all():
        from strings_bench.eval.lpips_net import INSTALL_HINT, available

        why = "it was skipped (--no-lpips)" if available() else f"its weights are not installed (`{INSTALL_HINT}`)"
        notes.append(f"LPIPS is n/a: {why}.")
    if left_out:
        notes.append("The tables and figures average the scenes every method has at each checkpoint (the cells table "
                     "and results.csv hold them all): " + "; ".join(left_out) + ".")
    lines += [f"\n{n}" for n in notes]
    lines.append("")
    lines.append("The same report as one page with sortable tables and word-crop galleries per scene: `index.html` "
                 "(open it in a browser; no server needed).")
    lines.append("")
    for files in tables.values():
        lines += [f"## {files['title']}", "", files["md"].read_text(encoding="utf-8"),
                  f"LaTeX: `{files['tex'].relative_to(out)}` (preamble `tables/preamble.tex`, all tables `tables/tables.tex`); "
                  f"CSV: `{files['csv'].relative_to(out)}`", ""]
    if analysis.fronts:
        lines += ["## Speed/accuracy front", "",
                  "At each checkpoint, the methods that no other method beats on both mean training time "
                  "(preprocessing + optimisation) and the mean CER over the scenes (circled in the scatter figures; "
                  "`tables/pareto_front.csv`):", "", *front_lines(analysis.fronts, names), ""]
    if analysis.size_fronts:
        budget = manifest.get("budget")
        src = f" --budget-from {manifest['budget_from']}" if manifest.get("budget_from") else ""
        held = (f" This run held every method to an equal budget (`--budget {budget}{src}`, docs/guide/running.md)." if budget
                else " The counts are each method's own (no `--budget`); `run --budget 3dgs` holds them level.")
        lines += ["## Size/accuracy front", "",
                  "At each checkpoint, the methods that no other method beats on both the mean Gaussian count and "
                  "the mean CER over the scenes (circled in the CER-vs-Gaussians figures; `tables/size_front.csv`)."
                  + held, "", *front_lines(analysis.size_fronts, names), ""]
    if figures:
        lines += ["## figures", ""]
        for name, p in figures.items():
            lines += [f"### {name.replace('_', ' ')}", "", f"![{name}]({p.relative_to(out)})", ""]
            if "_vs_gaussians_" in name:
                lines += [f"Mean {name.split('_vs_gaussians_')[0]} against the mean Gaussian count at the checkpoint.", ""]
            if "_vs_time_" in name:
                lines += [f"Mean {name.split('_vs_time_')[0]} against mean whole-run training time: preprocessing (text masks, 3D text "
                          "segmentation, initial model, text densification) plus optimisation (`total_seconds`).", ""]
    md = atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    write_html(run_dir, out, all_cells, manifest, build_tables(df, manifest) + analysis.tables, figures, notes,
               fronts=analysis.fronts + analysis.size_fronts)
    return md
