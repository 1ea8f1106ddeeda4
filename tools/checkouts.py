"""A checkout of an older commit for the tools that time or compare two versions side by side.

    from tools.checkouts import ref_checkout   # python tools/X.py: `from checkouts import ref_checkout`

`ref_checkout(ref)` gives a `git worktree` of `ref` (made once, under the system's temporary folder, named by the
commit it resolves to, so a branch that moved gets a checkout of its own). A folder given as `where` is used as it
is when it exists (e.g. a clone made elsewhere); a worktree found at the path on another commit is an error, not
silently reused.
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def resolve(ref: str, repo: Path = REPO) -> str:
    """The full commit `ref` names in `repo`; a clear error when it names none."""
    out = subprocess.run(["git", "-C", str(repo), "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}"],
                         capture_output=True, text=True)
    if out.returncode != 0 or not out.stdout.strip():
        raise SystemExit(f"{ref!r} is not a commit of {repo} (git rev-parse found none; fetch it or check the name)")
    return out.stdout.strip()


def head_of(path: Path) -> str:
    return subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()


def ref_checkout(ref: str, where: Path | None = None, repo: Path = REPO) -> Path:
    """A checkout of `ref`: `where` if it exists, else a worktree made at `where` or under the temporary folder."""
    if where is not None and Path(where).exists():
        return Path(where).resolve()
    sha = resolve(ref, repo)
    path = Path(where) if where is not None else Path(tempfile.gettempdir()) / f"strings-bench-ref-{sha[:12]}"
    if path.exists():
        if head_of(path) != sha:
            raise SystemExit(f"{path} holds {head_of(path)[:12] or 'no checkout'}, not {ref} ({sha[:12]}); "
                             "remove it (git worktree remove) or pass another folder")
        return path.resolve()
    made = subprocess.run(["git", "-C", str(repo), "worktree", "add", "--detach", str(path), sha],
                          capture_output=True, text=True)
    if made.returncode != 0:
        raise SystemExit(f"git worktree add {path} {sha[:12]} failed: {made.stderr.strip()}")
    return path.resolve()
