"""`strings-bench compare` (reports/compare/): the paper's
tables over run folders of one seed each (issue 27)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import pytest

import strings_bench.reports.compare as cmp
from strings_bench.cli import main as cli_main
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.results import safe_name


def _compare(*args) -> int:
    return cli_main(["compare", *map(str, args)])


def _cell(run: Path, method: str, scene: str, label: str, iteration: int, cer: float, known: float, *,
          seed: int | None = None, seconds: float = 60.0, evaluation: str = "full") -> None:
    settings = {"steps_scale": 0.05, **({} if seed is None else {"seed": seed})}
    rec = {"method": method, "dataset": "synthetic360-cpu", "scene": scene, "iteration": iteration, "label": label,
           "metrics": {"psnr": 20.0, "ssim": 0.7, "lpips": 0.3}, "timings": {"train_seconds": seconds},
           "config": {"method": {"name": method, "settings": settings}}, "evaluation": evaluation,
           "cer": {"cer": cer}, "cer_known": {"cer": known}, "gaussians": 1000}
    folder = run / "cells" / method / "synthetic360-cpu" / safe_name(scene) / str(iteration)  # pantry@1: pantry_1
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps(rec))


def test_means_over_scenes_then_seeds_with_the_range(tmp_path, capsys):
    s0, s1 = tmp_path / "seed0", tmp_path / "seed1"
    # seed 0 (no seed recorded, the default) and seed 1, two scenes each; figures chosen by hand
    for run, seed, (a, b) in ((s0, None, (0.2, 0.4)), (s1, 1, (0.4, 0.6))):
        _cell(run, "strings", "pantry", "30K", 1500, a, a / 2, seed=seed, seconds=120)
        _cell(run, "strings", "office", "30K", 1500, b, b / 2, seed=seed, seconds=180)
        _cell(run, "strings", "pantry", "25K", 1250, 0.0, 0.0, seed=seed, evaluation="words")  # dense: left out
    _cell(s0, "3dgs", "pantry", "30K", 1500, 0.9, 0.8)
    _cell(s0, "3dgs", "office", "30K", 1500, 0.7, 0.6)
    _cell(s1, "3dgs", "pantry", "30K", 1500, 0.5, 0.4, seed=1)  # seed 1 lacks office: means over pantry only
    data = cmp.collect([s0, s1])
    assert set(data) == {("strings", "30K"), ("3dgs", "30K")}
    st = cmp.summarise(data[("strings", "30K")], "cer")
    # seed 0: (0.2 + 0.4) / 2 = 0.3; seed 1: (0.4 + 0.6) / 2 = 0.5; mean 0.4, range 0.3-0.5
    assert st["per_seed"] == pytest.approx([0.3, 0.5]) and st["mean"] == pytest.approx(0.4)
    assert (st["min"], st["max"], st["seeds"], st["scenes"]) == (pytest.approx(0.3), pytest.approx(0.5), 2, 2)
    g = cmp.summarise(data[("3dgs", "30K")], "cer")
    assert g["scenes"] == 1 and g["per_seed"] == pytest.approx([0.9, 0.5]) and g["left_out"] == {0: ["office"]}
    assert _compare(s0, s1, "--out", tmp_path / "cmp") == 0
    md = capsys.readouterr().out
    # seeds and scenes (greyed), OCR-CER 7K/30K, known-text CER 7K/30K: the mean, then the seeds' range
    assert "| STRinGS | _2_ | _2_ | n/a | 0.400 (0.300-0.500) **(1)** | n/a | 0.200 (0.150-0.250) **(1)** |" in md
    # training time in minutes: seed means (120 + 180) / 2 s = 2.5 min for both seeds
    assert "| STRinGS | n/a | 2.50 (2.50-2.50) (2) |" in md
    assert "3dgs 30K: seed 0 also has office (left out of the means)" in md
    assert {p.name for p in (tmp_path / "cmp").iterdir()} == {"comparison.md", "comparison.tex", "comparison.csv",
                                                              "index.html"}
    # every cell per scene, the seeds in order
    assert _compare(s0, s1, "--per-scene", "cer", "--out", tmp_path / "cmp") == 0
    per = capsys.readouterr().out
    assert "| method | ckpt | office | pantry |" in per
    assert "| STRinGS | 30K | 0.400 / 0.600 | 0.200 / 0.400 |" in per and "| 3DGS | 30K | 0.700 | 0.900 / 0.500 |" in per
    with pytest.raises(SystemExit):
        _compare(s0, "--per-scene", "nonsense")
    with pytest.raises(StringsBenchError, match="not a compared value"):
        cmp.per_scene_table(cmp.compare([s0]), "nonsense")


def test_a_cell_given_twice_counts_once_or_is_an_error(tmp_path, capsys):
    for run in (tmp_path / "a", tmp_path / "b"):
        _cell(run, "strings", "pantry", "7K", 350, 0.5, 0.5, seconds=10 if run.name == "a" else 20)
    _cell(tmp_path / "c", "strings", "pantry", "7K", 350, 0.5, 0.4)
    # the same cell in two folders with the same figures (training time aside) counts once
    once = cmp.collect([tmp_path / "a", tmp_path / "b"])
    assert list(once[("strings", "7K")]) == [0] and once[("strings", "7K")][0]["pantry"]["train_seconds"] == 10
    with pytest.raises(StringsBenchError, match="different figures"):
        cmp.collect([tmp_path / "a", tmp_path / "c"])
    assert _compare(tmp_path / "a", tmp_path / "c") == 1
    assert _compare(tmp_path / "none") == 1
    assert "no run folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert _compare(tmp_path / "empty") == 1
    assert "no fully evaluated cells" in capsys.readouterr().err


def test_decided_paper_figures_and_ablations_come_from_the_specs(tmp_path):
    """Seeds decide a pair only where their ranges do not overlap; the paper's figures and the ablation pairs are the
    specs' (PaperFigures, ablation_of / ablation_at), not lists in the tables code."""
    s0, s1 = tmp_path / "seed0", tmp_path / "seed1"
    for run, seed, (ours, gs) in ((s0, None, (0.30, 0.60)), (s1, 1, (0.34, 0.31))):
        for method, cer in (("strings", ours), ("3dgs", gs)):
            _cell(run, method, "pantry", "30K", 1500, cer, cer, seed=seed)
            _cell(run, method, "pantry", "7K", 350, 0.9, 0.5 if method == "strings" else 0.8, seed=seed)
    _cell(s0, "strings-no-densify", "pantry", "7K", 350, 0.95, 0.7)
    _cell(s0, "strings-no-densify", "pantry", "30K", 1500, 0.5, 0.5)
    c = cmp.compare([s0, s1])
    verdict = {(r["value"], r["label"]): r["verdict"] for r in cmp.decided_rows(c) if r["method"] == "3dgs"}
    # 30K: STRinGS 0.30-0.34 against 3DGS 0.31-0.60: the ranges overlap; 7K known-text: 0.5 against 0.8 at both seeds
    assert verdict[("cer", "30K")] == "not decided" and verdict[("cer_known", "7K")] == "decided"
    assert {r["verdict"] for r in cmp.decided_rows(c) if r["method"] == "strings-no-densify"} == {"one seed"}
    tables = {t.name: t for t in cmp.comparison_tables(c)}
    paper = [col for col in tables["compare_cer"].columns if col.greyed and "paper" in col.group]
    assert [col.values["strings"] for col in paper] == [0.177, 0.106]  # the strings spec's STRinGS-360 figures
    abl = tables["compare_ablations"]
    assert abl.methods == ["strings-no-densify"]
    by = {col.sub_plain: col.values["strings-no-densify"] for col in abl.columns}
    # at 7K (the spec's ablation_at), not at 30K: w/o 0.95 against STRinGS' 0.9 (one seed of the ablation, both of STRinGS)
    assert by["checkpoint"] == 7000 and by["w/o: OCR-CER"] == 0.95 and by["full method: OCR-CER"] == pytest.approx(0.9)
    html = (cmp.write_comparison(c, tmp_path / "out")["html"]).read_text()
    assert 'id="table-compare_cer"' in html and 'class="undecided"' in html and 'class="decided"' in html



