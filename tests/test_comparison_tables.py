"""benchmarks/comparison.py: the paper's tables over run folders of one seed each (issue 27)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from strings_bench.core.errors import StringsBenchError

REPO = Path(__file__).resolve().parents[1]


def _comparison():
    spec = importlib.util.spec_from_file_location("_bench_comparison", REPO / "benchmarks" / "comparison.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _cell(run: Path, method: str, scene: str, label: str, iteration: int, cer: float, known: float, *,
          seed: int | None = None, seconds: float = 60.0, evaluation: str = "full") -> None:
    settings = {"steps_scale": 0.05, **({} if seed is None else {"seed": seed})}
    rec = {"method": method, "dataset": "synthetic360-cpu", "scene": scene, "iteration": iteration, "label": label,
           "metrics": {"psnr": 20.0, "ssim": 0.7, "lpips": 0.3}, "timings": {"train_seconds": seconds},
           "config": {"method": {"name": method, "settings": settings}}, "evaluation": evaluation,
           "cer": {"cer": cer}, "cer_known": {"cer": known}, "gaussians": 1000}
    folder = run / "cells" / method / "synthetic360-cpu" / scene / str(iteration)
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps(rec))


def test_means_over_scenes_then_seeds_with_the_range(tmp_path, capsys):
    cmp = _comparison()
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
    assert cmp.main([str(s0), str(s1)]) == 0
    md = capsys.readouterr().out
    assert "| strings | 2 / 2 | - | 0.400 (0.300-0.500) | - | 0.200 (0.150-0.250) |" in md
    # training time in minutes: seed means (120 + 180) / 2 s = 2.5 min for both seeds
    assert "| strings | - | 2.50 (2.50-2.50) |" in md
    assert "3dgs 30K: seed 0 also has office (left out of the means)" in md
    # every cell per scene, the seeds in order
    assert cmp.main([str(s0), str(s1), "--per-scene", "cer"]) == 0
    per = capsys.readouterr().out
    assert "| method | ckpt | office | pantry |" in per
    assert "| strings | 30K | 0.400 / 0.600 | 0.200 / 0.400 |" in per and "| 3dgs | 30K | 0.700 | 0.900 / 0.500 |" in per
    assert cmp.main([str(s0), "--per-scene", "nonsense"]) == 1


def test_a_cell_given_twice_counts_once_or_is_an_error(tmp_path, capsys):
    cmp = _comparison()
    for run in (tmp_path / "a", tmp_path / "b"):
        _cell(run, "strings", "pantry", "7K", 350, 0.5, 0.5, seconds=10 if run.name == "a" else 20)
    _cell(tmp_path / "c", "strings", "pantry", "7K", 350, 0.5, 0.4)
    # the same cell in two folders with the same figures (training time aside) counts once
    once = cmp.collect([tmp_path / "a", tmp_path / "b"])
    assert list(once[("strings", "7K")]) == [0] and once[("strings", "7K")][0]["pantry"]["train_seconds"] == 10
    with pytest.raises(StringsBenchError, match="different figures"):
        cmp.collect([tmp_path / "a", tmp_path / "c"])
    assert cmp.main([str(tmp_path / "a"), str(tmp_path / "c")]) == 1
    assert cmp.main([str(tmp_path / "none")]) == 1
    assert "no run folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert cmp.main([str(tmp_path / "empty")]) == 1
