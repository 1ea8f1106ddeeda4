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


def test_the_readme_paragraph_names_the_cpus_kind_when_the_record_has_it(speed, tmp_path):
    ms = [speed.measure("demo from a fresh clone, set-up (its last line)", 62.0, 41.0, "s"),
          speed.measure("demo from a fresh clone, run (its last line)", 289.0, 233.0, "s"),
          speed.measure("default test suite, fresh clone: the tests (pytest's seconds)", 520.0, 471.4, "s"),
          speed.measure("default test suite, fresh clone: set-up (scripts/test.sh less the tests)", 80.0, 77.0, "s")]
    kind = {"vendor": "AuthenticAMD", "family": "25", "model": "1", "vector_isa": "AVX2"}
    rec = tmp_path / "record.json"
    rec.write_text(json.dumps({"machine": {"cpu": "AMD EPYC", "cpu_kind": kind, "cores": 2}, "measures": ms}))
    readme = tmp_path / "readme.csv"
    speed.summarize_record(rec, None, readme)
    text = list(csv.DictReader(readme.open()))[0]["text"]
    assert text.startswith("Measured from fresh clones on a 2-core AMD EPYC (family 25, model 1, AVX2): ")


def test_the_cpus_kind_is_read_from_the_first_processor(speed, tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
                    "flags\t\t: fpu sse2 avx2 avx512f\n\nprocessor\t: 1\nvendor_id\t: Other\ncpu family\t: 1\n")
    assert speed.cpu_kind(info) == {"vendor": "AuthenticAMD", "family": "26", "model": "2", "vector_isa": "AVX-512"}
    info.write_text("vendor_id\t: GenuineIntel\ncpu family\t: 6\nmodel\t\t: 143\nflags\t\t: sse2 avx2\n")
    assert speed.cpu_kind(info)["vector_isa"] == "AVX2"
    assert speed.cpu_kind(tmp_path / "absent") == {}


def test_a_record_without_the_demo_gives_no_readme_paragraph(speed, tmp_path):
    rec = tmp_path / "record.json"
    rec.write_text(json.dumps({"finished_utc": "2025-03-14 09:30", "machine": {"cpu": "AMD EPYC", "cores": 2},
                               "measures": [speed.measure("default run, training", 1.0, 1.0, "s")]}))
    with pytest.raises(SystemExit, match="no demo or test-suite measure"):
        speed.summarize_record(rec, None, tmp_path / "readme.csv")


def _run_folder(path, room, cer):
    cell = path / "cells" / "3dgs" / "d" / "s" / "150"
    cell.mkdir(parents=True)
    cell.joinpath("result.json").write_text(json.dumps({"config": {"scene": {"path": f"/scenes/{room}"}}, "cer": cer}))
    path.joinpath("results.csv").write_text(f"method,dataset,scene,iteration,cer,train_seconds\n3dgs,d,s,150,{cer},1.5\n")
    return path


def test_figures_count_against_the_reference_arm_and_the_banked_ones_only_where_the_room_differs(speed, tmp_path,
                                                                                                   capsys):
    banked = tmp_path / "banked.csv"
    banked.write_text("method,dataset,scene,iteration,cer,train_seconds\n3dgs,d,s,150,0.25,9.0\n")
    same = tmp_path / "same"
    rows = {"reference": speed.read_csv(_run_folder(same / "run-reference", "room-a", 0.5) / "results.csv"),
            "new": speed.read_csv(_run_folder(same / "run-new", "room-a", 0.5) / "results.csv")}
    diffs, against = speed.check_figures(same, rows, "abc1234", banked, "banked.csv")
    out = capsys.readouterr().out
    assert diffs == [] and against == "the reference's (abc1234)"  # the banked figures are another machine's
    assert "1 difference(s), in cer (not counted above)" in out and "cer: banked '0.25', new '0.5'" in out
    other = tmp_path / "other"
    rows = {"reference": speed.read_csv(_run_folder(other / "run-reference", "room-old", 0.4) / "results.csv"),
            "new": speed.read_csv(_run_folder(other / "run-new", "room-a", 0.5) / "results.csv")}
    diffs, against = speed.check_figures(other, rows, "abc1234", banked, "banked.csv")
    assert against == "the banked banked.csv" and len(diffs) == 1 and "cer" in diffs[0]
    # the reference arm's run differing from the new one's counts
    (same / "run-new" / "results.csv").write_text("method,dataset,scene,iteration,cer,train_seconds\n3dgs,d,s,150,0.75,1.5\n")
    rows = {"reference": speed.read_csv(same / "run-reference" / "results.csv"),
            "new": speed.read_csv(same / "run-new" / "results.csv")}
    diffs, _ = speed.check_figures(same, rows, "abc1234", banked, "banked.csv")
    assert len(diffs) == 1 and "reference '0.5', new '0.75'" in diffs[0]


def test_waiting_notes_each_runs_own_wall_time_and_samples_the_load_meanwhile(speed, monkeypatch):
    import subprocess
    import sys
    import time

    monkeypatch.setattr(speed.os, "getloadavg", lambda: (1.5, 0.0, 0.0))
    t = time.perf_counter()
    procs = {"short": subprocess.Popen([sys.executable, "-c", "pass"]),
             "long": subprocess.Popen([sys.executable, "-c", "import time; time.sleep(1.2)"])}
    t0, wall, loads = {"short": t, "long": t}, {}, []
    speed.wait_sampling_load(procs, t0, wall, loads, every_s=0.3)
    assert set(wall) == {"short", "long"} and wall["short"] < wall["long"]
    assert 1.2 <= wall["long"] < 1.2 + 1.0  # noted when it ended, not at the next load sample
    assert len(loads) >= 3 and set(loads) == {1.5}  # a sequential run is sampled too, not left without a load