def test_an_ablation_whose_checkpoint_the_folder_lacks_is_shown_at_the_last_one_both_have(tmp_path):
    """strings-pos-lr's spec reads its ablation at 3K (the end of phase 1); a folder trained to 7K and 30K has no 3K,
    so the table shows it at 30K and says so, rather than n/a (figures by hand)."""
    run = tmp_path / "run"
    for method, (at7, at30) in (("strings", (0.8, 0.3)), ("strings-pos-lr", (0.6, 0.2))):
        _cell(run, method, "pantry", "7K", 350, at7, at7)
        _cell(run, method, "pantry", "30K", 1500, at30, at30 / 2)
    c = cmp.compare([run])
    assert c.ablations() == [("strings-pos-lr", "strings", "30K", "3K")]
    abl = {t.name: t for t in cmp.comparison_tables(c)}["compare_ablations"]
    by = {col.sub_plain: col.values["strings-pos-lr"] for col in abl.columns}
    assert by["checkpoint"] == 30000 and by["w/o: OCR-CER"] == 0.2 and by["full method: OCR-CER"] == pytest.approx(0.3)
    assert by["w/o: known-text CER"] == pytest.approx(0.1) and "its spec names 3K, which this comparison lacks" in abl.caption
    _cell(run, "strings", "pantry", "3K", 150, 0.95, 0.9)  # with 3K for both, the spec's checkpoint again
    _cell(run, "strings-pos-lr", "pantry", "3K", 150, 0.9, 0.85)
    assert cmp.compare([run]).ablations() == [("strings-pos-lr", "strings", "3K", "3K")]

