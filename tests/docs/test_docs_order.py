"""What happened, in order: the docs' statements on what came before what name their commits, and `git log` agrees.

Each ORDER entry is (page, earlier commit, later commit, why); the test checks that the page names both commits,
that both are in the history, that the earlier is an ancestor of the later and committed no later. FILES_AT lists
files a statement says a commit held. Skipped, saying why, where the clone has no history (shallow, or no git)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

ORDER = (
    ("docs/miniature.md", "1ecaa37", "9211ae4", "provisional agreement scores committed before the rule"),
    ("docs/miniature.md", "56213f9", "ec0a80a", "cpu-long's 7K comparison before the first full-schedule cell"),
    ("docs/miniature.md", "750f26f", "ec0a80a", "cpu-long's 30K comparison before the first full-schedule cell"),
    ("docs/miniature.md", "9211ae4", "4d9095d", "the rule before the freeze"),
    ("docs/results/full-schedule.md", "1ecaa37", "9211ae4", "provisional scores before the rule"),
    ("docs/results/full-schedule.md", "750f26f", "ec0a80a", "cpu-long compared before the first x1 cell"),
    ("docs/results/full-schedule.md", "9211ae4", "4d9095d", "the rule before the freeze"),
)
FILES_AT = (
    ("9211ae4", "docs/results/data/full-schedule/choice.csv"),  # the rule's commit carries a provisional choice
    ("1ecaa37", "docs/results/data/full-schedule/agreement.csv"),  # the provisional agreement scores
)


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True)


@pytest.fixture(scope="module")
def history():
    if shutil.which("git") is None or _git("rev-parse", "--git-dir").returncode != 0:
        pytest.skip("no git repository: the order of commits cannot be checked")
    if _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true":
        pytest.skip("a shallow clone: the commits the docs name are not in it (clone with full history)")
    return True


def _time(commit: str) -> int:
    out = _git("show", "-s", "--format=%ct", commit)
    assert out.returncode == 0, f"commit {commit} is not in the history"
    return int(out.stdout.strip())


@pytest.mark.parametrize("page,earlier,later,why", ORDER, ids=lambda x: x if isinstance(x, str) and len(x) == 7 else "")
def test_the_docs_order_of_events_matches_git(history, page, earlier, later, why):
    text = (ROOT / page).read_text(encoding="utf-8")
    assert earlier in text and later in text, f"{page} no longer names {earlier} and {later} ({why})"
    assert _time(earlier) <= _time(later), f"{earlier} was committed after {later}: {why} is not so"
    assert _git("merge-base", "--is-ancestor", earlier, later).returncode == 0, f"{earlier} is not before {later}"


@pytest.mark.parametrize("commit,path", FILES_AT)
def test_the_files_a_commit_is_said_to_hold_are_in_it(history, commit, path):
    assert _git("cat-file", "-e", f"{commit}:{path}").returncode == 0, f"{commit} holds no {path}"
