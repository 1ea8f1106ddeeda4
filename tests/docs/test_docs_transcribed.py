"""`docs refresh --check` holds the results to derived tables: it fails when a page outside docs/history/ has a table
read from a transcribed CSV (a `data/tables/` folder, or anything under docs/history/), when a page outside
docs/history/ carries the history mark, and when a page under docs/history/ lacks it; the same checkout with the
section moved to a marked history page passes."""

from __future__ import annotations

from pathlib import Path

from strings_bench.cli import main
from strings_bench.cli.docs import (HISTORY_MARK, misplaced_history_pages, refresh, transcribed_reads,
                                    unmarked_history_pages)

ROOT = Path(__file__).resolve().parents[2]
MARK = f"{HISTORY_MARK} transcribed -->\n"


def _table(data: str) -> str:
    return f"<!-- table (strings-bench docs refresh): {data} -->\n| a |\n|---|\n| 1 |\n<!-- end table -->\n"


def _checkout(tmp_path: Path, pages: dict[str, str]) -> Path:
    """A source checkout with a machine-written CSV (data/study/out.csv), a transcribed one in each place one may
    lie (docs/results/data/tables/, docs/history/data/tables/) and the given pages."""
    root = tmp_path / "repo"
    for csv_path in ("docs/results/data/study/out.csv", "docs/results/data/tables/t.csv",
                     "docs/history/data/tables/t.csv", "docs/history/old.csv"):
        (root / csv_path).parent.mkdir(parents=True, exist_ok=True)
        (root / csv_path).write_text("a\n1\n")
    for name, text in pages.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    refresh(root)  # the CLI reference, so that only the rule can fail the check
    return root


def _check(root: Path, capsys) -> tuple[int, str]:
    status = main(["docs", "refresh", "--check", "--root", str(root)])
    return status, capsys.readouterr().out


def test_this_checkout_keeps_the_rule():
    assert transcribed_reads(ROOT) == []
    assert misplaced_history_pages(ROOT) == []
    assert unmarked_history_pages(ROOT) == []
    assert not (ROOT / "docs/results/data/tables").exists()


def test_derived_results_and_a_marked_history_page_pass(tmp_path, capsys):
    root = _checkout(tmp_path, {
        "docs/results/page.md": "# A study\n\n" + _table("data/study/out.csv"),
        "docs/history/page.md": "# A study (history)\n\n" + MARK + "\n" + _table("data/tables/t.csv"),
        "docs/history/README.md": "# History pages\n\n[page](page.md)\n",
    })
    assert _check(root, capsys)[0] == 0


def test_a_results_table_read_from_a_transcribed_csv_fails(tmp_path, capsys):
    root = _checkout(tmp_path, {"docs/results/page.md": "# A study\n\n" + _table("data/tables/t.csv")})
    assert transcribed_reads(root) == [(root / "docs/results/page.md", "data/tables/t.csv")]
    status, out = _check(root, capsys)
    assert status == 1 and "docs/results/page.md: a table reads data/tables/t.csv, a transcribed CSV" in out


def test_a_results_table_read_from_the_history_folder_fails(tmp_path, capsys):
    """Anything under docs/history/ is transcribed, in data/tables/ or not."""
    for data in ("../history/data/tables/t.csv", "../history/old.csv"):
        root = _checkout(tmp_path / data.replace("/", "_"), {"docs/results/page.md": "# A study\n\n" + _table(data)})
        assert transcribed_reads(root) == [(root / "docs/results/page.md", data)]
        assert _check(root, capsys)[0] == 1


def test_the_history_mark_does_not_excuse_a_results_page(tmp_path, capsys):
    """A results page marked history once passed the check; now it fails twice: the read, and the mark."""
    root = _checkout(tmp_path, {"docs/results/page.md": "# A study\n\n" + MARK + "\n" + _table("data/tables/t.csv")})
    assert misplaced_history_pages(root) == [root / "docs/results/page.md"]
    assert len(transcribed_reads(root)) == 1
    status, out = _check(root, capsys)
    assert status == 1 and "a history page outside docs/history/" in out


def test_a_history_mark_under_docs_results_fails_even_without_a_table(tmp_path, capsys):
    root = _checkout(tmp_path, {"docs/results/page.md": "# A study\n\n" + MARK + "\nProse only.\n"})
    assert _check(root, capsys)[0] == 1


def test_a_history_page_without_its_mark_fails(tmp_path, capsys):
    root = _checkout(tmp_path, {"docs/history/page.md": "# A study\n\n" + _table("data/tables/t.csv")})
    assert unmarked_history_pages(root) == [root / "docs/history/page.md"]
    status, out = _check(root, capsys)
    assert status == 1 and "without the history mark" in out


def test_the_mark_counts_only_at_the_top_of_a_page(tmp_path):
    root = _checkout(tmp_path, {"docs/history/page.md": "# A study\n\n" + _table("data/tables/t.csv") + "\n" * 6
                                + MARK})
    assert unmarked_history_pages(root) == [root / "docs/history/page.md"]