# docs/results/strings-cpu.md, "On `synthetic360-cpu`": known-text CER per room at seed 0 (office / pantry / storeroom), 7K and
# 30K, and the mean of the rooms its CER table prints. The run folders it was made from are not kept in the
# repository; this fixture holds the per-room figures as the doc prints them (rounded to 3 decimals).
DOC_PER_ROOM = {
    "3dgs": ((0.905, 0.883, 0.896), (0.517, 0.567, 0.507), (0.895, 0.530)),
    "mip-splatting": ((0.932, 0.892, 0.951), (0.633, 0.625, 0.562), (0.925, 0.607)),
    "mcmc": ((0.864, 1.000, 0.972), (0.544, 0.592, 0.514), (0.945, 0.550)),
    "absgs": ((0.857, 0.900, 0.847), (0.456, 0.358, 0.201), (0.868, 0.339)),
    "edc-absgs": ((0.694, 0.750, 0.812), (0.231, 0.100, 0.174), (0.752, 0.168)),
    "strings": ((0.878, 0.917, 0.910), (0.435, 0.317, 0.229), (0.901, 0.327)),
    "strings-no-densify": ((0.966, 0.992, 0.958), (0.571, 0.642, 0.618), (0.972, 0.610)),
    "strings-pos-lr": ((0.694, 0.683, 0.715), (0.395, 0.242, 0.146), (0.697, 0.261)),
}
# Its seeds table: the mean of the rooms per seed, known-text CER at 7K (seeds 0 / 1 / 2).
DOC_SEEDS_7K = {"3dgs": (0.895, 0.918, 0.875), "strings": (0.901, 0.895, 0.911)}


def test_rebuilds_the_doc_synthetic360_cpu_known_text_tables(tmp_path, capsys):
    rooms = ("office", "pantry", "storeroom")
    s0 = tmp_path / "s360cpu-compare"
    for method, (at7, at30, _) in DOC_PER_ROOM.items():
        for room, k7, k30 in zip(rooms, at7, at30):
            _cell(s0, method, room, "7K", 350, 1.0, k7)
            _cell(s0, method, room, "30K", 1500, 1.0, k30)
    c = cmp.compare([s0])
    assert c.methods == list(DOC_PER_ROOM)  # the registry's (the paper's) order, ablations last
    for method, (_, _, (mean7, mean30)) in DOC_PER_ROOM.items():
        # the doc's means were taken before its per-room figures were rounded: equal within that rounding (+-0.001)
        assert abs(c.get(method, "7K", "cer_known")["mean"] - mean7) <= 0.001, method
        assert abs(c.get(method, "30K", "cer_known")["mean"] - mean30) <= 0.001, method
    # seeds 1 and 2 of STRinGS and 3DGS at 7K, every room at the doc's room mean of that seed
    for seed in (1, 2):
        run = tmp_path / f"seed{seed}"
        for method, means in DOC_SEEDS_7K.items():
            for room in rooms:
                _cell(run, method, room, "7K", 350, 1.0, means[seed], seed=seed)
    c = cmp.compare([s0, tmp_path / "seed1", tmp_path / "seed2"])
    s = c.get("3dgs", "7K", "cer_known")
    assert s["seeds"] == 3 and (round(s["min"], 3), round(s["max"], 3)) == (0.875, 0.918)
    # the doc: "STRinGS against 3DGS ... at 7K it is not [decided] in known-text CER (the seeds' ranges overlap)"
    verdict = {(r["value"], r["label"]): r["verdict"] for r in cmp.decided_rows(c) if r["method"] == "3dgs"}
    assert verdict[("cer_known", "7K")] == "not decided"


