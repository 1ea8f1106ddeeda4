"""studies/lock_rho/lock_rho.py: the lock's verdict per rho, the effective rho of a stand-in LR factor, the crossover."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from _scripts import load_study  # noqa: E402


@pytest.fixture(scope="module")
def lock_rho():
    return load_study("lock_rho")


def _run(root: Path, miniature: str, scale: float, cells: list[tuple], scene_path: str | None = None) -> Path:
    """A run folder with run.json and one result.json per (method, scene, label, seed, gain or None, rho, cer)."""
    root.mkdir(parents=True)
    (root / "run.json").write_text(json.dumps({"schedule": {"miniature": miniature, "steps_scale": scale}}))
    for method, scene, label, seed, gain, rho, cer in cells:
        settings = {"steps_scale": scale, "seed": seed, **({} if gain is None else {"position_lr_gain": gain})}
        d = root / "cells" / method / "synthetic360-cpu" / scene / f"{label}-{seed}"
        d.mkdir(parents=True)
        (d / "result.json").write_text(json.dumps({
            "method": method, "scene": scene, "label": label, "iteration": 300 if label == "3K" else 700,
            "cer_known": {"cer": cer}, "cer": cer + 0.05,
            "config": {"method": {"settings": settings}, "scene": {"rho": rho, "path": scene_path}}}))
    return root


def test_verdict_needs_two_seeds_a_side_and_ranges_apart(lock_rho):
    assert lock_rho.verdict([0.2, 0.25], [0.4, 0.5], 0.02) == "helps"
    assert lock_rho.verdict([0.4, 0.5], [0.2, 0.25], 0.02) == "hurts"
    assert lock_rho.verdict([0.2, 0.45], [0.4, 0.5], 0.02) == "not decided"  # ranges overlap
    assert lock_rho.verdict([0.2, 0.39], [0.4, 0.5], 0.02) == "not decided"  # apart by less than the tie
    assert lock_rho.verdict([0.1], [0.9], 0.02) == "not decided"  # one seed


def test_the_table_reads_seeds_stand_in_factors_and_finds_the_crossover(lock_rho, tmp_path):
    """Two rooms at the run's own gain and one at a stand-in factor of 8 over the lr-sum miniature's gain (10 at
    x0.1): effective rho 0.03, 0.04 and 0.32. The lock hurts at the first two and helps at 0.32: the crossover lies
    between 0.04 and 0.32, where the log-linear interpolation of the effects puts it."""
    cells = []
    for seed in (0, 1):
        for scene, gain, rho, lock, free in (("a", None, 0.03, 0.50, 0.30), ("b", None, 0.04, 0.45, 0.35),
                                             ("a", 80.0, 0.04, 0.20, 0.60)):
            cells.append(("strings", scene, "7K", seed, gain, rho, lock + 0.01 * seed))
            cells.append(("strings-pos-lr", scene, "7K", seed, gain, rho, free + 0.01 * seed))
    cells.append(("strings-cap", "a", "7K", 0, 80.0, 0.04, 0.10))
    base = _run(tmp_path / "base", "lr-sum", 0.1, [c for c in cells if c[4] is None])
    hard = _run(tmp_path / "hard", "lr-sum", 0.1, [c for c in cells if c[4] is not None])
    got = lock_rho.read_cells([str(base), str(hard)])
    assert sorted({round(c["rho_eff"], 6) for c in got}) == [0.03, 0.04, 0.32]
    rows = lock_rho.lock_table(got, "strings", "strings-pos-lr", ["strings-cap"], tie=0.02)
    by = {r["rho (effective)"]: r for r in rows}
    assert [by[k]["verdict (known-text CER)"] for k in ("0.030", "0.040", "0.320")] == ["hurts", "hurts", "helps"]
    assert by["0.320"]["LR factor"] == "8" and by["0.030"]["LR factor"] == "1"
    assert by["0.030"]["lock (known-text CER)"] == "0.500 0.510" and by["0.030"]["seeds (OCR-CER)"] == "2/2"
    assert by["0.320"]["strings-cap - lock (known-text CER)"] == "-0.105"
    [x_known, x_ocr] = lock_rho.crossover(rows)
    e1, e2 = 0.10, -0.40  # the mean effects at 0.04 and 0.32
    expected = math.exp(math.log(0.04) + e1 / (e1 - e2) * (math.log(0.32) - math.log(0.04)))
    assert float(x_known["crossover rho"]) == pytest.approx(expected, abs=1e-3)
    assert x_known["rho values"] == 3 and x_ocr["crossover rho"] == x_known["crossover rho"]


def test_no_crossover_when_the_lock_never_turns_to_help(lock_rho, tmp_path):
    cells = [(m, scene, "3K", s, None, rho, c + 0.01 * s) for s in (0, 1)
             for scene, rho, lock, free in (("a", 0.03, 0.5, 0.3), ("b", 0.06, 0.4, 0.3))
             for m, c in (("strings", lock), ("strings-pos-lr", free))]
    rows = lock_rho.lock_table(lock_rho.read_cells([str(_run(tmp_path / "r", "shrink", 0.1, cells))]),
                               "strings", "strings-pos-lr", [], tie=0.02)
    assert {x["crossover rho"] for x in lock_rho.crossover(rows)} == {"none in range"}


def test_a_scene_folder_that_is_still_there_gives_its_current_rho(lock_rho, tmp_path):
    """Cells record the rho of their day; the scene's record may hold a newer measurement (the synthetic rooms' rho
    was re-measured finer): the table uses the scene folder's current record, the recorded value only without it."""
    from _engine_helpers import make_tiny_scene
    from strings_bench.scene.difficulty import Difficulty, write_difficulty

    scene = tmp_path / "scene"
    make_tiny_scene(scene)
    write_difficulty(scene, Difficulty(0.5, 2.0, 0.00064, 1.5, 10, "crops", True))
    cells = [(m, "a", "3K", 0, None, 0.03, 0.4) for m in ("strings", "strings-pos-lr")]
    now = lock_rho.read_cells([str(_run(tmp_path / "r1", "shrink", 0.1, cells, str(scene)))])
    assert {c["rho"] for c in now} == {0.5}
    gone = lock_rho.read_cells([str(_run(tmp_path / "r2", "shrink", 0.1, cells, str(tmp_path / "moved")))])
    assert {c["rho"] for c in gone} == {0.03}


