"""A run folder written by 142d0ce's code reads, resumes and matches what today's code writes.

tests/data/run_142d0ce/ was written by 142d0ce's own code: `bench.run(["fake-a", "fake-b"], [toy scene],
schedule="tiny", ocr="fake", checkpoints=[3000, 7000], budget="fake-a")` with tests/runner_fakes.py (four cells:
fake-a, the uncapped reference of the budget, and fake-b capped at fake-a's count, at 15 and 35 steps)."""

from __future__ import annotations

import strings_bench.bench as bench

import csv
import json
import shutil
from pathlib import Path

import pytest

import runner_fakes as rf
import strings_bench.bench.runner as runner
from strings_bench.store import cell_row, iter_cells, read_manifest, write_results_csv

OLD = Path(__file__).resolve().parents[1] / "data" / "run_142d0ce"
TIMING = {"train_seconds", "preprocess_seconds", "total_seconds", "train_cpu_seconds", "eval_seconds"}
# Recorded since 142d0ce, checked apart: the scene's rho (a results.csv column and the cell's config.scene entry),
# the scope of the peak memory (a results.csv column and the cell's extra entry; every earlier cell measured the
# process's peak), the training's CPU seconds (a results.csv column and a timing) and the run's miniature (run.json's
# schedule; "shrink" is what every earlier run did).
ADDED_COLUMNS = {"rho", "peak_memory_scope", "train_cpu_seconds"}


# Two values depend on the machine's libraries, not on this code: the text NLL comes from the OCR recogniser's scores
# (onnxruntime, whose kernels follow the host's instruction set with no way to pin them: 0.000369998 on an Intel Xeon
# with AVX-512 against 0.000369354 on the AMD EPYC that wrote the folder), and the SSIMs from a float64 product of
# MKL inside torch's convolution, whose AVX2 branch is Intel's alone (1e-15 apart; docs/reproducibility.md, "Across
# machines: not yet"). Each is compared within its tolerance; every other value exactly.
MACHINE_TOLERANCE = {"nll": 0.01, "ssim": 1e-12}


def _tolerance(key: str) -> float | None:
    return next((tol for part, tol in MACHINE_TOLERANCE.items() if part in key), None)


def _split_machine(x, path=""):
    """(`x` without its machine-dependent entries, {path: (value, relative tolerance)} of those entries)."""
    found = {}
    if isinstance(x, dict):
        kept = {}
        for k, v in x.items():
            tol = _tolerance(k)
            if tol is not None and not isinstance(v, (dict, list)):
                found[f"{path}/{k}"] = (v, tol)
            else:
                kept[k], sub = _split_machine(v, f"{path}/{k}")
                found.update(sub)
        return kept, found
    if isinstance(x, list):
        kept = []
        for i, v in enumerate(x):
            k, sub = _split_machine(v, f"{path}/{i}")
            kept.append(k)
            found.update(sub)
        return kept, found
    return x, found


def _assert_same_up_to_the_machine(new, old):
    new, new_found = _split_machine(new)
    old, old_found = _split_machine(old)
    assert new == old
    assert set(new_found) == set(old_found)
    for k, (v, tol) in old_found.items():
        w = new_found[k][0]
        try:
            a, b = float(w), float(v)  # results.csv holds them as text, result.json as numbers
        except (TypeError, ValueError):  # "" or None: no value on either side
            assert w == v, k
            continue
        assert a == pytest.approx(b, rel=tol, abs=0), k


