"""`docs refresh --check` fails when a page that is not a history page has a table read from a transcribed CSV
(docs/results/data/tables/: tables once typed by hand), and passes the same page once it is marked a history page."""

from __future__ import annotations

from pathlib import Path

from strings_bench.cli import main
from strings_bench.cli.docs import HISTORY_MARK, refresh, transcribed_reads

ROOT = Path(__file__).resolve().parents[2]
TABLE = "<!-- table (strings-bench docs refresh): data/tables/t.csv -->\n| a |\n|---|\n| 1 |\n<!-- end table -->\n"


def _checkout(tmp_path: Path, page_text: str) -> Path:
    root = tmp_path / "repo"
    (root / "docs/results/data/tables").mkdir(parents=True)
    (root / "docs/results/data/tables/t.csv").write_text("a\n1\n")
    (root / "docs/results/page.md").write_text(page_text)
    refresh(root)  # the CLI reference, so that only the transcribed read can fail the check
    return root


def test_no_page_but_history_pages_reads_a_transcribed_csv():
    assert transcribed_reads(ROOT) == []


def test_check_fails_on_a_results_table_read_from_a_transcribed_csv(tmp_path, capsys):
    root = _checkout(tmp_path, "# A study\n\n" + TABLE)
    assert transcribed_reads(root) == [(root / "docs/results/page.md", "data/tables/t.csv")]
    assert main(["docs", "refresh", "--check", "--root", str(root)]) == 1
    assert "transcribed" in capsys.readouterr().out


def test_a_history_page_may_read_one(tmp_path):
    root = _checkout(tmp_path, f"# A study\n\n{HISTORY_MARK} transcribed -->\n\n" + TABLE)
    assert transcribed_reads(root) == []
    assert main(["docs", "refresh", "--check", "--root", str(root)]) == 0


def test_the_mark_counts_only_at_the_top_of_a_page(tmp_path):
    root = _checkout(tmp_path, "# A study\n\n" + TABLE + "\n" * 6 + f"{HISTORY_MARK} late -->\n")
    assert len(transcribed_reads(root)) == 1