def test_a_variant_setting_names_the_cell_and_joins_the_same_rows(lock_rho, tmp_path):
    """STRinGS with the phase-1 step capped, run in a folder of its own as `strings`, is named by its setting and
    lands in the rows of the lock and its ablation at the same rho."""
    assert lock_rho.cell_method("strings", {"seed": 0, "phase1_step_strokes": 0.4}) == "strings[phase1_step_strokes=0.4]"
    assert lock_rho.cell_method("strings", {"seed": 0, "phase1_step_strokes": None}) == "strings"
    pair = _run(tmp_path / "pair", "shrink", 0.1, [(m, "a", "7K", s, None, 0.05, c + 0.01 * s) for s in (0, 1)
                                                    for m, c in (("strings", 0.5), ("strings-pos-lr", 0.3))])
    var = tmp_path / "var"
    _run(var, "shrink", 0.1, [("strings", "a", "7K", s, None, 0.05, 0.2 + 0.01 * s) for s in (0, 1)])
    for result in var.glob("cells/*/*/*/*/result.json"):
        rec = json.loads(result.read_text())
        rec["config"]["method"]["settings"]["phase1_step_strokes"] = 0.4
        result.write_text(json.dumps(rec))
    rows = lock_rho.lock_table(lock_rho.read_cells([str(pair), str(var)]), "strings", "strings-pos-lr",
                               ["strings[phase1_step_strokes=0.4]"], tie=0.02)
    [row] = rows
    assert row["lock (known-text CER)"] == "0.500 0.510" and row["verdict (known-text CER)"] == "hurts"
    assert row["strings[phase1_step_strokes=0.4] - no lock (known-text CER)"] == "-0.100"


def test_the_locked_side_at_factor_one_stands_for_every_factor_at_the_end_of_phase_one(lock_rho, tmp_path):
    """Only when asked, only at the checkpoints named, and only from the same scene at factor 1."""
    base = _run(tmp_path / "base", "shrink", 1.0, [("strings", "a", "3K", 0, None, 0.034, 0.43),
                                                   ("strings", "a", "7K", 0, None, 0.034, 0.10),
                                                   ("strings", "b", "3K", 0, None, 0.034, 0.99)])
    free = _run(tmp_path / "free", "shrink", 1.0, [("strings-pos-lr", "a", lab, 0, 20.0, 0.034, 0.90)
                                                   for lab in ("3K", "7K")])
    cells = lock_rho.read_cells([str(base), str(free)])
    plain = {(r["ckpt"], r["LR factor"]): r for r in lock_rho.lock_table(cells, "strings", "strings-pos-lr", [], 0.02)}
    assert plain[("3K", "20")]["lock (known-text CER)"] == ""
    shared = {(r["ckpt"], r["scene"], r["LR factor"]): r for r in
              lock_rho.lock_table(cells, "strings", "strings-pos-lr", [], 0.02, lock_any_gain=("3K",))}
    assert shared[("3K", "a", "20")]["lock (known-text CER)"] == "0.430"
    assert shared[("3K", "a", "20")]["effect (known-text CER)"] == "-0.470"
    assert shared[("7K", "a", "20")]["lock (known-text CER)"] == ""  # phase 2 uses the LR: not shared


def test_one_cer_keeps_only_its_columns(lock_rho, tmp_path, capsys):
    cells = [(m, "a", "7K", s, None, 0.03, c + 0.01 * s) for s in (0, 1) for m, c in (("strings", 0.5), ("strings-pos-lr", 0.3))]
    run = _run(tmp_path / "r", "shrink", 0.1, cells)
    out = tmp_path / "known.csv"
    assert lock_rho.main([str(run), "--cer", "known", "--csv", str(out)]) == 0
    header = out.read_text().splitlines()[0]
    assert "verdict (known-text CER)" in header and "OCR-CER" not in header
