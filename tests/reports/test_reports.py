"""Reports: ranking/shading, n/a handling, table layouts, files produced, LaTeX compiles."""

from __future__ import annotations

import math
import re
import shutil
import subprocess

import pandas as pd
import pytest

import runner_fakes as rf
import strings_bench.bench.runner as runner
from strings_bench.reports import table_model, tables, write_report


def test_rank_classes_ties_and_nan():
    assert table_model.rank_classes([0.3, 0.1, 0.2, 0.4], True) == ["third", "first", "second", None]
    assert table_model.rank_classes([0.3, 0.1, 0.2, 0.4], False) == ["second", None, "third", "first"]
    # Ties share a place (the paper shades two "third" 0.392s); NaN never ranks.
    assert table_model.rank_classes([0.392, 0.392, 0.1, math.nan, 0.2], True) == ["third", "third", "first", None, "second"]
    # Compared as printed: 0.1234 and 0.1231 both show 0.123.
    assert table_model.rank_classes([0.1234, 0.1231, 0.2], True, decimals=3) == ["first", "first", "second"]


def _frame(cer_7k: dict, cer_30k: dict, lpips=math.nan, datasets=("synthetic",)):
    rows = []
    for d in datasets:
        for m in cer_7k:
            for label, it, cer in (("7K", 350, cer_7k[m]), ("30K", 1500, cer_30k[m])):
                for scene, delta in (("a", -0.01), ("b", 0.01)):  # mean over scenes = the given value
                    rows.append({"method": m, "dataset": d, "scene": scene, "iteration": it, "label": label,
                                 "cer": cer + delta, "cer_known": math.nan, "psnr": 25.0, "ssim": 0.9, "lpips": lpips,
                                 "train_seconds": 60.0 * (1 + len(m)), "gaussians": 12345, "ocr_failed": 0})
    return pd.DataFrame(rows)


def _shade_of(tex: str, method_title: str) -> list[str | None]:
    line = next(l for l in tex.splitlines() if l.startswith(method_title))
    cells = line.rstrip(" \\").split(" & ")[1:]
    return [m.group(1) if (m := re.match(r"\\cellcolor\{(\w+)\}", c)) else None for c in cells]


def test_ocr_cer_latex_shades_best_three(tmp_path):
    cer7 = {"3dgs": 0.736, "mip-splatting": 0.748, "mcmc": 0.927, "absgs": 0.768, "edc-absgs": 0.328, "strings": 0.177}
    cer30 = {"3dgs": 0.148, "mip-splatting": 0.129, "mcmc": 0.110, "absgs": 0.143, "edc-absgs": 0.116, "strings": 0.106}
    df = _frame(cer7, cer30)
    manifest = {"schedule": {"name": "quick", "steps_scale": 0.05},
                "methods": {"3dgs": {"paper": "SIGGRAPH'23"}, "strings": {"paper": "WACV'26"}}}
    written = tables.write_tables(df, tmp_path, manifest)
    tex = written["ocr_cer"]["tex"].read_text()
    # Same shading as the paper's STRinGS-360 columns.
    assert _shade_of(tex, r"\textbf{STRinGS}") == ["first", "first"]
    assert _shade_of(tex, "EDC-AbsGS") == ["second", "third"]
    assert _shade_of(tex, "3DGS-MCMC") == [None, "second"]
    assert _shade_of(tex, "3DGS~") == ["third", None]
    assert _shade_of(tex, "AbsGS") == [None, None]
    assert r"\papertable{SIGGRAPH'23}" in tex
    assert "0.177" in tex and "0.106" in tex  # the mean over scenes a and b
    assert "7K = 350 iterations" in tex and "30K = 1500 iterations" in tex
    assert r"\cmidrule(lr){2-3}" in tex and "Synthetic" in tex
    # Paper row order.
    order = [l.split("~")[0].split(" &")[0] for l in tex.splitlines() if "&" in l and "cellcolor" in l or l.startswith("AbsGS")]
    assert order.index("3DGS") < order.index(r"\textbf{STRinGS}")
    md = written["ocr_cer"]["md"].read_text()
    assert "| STRinGS | 0.177 **(1)** | 0.106 **(1)** |" in md
    csv = pd.read_csv(written["ocr_cer"]["csv"])
    assert csv.loc[csv["method"] == "strings", "Synthetic 7K"].iloc[0] == pytest.approx(0.177)


