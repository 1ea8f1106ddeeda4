"""The documentation against what it documents: every generated table and the CLI reference up to date with their
sources (`docs refresh --check` clean, and what the check catches), the CLI reference complete, results.csv's columns
documented, the paper's figures the same in docs/sources.md and the method specs. The rules on how the docs are
written (no work-log words, links that resolve, no hand-written figures, ...) are tests/lint/'s."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from strings_bench.cli import build_parser
from strings_bench.cli.docs import cli_reference, refresh
from strings_bench.reports.doc_tables import refresh_page, refresh_text
from tests.lint.test_docs_rules import cli_parsers

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"


def test_generated_docs_match_their_sources():
    """`strings-bench docs refresh --check` in CI: every generated table and the CLI reference are up to date."""
    assert refresh(ROOT, check=True) == []


def test_refresh_check_catches_a_table_that_differs_from_its_data(tmp_path):
    root = tmp_path / "repo"
    (root / "docs" / "data").mkdir(parents=True)
    (root / "docs" / "data" / "t.csv").write_text("method,label,cer_known\n3dgs,30K,0.54\nstrings,30K,0.23\n")
    page = root / "docs" / "p.md"
    page.write_text("x\n<!-- table (strings-bench docs refresh): data/t.csv kind=results bold=1 columns=method,label,cer_known -->\n<!-- end table -->\n")
    assert refresh_page(page) is True  # filled from the data
    text = page.read_text()
    assert "| strings | 30K | **0.230** |" in text and "| 3dgs | 30K | 0.540 |" in text
    assert refresh_page(page, check=True) is False
    page.write_text(text.replace("0.540", "0.500"))  # a hand edit
    assert refresh_page(page, check=True) is True
    (root / "docs" / "data" / "t.csv").write_text("method,label,cer_known\n3dgs,30K,0.54\nstrings,30K,0.25\n")
    assert refresh_page(page) is True and "**0.250**" in page.read_text()


def test_compare_tables_show_mean_and_range(tmp_path):
    data = tmp_path / "c.csv"
    data.write_text("method,label,value,mean,min,max,seeds\n"
                    "3dgs,30K,cer_known,0.2,0.19,0.21,3\nstrings,30K,cer_known,0.15,0.14,0.18,3\n")
    page = tmp_path / "p.md"
    out = refresh_text("<!-- table (strings-bench docs refresh): c.csv kind=compare values=cer_known labels=30K -->\n<!-- end table -->", page)
    assert "| strings | 3 | 0.150 (0.140-0.180) |" in out


def test_compare_table_blocks_are_compares_own_tables(tmp_path):
    """kind=compare-table: compare's table as its formatter makes it from the CSV (ranks and the paper's grey figures
    included); an unknown table, or where= (compare's tables are shown whole), is an error."""
    from strings_bench.core.errors import StringsBenchError

    data = tmp_path / "c.csv"
    data.write_text("method,label,value,mean,min,max,seeds,scenes,per_seed\n"
                    "3dgs,7K,cer,0.3,0.29,0.31,3,3,0.29 0.3 0.31\n3dgs,7K,cer_known,0.2,0.19,0.21,3,3,0.19 0.2 0.21\n"
                    "strings,7K,cer,0.25,0.2,0.3,3,3,0.2 0.25 0.3\nstrings,7K,cer_known,0.15,0.14,0.18,3,3,0.14 0.13 0.18\n")
    page = tmp_path / "p.md"
    out = refresh_text("<!-- table (strings-bench docs refresh): c.csv kind=compare-table table=compare_cer -->\n"
                       "<!-- end table -->", page)
    assert "| STRinGS | _3_ | _3_ | 0.250 (0.200-0.300) **(1)** | n/a | 0.150 (0.140-0.180) **(1)** |" in out
    assert "| 3DGS | _3_ | _3_ | 0.300 (0.290-0.310) (2) | n/a | 0.200 (0.190-0.210) (2) |" in out
    for spec, message in (("table=compare_x", "no table 'compare_x'"), ("where=method:3dgs", "takes no where=")):
        with pytest.raises(StringsBenchError, match=message):
            refresh_text(f"<!-- table (strings-bench docs refresh): c.csv kind=compare-table {spec} -->\n"
                         "<!-- end table -->", page)


def test_markdown_blocks_read_the_table_a_command_printed_under_a_heading(tmp_path):
    from strings_bench.core.errors import StringsBenchError

    (tmp_path / "c.md").write_text("# Comparison\n\n## CER over seeds\n\n| a |\n|---|\n| 0.1 |\n\n## Decided or not\n\n"
                                   "| method | verdict |\n|---|---|\n| 3DGS | decided |\n\ncaption\n\n## Notes\n\nno table\n")
    page = tmp_path / "p.md"

    def block(spec: str) -> str:
        return refresh_text(f"<!-- table (strings-bench docs refresh): c.md kind=markdown {spec} -->\n<!-- end table -->",
                            page)

    assert "| method | verdict |\n|---|---|\n| 3DGS | decided |\n<!-- end table -->" in block("section=decided-or-not")
    assert "| 0.1 |" not in block("section=decided-or-not")
    for spec, message in (("section=per-scene", "no section 'per-scene'"), ("section=notes", "holds no Markdown table"),
                          ("section=decided-or-not where=method:3DGS", "no where="), ("", "section=SLUG")):
        with pytest.raises(StringsBenchError, match=message):
            block(spec)


def test_csv_format_rounds_a_machine_written_column_and_a_repeated_header_is_an_error(tmp_path):
    from strings_bench.core.errors import StringsBenchError

    (tmp_path / "d.csv").write_text("run,step,p90,share\nstrings,100,18.54575884301866,0.4189\n")
    page = tmp_path / "p.md"
    out = refresh_text("<!-- table (strings-bench docs refresh): d.csv format=p90:.1f format=share:.1% -->\n"
                       "<!-- end table -->", page)
    assert "| strings | 100 | 18.5 | 41.9% |" in out
    with pytest.raises(StringsBenchError, match="not a number format"):
        refresh_text("<!-- table (strings-bench docs refresh): d.csv format=p90:.1q -->\n<!-- end table -->", page)
    (tmp_path / "twice.csv").write_text("step,p90,p90\n100,18.1,18.6\n")  # a dict row would keep 18.6 alone
    with pytest.raises(StringsBenchError, match="names 'p90' twice"):
        refresh_text("<!-- table (strings-bench docs refresh): twice.csv -->\n<!-- end table -->", page)


def test_cli_reference_names_every_option():
    reference = cli_reference()
    missing = [f"{name} {opt}" for name, p in cli_parsers(build_parser()) for a in p._actions
               for opt in a.option_strings if opt not in ("-h", "--help") and f"`{opt}`" not in reference]
    assert not missing, missing


def _csv_columns() -> list[str]:
    for module in ("strings_bench.reports.results", "strings_bench.store.results", "strings_bench.store"):
        try:
            return list(importlib.import_module(module).CSV_COLUMNS)
        except (ImportError, AttributeError):
            continue
    raise AssertionError("no module defines results.csv's CSV_COLUMNS")


def test_run_folder_page_documents_every_results_column():
    page = (DOCS / "guide" / "run-folder.md").read_text(encoding="utf-8")
    missing = [c for c in _csv_columns() if f"`{c}`" not in page]
    assert not missing, f"docs/guide/run-folder.md does not document {missing}"


def test_paper_figures_in_sources_match_the_method_specs():
    """docs/sources.md's table of the paper's headline figures (generated from its CSV) and the figures the reports
    print beside the measured ones (each method spec's `paper_figures`) are the same numbers."""
    import csv

    from strings_bench.methods.registry import list_methods

    rows = {r["method"]: r for r in csv.DictReader((DOCS / "results" / "data" / "paper" / "headline.csv").open())}
    specs = {s.title or s.name: s.paper_figures for s in list_methods() if s.paper_figures and not s.ablation_of}
    assert set(rows) == set(specs)
    columns = {"CER TandT 7K/30K": ("tandt", "cer"), "CER DL3DV 7K/30K": ("dl3dv", "cer"),
               "CER STRinGS-360 7K/30K": ("strings360", "cer"), "minutes 7K/30K (STRinGS-360)": ("strings360", "minutes")}
    for title, figures in specs.items():
        for column, (dataset, metric) in columns.items():
            at7, at30 = (float(v) for v in rows[title][column].split("/"))
            assert (at7, at30) == (figures.get(dataset, metric, 7000), figures.get(dataset, metric, 30000)), (title, column)


def test_pages_have_generated_blocks():
    """The block finder finds the README's table and every results page's (a broken marker would hide them all)."""
    from strings_bench.reports.doc_tables import blocks

    for page in [ROOT / "README.md", DOCS / "results" / "default-run.md"]:
        assert blocks(page.read_text(encoding="utf-8")), page


def test_a_marker_without_its_end_is_an_error(tmp_path):
    from strings_bench.core.errors import StringsBenchError

    (tmp_path / "t.csv").write_text("a,b\n1,2\n")
    with pytest.raises(StringsBenchError, match="table markers"):
        refresh_text("<!-- table (strings-bench docs refresh): t.csv -->\n| a | b |\n", tmp_path / "p.md")


def test_a_row_with_more_fields_than_its_header_is_an_error(tmp_path):
    """An unquoted comma in a value (a label such as `--text-px 10,16`) shifts every later column of its row: the
    table is refused, naming the line; quoted, the same value is one field."""
    from strings_bench.core.errors import StringsBenchError

    page = tmp_path / "p.md"
    block = "<!-- table (strings-bench docs refresh): t.csv -->\n<!-- end table -->\n"
    (tmp_path / "t.csv").write_text("scene,rho\nroom --text-px 10,16,0.054\n")
    with pytest.raises(StringsBenchError, match="line 2: 3 fields where the header has 2"):
        refresh_text(block, page)
    (tmp_path / "t.csv").write_text('scene,rho\n"room --text-px 10,16",0.054\n')
    assert "| room --text-px 10,16 | 0.054 |" in refresh_text(block, page)
