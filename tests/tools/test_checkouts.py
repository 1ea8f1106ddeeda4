"""tools/checkouts.py: the worktree of an older commit that the side-by-side tools share."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from _scripts import load_tool  # noqa: E402


@pytest.fixture(scope="module")
def checkouts():
    return load_tool("checkouts")


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout.strip()


@pytest.fixture()
def repo(tmp_path):
    r = tmp_path / "repo"
    r.mkdir()
    git(r, "init", "-q")
    for i in (1, 2):
        (r / "f.txt").write_text(f"version {i}\n")
        git(r, "add", "f.txt")
        git(r, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", f"v{i}")
    return r


def test_a_worktree_of_the_commit_is_made_once_and_reused(checkouts, repo, tmp_path, monkeypatch):
    monkeypatch.setattr(checkouts.tempfile, "gettempdir", lambda: str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    first = git(repo, "rev-parse", "HEAD~1")
    path = checkouts.ref_checkout("HEAD~1", repo=repo)
    assert path.name == f"strings-bench-ref-{first[:12]}"  # named by the commit, not by the ref's spelling
    assert (path / "f.txt").read_text() == "version 1\n"
    assert checkouts.head_of(path) == first
    assert checkouts.ref_checkout(first[:7], repo=repo) == path  # the same commit by another name: the same folder


def test_a_given_folder_is_used_as_it_is_but_the_default_one_must_hold_the_commit(checkouts, repo, tmp_path,
                                                                                  monkeypatch):
    where = tmp_path / "elsewhere"
    assert checkouts.ref_checkout("HEAD", where=where, repo=repo) == where.resolve()  # made there when missing
    git(where, "checkout", "-q", "--detach", "HEAD~1")
    assert checkouts.ref_checkout("HEAD", where=where, repo=repo) == where.resolve()  # the user's folder, as given
    monkeypatch.setattr(checkouts.tempfile, "gettempdir", lambda: str(tmp_path))
    sha = git(repo, "rev-parse", "HEAD")
    git(repo, "worktree", "add", "-q", "--detach", str(tmp_path / f"strings-bench-ref-{sha[:12]}"), "HEAD~1")
    with pytest.raises(SystemExit, match="not HEAD"):  # a stale default folder is never timed as the reference
        checkouts.ref_checkout("HEAD", repo=repo)


def test_a_name_that_is_no_commit_is_a_clear_error(checkouts, repo):
    with pytest.raises(SystemExit, match="is not a commit"):
        checkouts.ref_checkout("no-such-branch", repo=repo)