def test_missing_lpips_is_na_never_zero(tmp_path):
    df = _frame({"3dgs": 0.2, "strings": 0.1}, {"3dgs": 0.1, "strings": 0.05}, lpips=math.nan)
    written = tables.write_tables(df, tmp_path)
    tex = written["metrics"]["tex"].read_text()
    rows = [l for l in tex.splitlines() if l.startswith("3DGS") or l.startswith(r"\textbf{STRinGS}")]
    assert all(" & n/a & " in r for r in rows)
    assert "0.0000" not in tex
    assert "12K" in tex  # Points in thousands


def test_ablation_table_layout(tmp_path):
    cer7 = {"strings": 0.177, "strings-no-densify": 0.437, "strings-pos-lr": 0.2}
    df = _frame(cer7, cer7)
    extra = df[df["label"] == "7K"].copy()
    extra["label"], extra["iteration"] = "3K", 150
    extra.loc[extra["method"] == "strings-pos-lr", "cer"] += 0.6
    df = pd.concat([df, extra])
    written = tables.write_tables(df, tmp_path)
    tex = written["ablations"]["tex"].read_text()
    assert "Effect of text densification" in tex and "Effect of zero position LR" in tex
    assert r"0.437 & \textbf{0.177}" in tex
    assert "(3K iterations)" in tex
    # Ablation methods stay out of the main table.
    assert "w/o text densification" not in written["ocr_cer"]["tex"].read_text()


def test_report_files_produced(fake_run):
    rep = fake_run / "report"
    for name in ("ocr_cer", "training_time", "metrics", "known_text_cer"):
        for ext in ("tex", "md", "csv"):
            assert (rep / "tables" / f"{name}.{ext}").stat().st_size > 0
    for fig in ("cer_vs_time_7K", "cer_over_iterations", "qualitative_7K", "qualitative_30K"):
        assert (rep / "figures" / f"{fig}.png").stat().st_size > 1000
    md = (rep / "report.md").read_text()
    assert "figures/cer_vs_time_7K.png" in md and "| fake-a |" in md
    # A report can be rebuilt on its own from the cells (e.g. after deleting results.csv): the store rebuilds
    # results.csv (as `strings-bench report` does), the report reads it.
    (fake_run / "results.csv").unlink()
    from strings_bench.store import refresh

    refresh(fake_run)
    write_report(fake_run)
    assert len(pd.read_csv(fake_run / "results.csv")) == 9


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="pdflatex not installed")
def test_latex_compiles(fake_run, tmp_path):
    d = fake_run / "report" / "tables"
    proc = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "-output-directory", str(tmp_path),
                           "tables.tex"], cwd=d, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-3000:]
    assert (tmp_path / "tables.pdf").stat().st_size > 1000


def test_short_venue():
    assert table_model.short_venue("Kerbl et al.: 3D Gaussian Splatting (SIGGRAPH 2023)") == "SIGGRAPH'23"
    assert table_model.short_venue("Deng: EDC (arXiv 2024), on AbsGS; code github.com/x") == "arXiv'24"
    assert table_model.short_venue("CVPR'24") == "CVPR'24"
    assert table_model.short_venue("no venue here") == ""