# ---- scene draws (issue 40): a draw ROOM@N counts like a seed ---------------------------------------------------
# known-text CER at 7K per (seed, draw) and room (pantry, office), chosen by hand; OCR-CER the same for both rooms
DRAW_KNOWN = {"strings": {(0, 0): (0.2, 0.4), (0, 1): (0.6, 0.8), (1, 0): (0.3, 0.5), (1, 1): (0.5, 0.7)},
              "3dgs": {(0, 0): (0.8, 0.9), (0, 1): (0.75, 0.85), (1, 0): (0.9, 1.0), (1, 1): (0.7, 0.8)}}
DRAW_OCR = {"strings": {(0, 0): 0.3, (1, 0): 0.35, (0, 1): 0.8, (1, 1): 0.85},
            "3dgs": {(0, 0): 0.6, (1, 0): 0.65, (0, 1): 0.7, (1, 1): 0.75}}


def _draw_folders(tmp_path: Path, draws=(0, 1)) -> list[Path]:
    runs = []
    for seed in (0, 1):
        run = tmp_path / f"seed{seed}"
        for method, table in DRAW_KNOWN.items():
            for (s, d), known in table.items():
                if s != seed or d not in draws:
                    continue
                for room, k in zip(("pantry", "office"), known):
                    _cell(run, method, room if d == 0 else f"{room}@{d}", "7K", 350, DRAW_OCR[method][(s, d)], k,
                          seed=seed or None)
        runs.append(run)
    return runs


