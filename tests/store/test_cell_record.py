"""One cell record (store/cells.py): `CellRecord` and `write_cell`, which the runner and `evaluate` both call."""

from __future__ import annotations

import json

import numpy as np
import pytest

from strings_bench.core.errors import StringsBenchError
from strings_bench.store import (RESULT_FILE, WORDS_FILE, CellConfig, CellRecord, cell_row, iter_cells, render_file_name,
                                           write_cell)


def _record(**kw) -> CellRecord:
    scores = {"metrics": {"psnr": 31.5, "ssim": 0.91, "lpips": float("nan")},
              "cer": {"cer": 0.25, "errors": 1, "chars": 4, "images": {"v.png": {}}}, "cer_known": None}
    base = dict(method="m", dataset="d", scene="s", iteration=35, label="7K",
                config=CellConfig(schedule="tiny", downscale=1.0), timings={"train_seconds": 2.0, "eval_seconds": 0.5},
                scores=scores, gaussians=1200, extra={"steps_scale": 0.005})
    return CellRecord(**{**base, **kw})


def test_render_file_name_keeps_sub_folders_apart():
    assert render_file_name("view_000.png") == "view_000.png"
    assert render_file_name("left/0001.jpg") == "left_0001.png" != render_file_name("right/0001.jpg")
    assert render_file_name("a.b.JPG") == "a.b.png"


def test_write_cell_writes_renders_then_result_json_and_reads_back(tmp_path):
    cell = tmp_path / "cells" / "m" / "d" / "s" / "35"
    img = np.full((4, 6, 3), 0.5, np.float32)
    rec = write_cell(cell, _record(), {"left/0001.jpg": img})
    assert (cell / "renders" / "left_0001.png").is_file()
    on_disk = json.loads((cell / RESULT_FILE).read_text())
    assert on_disk == rec and on_disk["evaluation"] == "full" and on_disk["metrics"]["lpips"] is None  # NaN as null
    (read,) = list(iter_cells(tmp_path))
    row = cell_row(read)
    assert (row["cer"], row["psnr"], row["gaussians"], row["label"]) == (0.25, 31.5, 1200, "7K")
    assert not (cell / WORDS_FILE).exists()  # no word-crop readability in this record: no words.csv


def test_a_malformed_record_is_refused_before_anything_is_written(tmp_path):
    cell = tmp_path / "cell"
    bad = _record(scores={"metrics": {"psnr": "high"}, "cer": {"cer": 0.1}})
    with pytest.raises(StringsBenchError, match="metrics.psnr"):
        write_cell(cell, bad, {"v.png": np.zeros((2, 2, 3), np.float32)})
    assert not cell.exists()


def test_versions_name_the_git_commit_of_the_code_and_whether_it_was_modified(tmp_path):
    """A cell's versions trace it to the commit that made it: git's HEAD of the checkout holding the package, and
    whether the package's files differ from it; nothing outside a git checkout."""
    import shutil
    import subprocess

    from strings_bench.bench.records import source_revision

    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    pkg = tmp_path / "repo" / "pkg"
    pkg.mkdir(parents=True)
    (pkg / "mod.py").write_text("x = 1\n")
    (tmp_path / "repo" / "other.txt").write_text("a\n")

    def git(*args):
        return subprocess.run(["git", "-C", str(tmp_path / "repo"), "-c", "user.name=t", "-c", "user.email=t@t",
                               *args], check=True, capture_output=True, text=True).stdout.strip()

    git("init", "-q")
    git("add", ".")
    git("commit", "-q", "-m", "one")
    head = git("rev-parse", "HEAD")
    assert source_revision.__wrapped__(str(pkg)) == {"source_commit": head, "source_modified": False}
    (tmp_path / "repo" / "other.txt").write_text("b\n")  # outside the package: not the code that ran
    (pkg / "new.py").write_text("")  # untracked: not imported by anything committed
    assert source_revision.__wrapped__(str(pkg))["source_modified"] is False
    (pkg / "mod.py").write_text("x = 2\n")
    assert source_revision.__wrapped__(str(pkg)) == {"source_commit": head, "source_modified": True}
    outside = tmp_path / "plain"
    outside.mkdir()
    assert source_revision.__wrapped__(str(outside)) == {}
    installed = tmp_path / "repo" / "venv" / "site-packages" / "pkg"  # a wheel installed inside some repository
    installed.mkdir(parents=True)
    (installed / "mod.py").write_text("x = 1\n")
    assert source_revision.__wrapped__(str(installed)) == {}