def test_paper_figures_next_to_measured_only_where_published(tmp_path):
    """The specs carry the paper's CER (docs/sources.md §5): the report sets it beside the measured CER for the
    datasets the paper reports, and has no such table for the synthetic scenes."""
    df = _frame({"3dgs": 0.5, "strings": 0.25}, {"3dgs": 0.2, "strings": 0.1}, datasets=("strings360", "synthetic"))
    written = tables.write_tables(df, tmp_path)
    csv = pd.read_csv(written["paper_comparison"]["csv"]).set_index("method")
    # docs/sources.md §5, STRinGS-360: 3DGS .736 / .148, STRinGS .177 / .106
    assert csv.loc["3dgs", "STRinGS-360 7K paper"] == pytest.approx(0.736)
    assert csv.loc["strings", "STRinGS-360 30K paper"] == pytest.approx(0.106)
    assert csv.loc["strings", "STRinGS-360 7K measured"] == pytest.approx(0.25)
    assert not any(c.startswith("Synthetic") for c in csv.columns)
    only_synthetic = tables.write_tables(_frame({"3dgs": 0.5}, {"3dgs": 0.2}), tmp_path / "syn")
    assert "paper_comparison" not in only_synthetic


def test_readability_tables_and_metric_figures(tmp_path):
    df = _frame({"3dgs": 0.9, "strings": 0.8}, {"3dgs": 0.7, "strings": 0.6})
    df["word_cer"] = df["cer"] / 2
    df["word_cer_gt"] = 0.05
    df["text_nll"] = df["cer"] * 3
    df["text_nll_gt"] = 0.2
    for c, v in (("word_acc", 0.5), ("text_psnr", 20.0), ("text_ssim", 0.8), ("text_lpips", math.nan)):
        df[c] = v
    written = tables.write_tables(df, tmp_path / "t")
    assert {"word_cer", "text_nll", "text_region"} <= set(written)
    md = written["word_cer"]["md"].read_text()
    ceiling = next(l for l in md.splitlines() if l.startswith("| GT view (ceiling)"))
    assert ceiling.count("0.050") == 2 and "(1)" not in ceiling  # the ceiling row is never ranked
    assert "0.400 **(1)**" in md  # strings' 7K word CER: the best method
    assert "0.2" in written["text_nll"]["csv"].read_text()
    region = written["text_region"]["md"].read_text()
    assert "20.00" in region and "n/a" in region
    from strings_bench.reports import figures

    out = figures.write_figures(df, tmp_path, tmp_path / "f", metrics=["text_nll"])
    assert {"text_nll_vs_time_7K", "text_nll_vs_time_30K", "text_nll_over_iterations"} <= set(out)
    assert not any(k.startswith("cer_") for k in out)
    default = figures.write_figures(df, tmp_path, tmp_path / "g")
    assert {"cer_vs_time_7K", "word_cer_over_iterations", "text_nll_over_iterations"} <= set(default)
    from strings_bench.core.errors import StringsBenchError

    with pytest.raises(StringsBenchError, match="unknown metric"):
        figures.write_figures(df, tmp_path, tmp_path / "h", metrics=["nope"])
    # The CLI: strings-bench report RUN --metric text_nll
    from strings_bench.cli import main

    run = tmp_path / "run"
    run.mkdir()
    df.to_csv(run / "results.csv", index=False)
    assert main(["report", str(run), "--metric", "text_nll"]) == 0
    report = (run / "report" / "report.md").read_text()
    assert "text_nll_over_iterations.png" in report and "cer_over_iterations.png" not in report
    assert "## Word CER (lower is better)" in report and "## word cer" not in report and "GT view (ceiling)" in report


def test_every_evaluated_checkpoint_gets_its_column_and_headings_are_titles(tmp_path):
    """The default run evaluates 3K and 7K: both appear (the tables once showed only 7K), in order."""
    rows = []
    for method, cers in (("strings", (0.9, 0.5)), ("3dgs", (0.95, 0.6))):
        for label, it, cer in (("3K", 450, cers[0]), ("7K", 1050, cers[1])):
            rows.append({"method": method, "dataset": "synthetic", "scene": "books", "iteration": it, "label": label,
                         "cer": cer, "cer_known": math.nan, "psnr": 20.0, "ssim": 0.8, "lpips": math.nan,
                         "train_seconds": 60.0, "gaussians": 1000, "ocr_failed": 0})
    df = pd.DataFrame(rows)
    t = [x for x in tables.build_tables(df) if x.name == "ocr_cer"][0]
    assert [c.sub_plain for c in t.columns] == ["3K", "7K"]
    assert t.columns[0].values == {"strings": 0.9, "3dgs": 0.95} and t.columns[1].values == {"strings": 0.5, "3dgs": 0.6}
    run = tmp_path / "run"
    run.mkdir()
    df.to_csv(run / "results.csv", index=False)
    report = write_report(run).read_text()
    assert "## OCR-CER (lower is better)" in report and "## ocr cer" not in report
    section = report.split("## OCR-CER (lower is better)")[1].split("## ")[0]
    assert " 3K |" in section and " 7K |" in section