def test_draws_count_like_seeds_in_means_ranges_and_decided(tmp_path, capsys):
    runs = _draw_folders(tmp_path)
    c = cmp.compare(runs)
    st = c.get("strings", "7K", "cer_known")
    # replicate means (mean of the two rooms): s0d0 0.3, s0d1 0.7, s1d0 0.4, s1d1 0.6
    # per draw (mean over seeds): d0 0.35, d1 0.65; mean over draws 0.5; range over replicates 0.3-0.7
    assert st["mean"] == pytest.approx(0.5) and (st["min"], st["max"]) == (pytest.approx(0.3), pytest.approx(0.7))
    assert (st["seeds"], st["draws"], st["replicates"], st["scenes"]) == (2, 2, 4, 2)
    assert st["per_draw"] == {0: pytest.approx(0.35), 1: pytest.approx(0.65)}
    assert st["per_seed"] == pytest.approx([0.5, 0.5]) and st["left_out"] == {}
    gs = c.get("3dgs", "7K", "cer_known")  # replicates 0.85, 0.8, 0.95, 0.75: mean (0.9 + 0.775) / 2 = 0.8375
    assert gs["mean"] == pytest.approx(0.8375) and (gs["min"], gs["max"]) == (pytest.approx(0.75), pytest.approx(0.95))
    verdict = {(r["value"], r["label"]): r for r in cmp.decided_rows(c) if r["method"] == "3dgs"}
    # known-text: STRinGS 0.3-0.7 against 3DGS 0.75-0.95: decided; OCR-CER: 0.3-0.85 against 0.6-0.75: not decided
    assert verdict[("cer_known", "7K")]["verdict"] == "decided"
    assert verdict[("cer", "7K")]["verdict"] == "not decided" and verdict[("cer", "7K")]["seeds"] == "2x2 draws / 2x2 draws"
    # paired by (seed, draw), beside the verdict: 3DGS' OCR-CER is below STRinGS' on draw 1 (0.7 < 0.8, 0.75 < 0.85)
    # and above on draw 0 (0.6 > 0.3, 0.65 > 0.35); its known-text CER is above on all four
    assert (verdict[("cer", "7K")]["paired"], verdict[("cer_known", "7K")]["paired"]) == ("2 of 4", "0 of 4")
    # draw 0 alone: the seeds (0.3, 0.35 against 0.6, 0.65) decide OCR-CER; the draws undo that
    only0 = cmp.compare(_draw_folders(tmp_path / "d0", draws=(0,)))
    assert {r["verdict"] for r in cmp.decided_rows(only0) if (r["method"], r["value"]) == ("3dgs", "cer")} == {"decided"}
    assert only0.get("strings", "7K", "cer")["draws"] == 1 and not cmp.has_draws(only0)
    # the draws tables: per room the mean over its draws of the seeds' mean, with the draws' range
    tables = {t.name: t for t in cmp.comparison_tables(c)}
    known = {(col.group, col.sub_plain): col for col in tables["compare_draws_cer_known"].columns}
    pantry, office, every = (known[("known-text CER 7K", r)] for r in ("pantry", "office", "all rooms"))
    # pantry: d0 (0.2 + 0.3) / 2 = 0.25, d1 (0.6 + 0.5) / 2 = 0.55; office: d0 0.45, d1 0.75
    assert pantry.values["strings"] == pytest.approx(0.4) and pantry.suffix["strings"] == " (0.250-0.550, 2 draws)"
    assert office.values["strings"] == pytest.approx(0.6) and office.suffix["strings"] == " (0.450-0.750, 2 draws)"
    assert every.values["strings"] == pytest.approx(0.5) and every.suffix["strings"] == " (0.350-0.650, 2 draws)"
    assert _compare(*runs, "--per-scene", "cer_known", "--out", tmp_path / "cmp") == 0
    md = capsys.readouterr().out
    assert md.startswith("# Comparison over seeds and scene draws")
    assert "| 3DGS | STRinGS | OCR-CER | 7K | +0.100 | 2x2 draws / 2x2 draws | not decided | 2 of 4 |" in md
    # seeds, draws, scenes (rooms), then OCR-CER 7K and known-text CER 7K with the range over seeds and draws
    assert "| STRinGS | _2_ | _2_ | _2_ | 0.575 (0.300-0.850) **(1)** | n/a | 0.500 (0.300-0.700) **(1)** |" in md
    assert "| STRinGS | 0.600 (0.450-0.750, 2 draws) **(1)** | 0.400 (0.250-0.550, 2 draws) **(1)** | 0.500 " in md
    assert "| method | ckpt | office | office@1 | pantry | pantry@1 |" in md  # a room's draws side by side
    assert "| STRinGS | 7K | 0.400 / 0.500 | 0.800 / 0.700 | 0.200 / 0.300 | 0.600 / 0.500 |" in md
    row = next(r for r in csv.DictReader(io.StringIO((tmp_path / "cmp" / "comparison.csv").read_text()))
               if (r["method"], r["label"], r["value"]) == ("strings", "7K", "cer_known"))
    assert [float(row[k]) for k in ("mean", "min", "max", "draw_min", "draw_max")] == pytest.approx([0.5, 0.3, 0.7, 0.35, 0.65])
    assert (row["seeds"], row["draws"], row["scenes"]) == ("2", "2", "2") and row["per_draw"].startswith("0:0.35")


