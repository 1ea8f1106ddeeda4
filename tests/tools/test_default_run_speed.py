"""tools/default_run_speed.py's parts that need no run: pytest's summary line read back, each goal judged on the
side its ratio is stated, and a banked record turned into the docs' table and the README's paragraph."""

from __future__ import annotations

import csv
import json

import pytest

from _scripts import load_tool  # noqa: E402


@pytest.fixture(scope="module")
def speed():
    return load_tool("default_run_speed")


def test_pytest_summary_reads_the_last_summary_line(speed):
    out = ("..... [ 99%]\n= 3 passed in 1.00s =\nmore output\n"
           "2 failed, 1569 passed, 1 skipped, 3 warnings in 498.20s (0:08:18)\n")
    assert speed.pytest_summary(out) == {"seconds": 498.2, "failed": 2, "passed": 1569, "skipped": 1, "warnings": 3}
    assert speed.pytest_summary("no summary here") is None


@pytest.mark.parametrize("ref,new,goal,ratio,met", [
    (58.3, 29.0, ("new/ref", 0.5), 29.0 / 58.3, True),
    (58.3, 30.0, ("new/ref", 0.5), 30.0 / 58.3, False),
    (255.0, 120.0, ("ref/new", 2.0), 255.0 / 120.0, True),
    (255.0, 168.0, ("ref/new", 2.0), 255.0 / 168.0, False),
    (351.0, 300.0, ("new<=", 300), 300.0 / 351.0, True),
    (351.0, 301.0, ("new<=", 300), 301.0 / 351.0, False),
    (None, 40.0, ("new<=", 480), None, True),
])
def test_each_goal_is_judged_on_its_own_side(speed, ref, new, goal, ratio, met):
    m = speed.measure("x", ref, new, "s", goal=goal)
    assert m["met"] is met
    assert m["ratio"] == (None if ratio is None else pytest.approx(ratio))
    assert m["ratio_kind"] == ("reference / new" if goal[0] == "ref/new" else "new / reference")


def test_a_record_gives_the_table_and_the_readme_paragraph_from_its_own_figures(speed, tmp_path):
    ms = [speed.measure("demo from a fresh clone, set-up (its last line)", 62.0, 41.0, "s"),
          speed.measure("demo from a fresh clone, run (its last line)", 289.0, 233.0, "s"),
          speed.measure("demo from a fresh clone, set-up + run", 351.0, 274.0, "s", goal=("new<=", 300)),
          speed.measure("default test suite, fresh clone: the tests (pytest's seconds)", 520.0, 471.4, "s",
                        goal=("new<=", 480), passed={"reference": 1474, "new": 1583}, failed={"reference": 1, "new": 0}),
          speed.measure("default test suite, fresh clone: set-up (scripts/test.sh less the tests)", 80.0, 77.0, "s")]
    rec = tmp_path / "record.json"
    rec.write_text(json.dumps({"finished_utc": "2025-03-14 09:30", "machine": {"cpu": "AMD EPYC", "cores": 2},
                               "measures": ms}))
    table, readme = tmp_path / "table.csv", tmp_path / "readme.csv"
    assert speed.summarize_record(rec, table, readme) == 0
    rows = list(csv.reader(table.open()))
    assert rows[0][:3] == ["measure", "reference", "new"] and len(rows) == 6
    assert rows[3][1:] == ["351 s", "274 s", "0.78x (new / reference)", "<= 300 s", "met"]
    assert rows[4][-1] == "met" and rows[4][2] == "471 s"
    text = list(csv.DictReader(readme.open()))[0]["text"]
    assert text.startswith("Measured from fresh clones on a 2-core AMD EPYC: ")
    assert "41 s of set-up and 233 s of run (274 s in all" in text and "77 s of set-up and 471 s of tests (1 583 passed)" in text


def test_a_record_without_the_demo_gives_no_readme_paragraph(speed, tmp_path):
    rec = tmp_path / "record.json"
    rec.write_text(json.dumps({"finished_utc": "2025-03-14 09:30", "machine": {"cpu": "AMD EPYC", "cores": 2},
                               "measures": [speed.measure("default run, training", 1.0, 1.0, "s")]}))
    with pytest.raises(SystemExit, match="no demo or test-suite measure"):
        speed.summarize_record(rec, None, tmp_path / "readme.csv")
