"""tools/evaluation_split.py's parts that need no evaluation: the time some interval covers, a run folder's cells in
the order they were written, and the table with its floor."""

from __future__ import annotations

import json
import math
import os

import pytest

from _scripts import load_tool  # noqa: E402


@pytest.fixture(scope="module")
def split():
    return load_tool("evaluation_split")


def test_union_of_intervals_counts_overlaps_once(split):
    assert split.union_seconds([]) == 0.0
    assert split.union_seconds([(0.0, 1.0)]) == 1.0
    # two reads at once count once; a call inside another adds nothing; a gap adds nothing
    assert split.union_seconds([(0.0, 1.0), (0.5, 2.0), (0.6, 0.9), (3.0, 4.5)]) == pytest.approx(3.5)
    assert split.union_seconds([(3.0, 4.0), (0.0, 1.0)]) == pytest.approx(2.0)  # any order


def test_overlap_counts_only_the_time_two_intervals_ran_at_once(split):
    assert split.overlap_seconds([]) == 0.0
    assert split.overlap_seconds([(0.0, 1.0)]) == 0.0
    assert split.overlap_seconds([(0.0, 1.0), (0.5, 2.0), (3.0, 4.0)]) == pytest.approx(0.5)
    assert split.overlap_seconds([(0.0, 4.0), (1.0, 2.0), (1.5, 3.0)]) == pytest.approx(2.0)  # 1-3: two or three
    assert split.overlap_seconds([(0.0, 4.0), (1.0, 2.0), (1.5, 3.0)], at_least=3) == pytest.approx(0.5)


def _cell(run, method, label, iteration, lpips, mtime, evaluation="full", scene_path="/scenes/room"):
    d = run / "cells" / method / "synthetic360-cpu" / "room" / str(iteration)
    (d / "renders").mkdir(parents=True)
    rec = {"method": method, "label": label, "scene": "room", "evaluation": evaluation,
           "metrics": {"lpips": lpips}, "config": {"scene": {"path": scene_path, "settings": {}}, "downscale": 1.0,
                                                    "cer_profile": "paper"}}
    (d / "result.json").write_text(json.dumps(rec), encoding="utf-8")
    os.utime(d / "result.json", (mtime, mtime))


def test_run_cells_in_the_order_written_with_lpips_where_the_run_scored_it(split, tmp_path):
    _cell(tmp_path, "3dgs", "3K", 150, None, 300)
    _cell(tmp_path, "strings", "3K", 150, None, 100)
    _cell(tmp_path, "strings", "30K", 1500, 0.41, 200)
    _cell(tmp_path, "3dgs", "30K", 1500, math.nan, 400)  # NaN: LPIPS was not scored
    _cell(tmp_path, "3dgs", "dense", 160, None, 50, evaluation="words")  # a dense checkpoint: left out
    cells = split.run_cells(tmp_path)
    assert [c["name"] for c in cells] == ["strings 3K", "strings 30K", "3dgs 3K", "3dgs 30K"]
    assert [c["lpips"] for c in cells] == [False, True, False, False]
    assert cells[0]["scene_path"] == "/scenes/room" and cells[0]["renders"].endswith("strings/synthetic360-cpu/room/150/renders")


def test_run_cells_refuses_an_empty_run_and_one_of_several_scenes(split, tmp_path):
    with pytest.raises(SystemExit, match="no evaluated cell"):
        split.run_cells(tmp_path)
    _cell(tmp_path, "3dgs", "3K", 150, None, 100)
    _cell(tmp_path, "strings", "3K", 150, None, 200, scene_path="/scenes/other")
    with pytest.raises(SystemExit, match="several scenes"):
        split.run_cells(tmp_path)


def test_table_gives_each_ratio_and_the_floor_against_the_reference_evaluation(split):
    ref = {"evaluation": 80.0, "read_views": 40.0, "readability": 20.0, "view_metrics": 16.0, "inference": 58.0,
           "inference_two_at_once": 10.0, "cpu": 100.0}
    new = {"evaluation": 60.0, "read_views": 34.0, "readability": 15.0, "view_metrics": 7.0, "inference": 48.0,
           "inference_two_at_once": 12.0, "cpu": 90.0}
    rows = split.table_rows({"reference": ref, "new": new}, 2)
    assert rows[0][0] == "measure (median of 2)"
    assert rows[1][1:] == ("80.0 s", "60.0 s", "0.75x")
    assert rows[-1][-1] == "0.60x"  # 48 s of inference against the reference's 80 s of evaluation
    assert rows[-2][1:3] == ("1.25", "1.50")  # CPU seconds per second of evaluation: how many of the cores it kept busy