def test_a_room_missing_at_one_draw_is_left_out_and_two_datasets_scene_names_collide(tmp_path):
    run = tmp_path / "run"
    for scene, k in (("pantry", 0.2), ("office", 0.4), ("pantry@1", 0.6)):  # office@1 not trained
        _cell(run, "3dgs", scene, "7K", 350, 1.0, k)
    s = cmp.compare([run]).get("3dgs", "7K", "cer_known")
    # the rooms every (seed, draw) has: pantry only; draws 0.2 and 0.6
    assert (s["scenes"], s["draws"], s["mean"]) == (1, 2, pytest.approx(0.4)) and s["left_out"] == {0: ["office"]}
    other = tmp_path / "other"
    rec = json.loads((run / "cells" / "3dgs" / "synthetic360-cpu" / "pantry" / "350" / "result.json").read_text())
    assert (run / "cells" / "3dgs" / "synthetic360-cpu" / "pantry_1").is_dir()  # the runner's folder name of pantry@1
    folder = other / "cells" / "3dgs" / "s360-seed1" / "pantry" / "350"
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps({**rec, "dataset": "s360-seed1"}))
    with pytest.raises(StringsBenchError, match="is in datasets synthetic360-cpu and s360-seed1"):
        cmp.collect([run, other])
    assert set(cmp.collect([run, other], "s360-seed1")) == {("3dgs", "7K")}


def test_methods_are_held_to_the_scenes_they_all_have(tmp_path, capsys):
    """A draw trained for some methods only (a 30K folder still filling) would rank methods on different rooms: every
    method is averaged over the scenes all of them have, and the rest is listed."""
    run = tmp_path / "run"
    known = {"3dgs": {"pantry": 0.5, "office": 0.7, "storeroom": 0.6, "pantry@1": 0.9},
             "strings": {"pantry": 0.4, "office": 0.2, "storeroom": 0.3, "pantry@1": 0.1},
             "edc-absgs": {"pantry": 0.2, "office": 0.2, "storeroom": 0.2}}  # pantry@1 not trained yet
    for method, by_scene in known.items():
        for scene, k in by_scene.items():
            _cell(run, method, scene, "30K", 3000, 0.5, k)
    c = cmp.compare([run])
    # all three on draw 0: 3DGS (0.5 + 0.7 + 0.6) / 3 = 0.6; over its own scenes it was (0.5 + 0.9) / 2 = 0.7
    means = {m: c.get(m, "30K", "cer_known")["mean"] for m in known}
    assert means == {"3dgs": pytest.approx(0.6), "strings": pytest.approx(0.3), "edc-absgs": pytest.approx(0.2)}
    assert {c.get(m, "30K", "cer_known")["scenes"] for m in known} == {3}
    assert "3dgs 30K: seed 0 also has pantry@1 (left out of the means: not every method has it)" in c.left_out()
    assert not any(line.startswith("edc-absgs") for line in c.left_out())
    # the per-scene rows still show every cell
    assert "| 3DGS | 30K | 0.700 | 0.500 | 0.900 | 0.600 |" in cmp.per_scene_table(c)
    # EDC-AbsGS' pantry@1 lands: every method has four scenes, but draw 1 has one room of three. Keeping the
    # complete draw (3 cells) beats keeping pantry alone over both draws (2 cells): the same means, and pantry@1 is
    # listed as left out within each method.
    _cell(run, "edc-absgs", "pantry@1", "30K", 3000, 0.5, 0.3)
    c = cmp.compare([run])
    assert {m: c.get(m, "30K", "cer_known")["mean"] for m in known} == means
    assert "edc-absgs 30K: seed 0 also has pantry@1 (left out of the means)" in c.left_out()


def test_methods_with_no_common_scene_keep_their_own_and_say_so(tmp_path):
    run = tmp_path / "run"
    _cell(run, "3dgs", "pantry", "7K", 700, 0.5, 0.6)
    _cell(run, "strings", "office", "7K", 700, 0.5, 0.4)
    c = cmp.compare([run])
    assert c.get("3dgs", "7K", "cer_known")["mean"] == pytest.approx(0.6)
    assert c.get("strings", "7K", "cer_known")["mean"] == pytest.approx(0.4)
    assert c.left_out() == ["7K: the methods share no scene; each method's mean is over its own (not comparable)"]