def test_method_titles_and_groups_come_from_the_run_folder_then_the_specs():
    """One place for a method's title and group: its spec, recorded in run.json; the reports read them there, from
    the MethodNames a report is built with (no module-level state: another report's names are untouched)."""
    names = table_model.MethodNames.of({"methods": {"my-splat": {"title": "MySplat (ours)", "group": "ours"}}})
    assert names.title("my-splat") == "MySplat (ours)"
    assert names.title("my-splat", latex=True).startswith(r"\textbf{MySplat (ours)}")
    assert names.title("mcmc") == "3DGS-MCMC" and names.is_ablation("strings-pos-lr")
    assert names.title("edc") == "edc"  # no spec registers it: no invented title
    assert names.order(["strings", "zzz", "mcmc", "3dgs", "strings-no-densify", "mip-splatting"]) == \
        ["3dgs", "mip-splatting", "mcmc", "strings", "strings-no-densify", "zzz"]
    assert table_model.REGISTERED.title("my-splat") == "my-splat"  # the registry's names alone know nothing of it
    df = pd.DataFrame([{"method": m, "dataset": "synthetic", "scene": "books", "label": "7K", "iteration": 35,
                        "cer": c, "cer_known": math.nan, "total_seconds": 60.0, "train_seconds": 60.0, "psnr": 20.0,
                        "ssim": 0.7, "lpips": math.nan, "gaussians": 1000, "ocr_failed": 0}
                       for m, c in (("my-splat", 0.2), ("3dgs", 0.5))])
    (ocr_cer, *_) = tables.build_tables(df, {"methods": {"my-splat": {"title": "MySplat (ours)", "group": "ours"}}})
    assert "| MySplat (ours) | 0.200 **(1)** |" in ocr_cer.markdown()
    assert "| my-splat | 0.200 **(1)** |" in tables.build_tables(df)[0].markdown()  # built without the record


def test_the_report_ranks_methods_on_the_scenes_they_all_have(tmp_path):
    """A run still under way (STRinGS has trained one scene of two): the tables and figures average the common
    scene, the cells table keeps both, and the report says what is left out."""
    rows = []
    for method, cers in (("strings", {"a": 0.2}), ("3dgs", {"a": 0.4, "b": 0.9})):
        for scene, cer in cers.items():
            rows.append({"method": method, "dataset": "synthetic", "scene": scene, "iteration": 1050, "label": "7K",
                         "cer": cer, "cer_known": math.nan, "psnr": 20.0, "ssim": 0.8, "lpips": math.nan,
                         "train_seconds": 60.0, "gaussians": 1000, "ocr_failed": 0})
    df = pd.DataFrame(rows)
    from strings_bench.reports.aggregate import common_scenes

    kept, notes = common_scenes(df)
    assert sorted(zip(kept["method"], kept["scene"])) == [("3dgs", "a"), ("strings", "a")]
    assert notes == ["3dgs synthetic 7K: b left out of the means (not every method has them yet)"]
    run = tmp_path / "run"
    run.mkdir()
    df.to_csv(run / "results.csv", index=False)
    report = write_report(run).read_text()
    section = report.split("## OCR-CER (lower is better)")[1].split("## ")[0]
    assert "0.400" in section and "0.650" not in section  # 3DGS on scene a, not the mean (0.4 + 0.9) / 2
    assert "3dgs synthetic 7K: b left out of the means" in report
    assert "3 cell(s)" in report
    # one method alone, or methods on the same scenes: nothing is held back
    assert common_scenes(df[df["method"] == "3dgs"])[1] == []
