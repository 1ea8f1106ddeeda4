"""Dense checkpoints (issue 30): `run --checkpoints every:N`, evaluated cheaply, for time to legibility."""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.core.results import CellKey

import argparse
import csv
import json

import pytest

import runner_fakes as rf
import strings_bench.bench.runner as runner
from strings_bench.core.schedules import schedule
from strings_bench.cli.run import parse_checkpoints
from strings_bench.core.errors import StringsBenchError


def test_every_n_adds_checkpoints_up_to_the_last():
    p = schedule("tiny", checkpoints=[3000, 7000], dense_every=1000)  # tiny: x0.005
    assert p.dense_paper_checkpoints() == [1000, 2000, 3000, 4000, 5000, 6000, 7000]
    assert p.checkpoints() == [5, 10, 15, 20, 25, 30, 35]
    assert p.dense_checkpoints() == [5, 10, 20, 25, 30]  # 15 and 35 are the paper checkpoints 3K and 7K
    assert [p.label_of(i) for i in p.checkpoints()] == ["1K", "2K", "3K", "4K", "5K", "6K", "7K"]
    q = schedule("early", dense_every=500)  # early: 3K/7K at x0.15
    assert len(q.checkpoints()) == 14 and q.label_of(75) == "500" and q.label_of(1050) == "7K"
    assert schedule("early").dense_checkpoints() == []
    with pytest.raises(StringsBenchError, match="every:N"):
        schedule("early", dense_every=0)


def test_parse_checkpoints_every():
    assert parse_checkpoints("every:500") == [("every", 500)]
    assert parse_checkpoints("3K,7K,every:1k") == [3000, 7000, ("every", 1000)]
    for bad in ("every:", "every:x", "every:500,every:1K", "every:-5"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_checkpoints(bad)


def test_cli_every_reaches_the_run_config():
    from strings_bench.cli import build_parser
    from strings_bench.cli.run import run_config

    args = build_parser().parse_args(["run", "--checkpoints", "3K,every:500", "--dense-eval", "full"])
    c = run_config(args)
    assert (list(c.checkpoints), c.dense_every, c.dense_eval) == ([3000], 500, "full")
    c = run_config(build_parser().parse_args(["run", "--checkpoints", "every:500"]))
    assert (c.checkpoints, c.dense_every, c.dense_eval) == (None, 500, "words")


def _rows(out):
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_dense_checkpoints_get_word_crop_metrics_only_and_gt_is_read_once(tmp_path, scene_dir):
    rf.register_fakes()
    ocr = rf.FakeOCR()
    out = tmp_path / "run"
    bench.run(["fake-a", "fake-b"], [str(scene_dir)], run_dir=out, schedule="tiny", checkpoints=[3000, 7000],
               dense_every=1000, ocr="fake", ocr_backend=ocr, with_lpips=False, progress=False)
    rows = _rows(out)
    assert len(rows) == 2 * 7
    for r in rows:
        dense = int(r["iteration"]) in (5, 10, 20, 25, 30)
        assert r["evaluation"] == ("words" if dense else "full")
        assert (r["cer"] == "") == dense  # no OCR of the renders at a dense checkpoint
        assert r["word_cer"] != "" and r["psnr"] != ""  # word-crop metrics and PSNR at every checkpoint
        rec = json.loads((CellKey(r["method"], r["dataset"], r["scene"], int(r["iteration"])).path(out)
                          / "result.json").read_text())
        assert rec["evaluation"] == r["evaluation"]
    # OCR reads: each of the 2 GT views once for the whole scene (both methods' jobs share the GT side), and the
    # 2 render views of each of the 2 x 2 fully evaluated cells; none at the 10 dense cells.
    assert ocr.calls == 2 + 2 * 2 * 2
    # The report's checkpoint columns are the fully evaluated ones; the dense ones feed time to legibility.
    md = (out / "report" / "tables" / "ocr_cer.md").read_text()
    assert "3K" in md and "7K" in md and "1K" not in md and "5K" not in md
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["dense_every"] == 1000 and manifest["dense_eval"] == "words"
    # Resuming with another dense schedule is refused.
    with pytest.raises(StringsBenchError, match="every:N"):
        bench.run(["fake-a"], [str(scene_dir)], run_dir=out, schedule="tiny", checkpoints=[3000, 7000],
                   dense_every=500, ocr="fake", ocr_backend=ocr, with_lpips=False, progress=False)


def test_dense_eval_full_evaluates_every_checkpoint(tmp_path, scene_dir):
    rf.register_fakes()
    ocr = rf.FakeOCR()
    out = tmp_path / "run"
    bench.run(["fake-a"], [str(scene_dir)], run_dir=out, schedule="tiny", checkpoints=[3000], dense_every=1000,
               dense_eval="full", ocr="fake", ocr_backend=ocr, with_lpips=False, progress=False, write_report=False)
    rows = _rows(out)
    assert [r["label"] for r in rows] == ["1K", "2K", "3K"]
    assert all(r["evaluation"] == "full" and r["cer"] != "" for r in rows)
    assert ocr.calls == 2 + 3 * 2


def test_dense_checkpoints_do_not_change_the_fully_evaluated_cells(tmp_path, scene_dir):
    """Evaluating at the extra checkpoints of every:N must leave training alone: a real 3DGS trained with and
    without them gives the same figures at the shared checkpoints (the CPU engine is deterministic)."""
    rf.register_fakes()
    kw = dict(schedule="tiny", checkpoints=[3000, 7000], ocr="fake", with_lpips=False, progress=False,
              write_report=False)
    bench.run(["3dgs"], [str(scene_dir)], run_dir=tmp_path / "plain", ocr_backend=rf.FakeOCR(), **kw)
    bench.run(["3dgs"], [str(scene_dir)], run_dir=tmp_path / "dense", ocr_backend=rf.FakeOCR(), dense_every=1000,
               **kw)
    plain = {r["iteration"]: r for r in _rows(tmp_path / "plain")}
    dense = {r["iteration"]: r for r in _rows(tmp_path / "dense")}
    assert len(dense) > len(plain) == 2
    for it, r in plain.items():
        for col in ("psnr", "ssim", "gaussians", "word_cer", "cer", "text_nll"):
            assert dense[it][col] == r[col], (it, col)