def test_methods_and_scenes_choose_the_cells_before_the_common_scenes(tmp_path, capsys):
    """`--methods` and `--scenes` pick cells before the scenes all methods share are found: a method trained on
    draw 0 only, left out, no longer holds the others to draw 0; a scene choice holds every method to it; a
    name no cell has is an error, not a silent narrowing."""
    run = tmp_path / "run"
    known = {"3dgs": {"pantry": 0.5, "office": 0.7, "pantry@1": 0.9, "office@1": 0.3},
             "strings": {"pantry": 0.4, "office": 0.2, "pantry@1": 0.1, "office@1": 0.5},
             "improved-gs": {"pantry": 0.2, "office": 0.2}}  # draw 0 only
    for method, by_scene in known.items():
        for scene, k in by_scene.items():
            _cell(run, method, scene, "30K", 3000, 0.5, k)
    every = cmp.compare([run])
    assert every.get("3dgs", "30K", "cer_known")["mean"] == pytest.approx(0.6)  # held to draw 0 by improved-gs
    two = cmp.compare([run], methods=["3dgs", "strings"])
    assert two.methods == ["3dgs", "strings"]
    # both draws now: draw 0 (0.5 + 0.7) / 2 = 0.6, draw 1 (0.9 + 0.3) / 2 = 0.6 for 3DGS; 0.3 and 0.3 for STRinGS
    g, s = (two.get(m, "30K", "cer_known") for m in ("3dgs", "strings"))
    assert (g["mean"], g["draws"], s["mean"], s["draws"]) == (pytest.approx(0.6), 2, pytest.approx(0.3), 2)
    draw1 = cmp.compare([run], scenes=["pantry@1", "office@1"])
    assert draw1.methods == ["3dgs", "strings"]  # improved-gs has no cell there
    assert draw1.get("strings", "30K", "cer_known")["mean"] == pytest.approx(0.3)
    assert draw1.get("3dgs", "30K", "cer_known")["mean"] == pytest.approx(0.6)
    one = cmp.compare([run], methods=["3dgs", "strings"], scenes=["pantry@1"])
    assert one.get("strings", "30K", "cer_known")["mean"] == pytest.approx(0.1)
    with pytest.raises(StringsBenchError, match="methods 3dgss") as err:
        cmp.compare([run], methods=["3dgss"])
    assert "3dgs, improved-gs, strings" in err.value.hint
    with pytest.raises(StringsBenchError, match="scenes pantry@2"):
        cmp.compare([run], scenes=["pantry", "pantry@2"])
    # the command line: comma-separated names
    assert _compare(run, "--methods", "3dgs,strings", "--scenes", "pantry@1", "--out", tmp_path / "cmp") == 0
    md = capsys.readouterr().out
    assert "| STRinGS |" in md and "Improved-GS" not in md
    with pytest.raises(SystemExit):
        _compare(run, "--methods", ",")


def test_against_holds_every_method_against_the_method_named(tmp_path, capsys):
    """`--against METHOD`: "Decided or not" against METHOD rather than STRinGS (issue 42: the newer methods against
    EDC-AbsGS); a name without cells among the compared is an error that lists those there are."""
    rooms = ("office", "pantry")
    # known-text CER per seed (both rooms at it): EDC 0.10/0.12, Improved-GS 0.20/0.22 (apart from EDC), Perceptual-GS
    # 0.11/0.25 (overlaps EDC), STRinGS 0.15/0.16
    per_seed = {"edc-absgs": (0.10, 0.12), "improved-gs": (0.20, 0.22), "perceptual-gs": (0.11, 0.25),
                "strings": (0.15, 0.16)}
    runs = [tmp_path / f"seed{s}" for s in (0, 1)]
    for s, run in enumerate(runs):
        for method, ks in per_seed.items():
            for room in rooms:
                _cell(run, method, room, "30K", 1500, 0.5, ks[s], seed=s)
    c = cmp.compare(runs, against="edc-absgs")
    assert c.reference == "edc-absgs"
    rows = {r["method"]: r for r in cmp.decided_rows(c) if (r["value"], r["label"]) == ("cer_known", "30K")}
    assert set(rows) == {"improved-gs", "perceptual-gs", "strings"} and {r["against"] for r in rows.values()} == {"edc-absgs"}
    assert rows["improved-gs"]["verdict"] == "decided" and rows["improved-gs"]["difference"] == pytest.approx(0.10)
    assert rows["perceptual-gs"]["verdict"] == "not decided" and rows["strings"]["verdict"] == "decided"
    assert rows["perceptual-gs"]["paired"] == "0 of 2"
    # without it, STRinGS is the reference as before: EDC-AbsGS is held against it, decided
    default = {r["method"]: r for r in cmp.decided_rows(cmp.compare(runs)) if r["value"] == "cer_known"}
    assert "strings" not in default and default["edc-absgs"]["against"] == "strings"
    assert _compare(*runs, "--against", "edc-absgs", "--out", tmp_path / "cmp") == 0
    md = capsys.readouterr().out
    assert "## Decided or not, against EDC-AbsGS" in md
    assert "| Improved-GS | EDC-AbsGS | known-text CER | 30K | +0.100 | 2 / 2 | decided | 0 of 2 |" in md
    assert "Decided or not, against EDC-AbsGS" in (tmp_path / "cmp" / "index.html").read_text()
    with pytest.raises(StringsBenchError, match="--against mcmc") as e:
        cmp.compare(runs, against="mcmc")
    assert "edc-absgs" in e.value.hint and "strings" in e.value.hint
    with pytest.raises(StringsBenchError, match="--against edc-absgs"):  # chosen away by --methods
        cmp.compare(runs, methods=["strings", "improved-gs"], against="edc-absgs")


