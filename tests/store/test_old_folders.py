"""A run folder written before issue 41 (by 99adc95, when "preset" named the run's schedule) is read as today's:
run.json, result.json's config and results.csv's column go through the readers of the store (strings_bench/store/).

tests/data/run_99adc95/ was written by 99adc95's own code: `bench.run(["fake-a"], [toy scene], schedule="tiny",
ocr="fake", checkpoints=[7000])` with tests/runner_fakes.py (one cell, fake-a at 7K = 35 steps)."""

from __future__ import annotations

import strings_bench.bench as bench

import csv
import shutil
from pathlib import Path

import pytest

import runner_fakes as rf
import strings_bench.bench.runner as runner
from strings_bench.core.errors import StringsBenchError
from strings_bench.store import cell_row, iter_cells, read_manifest, upgrade_names, write_results_csv
from strings_bench.reports.aggregate import load_results

OLD = Path(__file__).resolve().parents[1] / "data" / "run_99adc95"


@pytest.fixture
def old_run(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(OLD, run)
    return run


def test_the_fixture_is_in_the_former_names():
    assert '"preset": {' in (OLD / "run.json").read_text() and '"schedule"' not in (OLD / "run.json").read_text()
    with open(OLD / "results.csv", newline="") as f:
        header = next(csv.reader(f))
    assert "preset" in header and "schedule" not in header


def test_old_run_json_result_json_and_results_csv_read_as_today(old_run):
    m = read_manifest(old_run)
    assert m["schedule"]["name"] == "tiny" and m["schedule"]["steps_scale"] == 0.005 and "preset" not in m
    (rec,) = list(iter_cells(old_run))
    row = cell_row(rec)
    assert row["schedule"] == "tiny" and "preset" not in row and row["label"] == "7K" and row["iteration"] == 35
    df = load_results(old_run)  # the old results.csv as it is, not rebuilt
    assert list(df["schedule"]) == ["tiny"] and "preset" not in df
    write_results_csv(old_run)  # rebuilt from the old cells: today's column
    with open(old_run / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["schedule"] == "tiny" and "preset" not in rows[0]
    assert upgrade_names({"preset": "a", "schedule": "b"}) == {"schedule": "b"}  # today's name wins


def test_old_folder_resumes_under_its_schedule_and_refuses_another(old_run, tmp_path):
    rf.register_fakes()
    scene = rf.make_scene(tmp_path / "scenes", glyphs=True)
    kw = dict(run_dir=old_run, ocr="fake", checkpoints=[7000], ocr_backend=rf.FakeOCR(), with_lpips=False,
              progress=False, write_report=False)
    with pytest.raises(StringsBenchError, match="schedule 'tiny'"):
        bench.run(["fake-a"], [str(scene)], schedule="quick", **kw)
    rf.CALLS["train"].clear()
    bench.run(["fake-a"], [str(scene)], schedule="tiny", **kw)  # resumes: the cell is finished, nothing trains
    assert rf.CALLS["train"] == []
    assert '"schedule": {' in (old_run / "run.json").read_text()
    from strings_bench.reports import write_report

    report = write_report(old_run).read_text()
    assert "Schedule **tiny**" in report