def _rows(run: Path) -> list[dict]:
    with open(run / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def _untimed(x):
    """`x` without the keys that hold a time (`timings`, and every `*seconds`)."""
    if isinstance(x, dict):
        return {k: _untimed(v) for k, v in x.items() if k != "timings" and not k.endswith("seconds")}
    return [_untimed(v) for v in x] if isinstance(x, list) else x


def _comparable(rec: dict) -> dict:
    """A cell's result.json without what differs from machine to machine or run to run: its timings, the
    versions, where the scene and the weights were."""
    rec = _untimed(json.loads(json.dumps(rec)))
    rec["config"].pop("versions")
    rec["config"]["metrics"].pop("lpips", None)
    rec["config"]["scene"].pop("path")
    return rec


def _todays_names(rec: dict) -> dict:
    """An old cell with the Gaussian budget's keys renamed since 142d0ce as today's code writes them: the budget
    record's max_gaussians is its count, the method setting max_gaussians is gaussian_budget."""
    rec = json.loads(json.dumps(rec))
    budget, settings = rec["config"].get("budget"), rec["config"]["method"].get("settings", {})
    if isinstance(budget, dict) and "max_gaussians" in budget:
        budget["count"] = budget.pop("max_gaussians")
    if "max_gaussians" in settings:
        settings["gaussian_budget"] = settings.pop("max_gaussians")
    return rec


@pytest.fixture
def old_run(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(OLD, run)
    return run


def _kw(run_dir):
    return dict(run_dir=run_dir, schedule="tiny", ocr="fake", checkpoints=[3000, 7000], budget="fake-a",
                ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False, write_report=False)


def test_the_142d0ce_folder_reads(old_run):
    m = read_manifest(old_run)
    assert m["schedule"]["name"] == "tiny" and m["budget"] == "fake-a" and set(m["methods"]) == {"fake-a", "fake-b"}
    rows = {(r["method"], r["iteration"]): r for r in map(cell_row, iter_cells(old_run))}
    assert set(rows) == {("fake-a", 15), ("fake-a", 35), ("fake-b", 15), ("fake-b", 35)}
    assert rows["fake-a", 35]["budget"] == "reference" and rows["fake-b", 35]["budget"] == 2000
    before = _rows(old_run)
    write_results_csv(old_run)  # rebuilt from the old cells by today's code: the same table
    after = _rows(old_run)
    added = set(after[0]) - set(before[0])  # columns added since (rho, the peak's scope): empty for the old cells
    assert added <= ADDED_COLUMNS and all(r[c] == "" for r in after for c in added)
    assert [{k: v for k, v in r.items() if k not in added} for r in after] == before


def test_the_142d0ce_folder_resumes_without_training(old_run, tmp_path):
    rf.register_fakes()
    scene = rf.make_scene(tmp_path / "scenes", glyphs=True)
    rf.CALLS["train"].clear()
    bench.run(["fake-a", "fake-b"], [str(scene)], **_kw(old_run))
    assert rf.CALLS["train"] == []


def test_todays_run_writes_the_142d0ce_cells_in_every_non_timing_column(tmp_path):
    rf.register_fakes()
    scene = rf.make_scene(tmp_path / "scenes", glyphs=True)
    new = tmp_path / "new"
    bench.run(["fake-a", "fake-b"], [str(scene)], **_kw(new))
    old_rows, new_rows = _rows(OLD), _rows(new)
    assert list(old_rows[0]) == [c for c in new_rows[0] if c not in ADDED_COLUMNS]
    _assert_same_up_to_the_machine([{k: v for k, v in r.items() if k not in TIMING | ADDED_COLUMNS} for r in new_rows],
                           [{k: v for k, v in r.items() if k not in TIMING} for r in old_rows])
    old_cells = [_comparable(_todays_names(r)) for r in iter_cells(OLD)]
    new_cells = [_comparable(r) for r in iter_cells(new)]
    rhos = {c["config"]["scene"].pop("rho") for c in new_cells}
    [rho] = rhos  # measured on the toy scene's known words, the same in every cell and its results.csv row
    assert rho > 0 and {r["rho"] for r in new_rows} == {str(rho)}
    _assert_same_up_to_the_machine(new_cells, old_cells)
    old_m, new_m = read_manifest(OLD), read_manifest(new)
    for key in ("versions", "datasets", "resolved_device"):
        old_m.pop(key), new_m.pop(key)
    assert new_m["schedule"].pop("miniature") == "shrink"
    # the schedule's description is its --help text, corrected since (tiny evaluates 3K too: 15/35/150 steps)
    assert "15/35/150 iterations for 3K/7K/30K" in new_m["schedule"].pop("description")
    old_m["schedule"].pop("description")
    assert new_m == old_m