def test_the_banked_csv_gives_the_tables_compare_printed_from_the_folders(tmp_path):
    """`comparison_from_csv` (what `docs refresh`'s kind=compare-table reads): compare's tables made from the CSV it
    wrote equal those it made from the run folders, with scene draws (ranges over replicates) and an ablation."""
    runs = _draw_folders(tmp_path)
    for seed, run in enumerate(runs):
        for room in ("pantry", "office"):
            _cell(run, "strings-no-densify", room, "7K", 350, 0.95, 0.9 + 0.01 * seed, seed=seed or None)
            _cell(run, "strings-no-densify", f"{room}@1", "7K", 350, 0.97, 0.92, seed=seed or None)
    c = cmp.compare(runs)
    written = cmp.write_comparison(c, tmp_path / "out")
    from_csv = cmp.comparison_from_csv(written["csv"])
    made = {t.name: t.markdown() for t in cmp.comparison_tables(c)}
    assert {"compare_cer", "compare_time_quality", "compare_ablations"} <= set(made)
    for t in cmp.comparison_tables(from_csv):
        if t.name in ("compare_cer", "compare_time_quality", "compare_ablations"):
            assert t.markdown() == made[t.name], t.name
    assert "0.500 (0.300-0.700)" in made["compare_cer"]  # STRinGS' known-text CER over seeds and draws


@pytest.mark.parametrize("banked", sorted(p for p in (Path(__file__).resolve().parents[2] / "docs/results/data").glob(
    "*/comparison*.csv") if (p.with_suffix(".md")).is_file()), ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_each_banked_comparison_csv_gives_the_tables_of_its_markdown(banked):
    """The tables the results pages make from a banked comparison.csv are those compare printed into the Markdown
    beside it when it ran on the run folders (an independent record: the folders are not banked)."""
    printed = banked.with_suffix(".md").read_text(encoding="utf-8")
    c = cmp.comparison_from_csv(banked)
    # compare once printed n/a for an ablation at the checkpoint its spec names when the folders lacked it; it now
    # shows it at the last checkpoint both have and says so in the caption: those rows are not in the old Markdown
    moved = {c.names.title(m) for m, _, label, named in c.ablations() if label != named}
    for t in cmp.comparison_tables(c):
        if t.name in ("compare_cer", "compare_time_quality"):
            assert t.markdown().strip() in printed, (banked.name, t.name)
        elif t.name == "compare_ablations":
            rows = [line for line in t.markdown().splitlines() if line.split(" | ")[0].lstrip("| ") not in moved]
            assert rows[2:] or moved, banked.name
            assert all(line in printed.splitlines() for line in rows), (banked.name, t.name)


def test_a_csv_that_is_not_a_comparison_is_refused(tmp_path):
    bad = tmp_path / "results.csv"
    bad.write_text("method,label,cer\n3dgs,7K,0.5\n")
    with pytest.raises(StringsBenchError, match="not a comparison.csv"):
        cmp.comparison_from_csv(bad)
