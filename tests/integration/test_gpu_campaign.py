"""scripts/gpu_campaign.sh before a GPU ever runs it: the whole `verify` stage in --dry-run (every step
on the CPU at 64x48: the same commands, tiny sizes), banking, skipping what is banked, the stage's time
budget (a step cut short is `partial` and the stage is not banked), and the choice of the 30K setting.

The dry run takes ~70 s on a loaded 2-core machine (most of it OCR of the renders, as in a real run)."""

from __future__ import annotations

import csv
import json
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "gpu_campaign.sh"


# The rounds' date, set by the tests rather than read from the clock (the fixtures carry dates of their own).
ROUND_DATE = "2020-03-02"


def campaign(*args, timeout=600, env=None):
    env = {**os.environ, "PYTHON": sys.executable, "PYTHONPATH": str(ROOT), **(env or {})}
    dated = args if "--date" in args else ("--date", ROUND_DATE, *args)
    return subprocess.run(["bash", str(SCRIPT), *map(str, dated)], capture_output=True, text=True, timeout=timeout,
                          env=env)


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _module():
    spec = importlib.util.spec_from_file_location("gpu_campaign", ROOT / "scripts" / "gpu_campaign.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# The whole verify stage (about 2 minutes loaded): opt-in; the later-round, budget, calibration and x1 tests below
# run its steps in CI.
@pytest.mark.slow
def test_dry_run_of_verify_banks_every_step_then_skips(tmp_path):
    out = tmp_path / "gpu"
    done = campaign("--dry-run", out, "verify")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    (steps_csv,) = out.glob("*_verify_cpu-dry-run.csv")
    steps = rows(steps_csv)
    assert [r["step"] for r in steps] == ["versions", "compile", "pytest_gpu", "benchmark_320x240", "build_books",
                                          "paper_run_strings", "paper_run_3dgs", "benchmark_1280x960"]
    assert all(r["status"] == "ok" for r in steps), steps
    import torch

    assert {(r["gpu"], r["torch"], r["dry_run"]) for r in steps} == {("cpu (dry run)", torch.__version__, "true")}
    assert steps[0]["gsplat"] not in ("", "none")
    assert "skipped" in steps[2]["detail"]  # pytest -m gpu ran and skipped ("no CUDA")
    results = [r for m in ("strings", "3dgs") for r in rows(next(out.glob(f"*_verify_paper_run_{m}_cpu-dry-run.csv")))]
    assert [r["method"] for r in results] == ["strings", "3dgs"]  # each step banks its own method's cell
    assert all(float(r["peak_memory_mb"]) > 0 and r["gpu"] == "cpu (dry run)" for r in results)
    assert all(r["iteration"] == "35" for r in results)  # 7K on the tiny schedule (x0.005)
    for size in ("320x240", "1280x960"):  # the benchmark's rows, versions added
        (bench,) = rows(next(out.glob(f"*_verify_benchmark_{size}_cpu-dry-run.csv")))
        assert bench["method"] == "3dgs" and bench["device"] == "cpu" and float(bench["steps_per_s"]) > 0
        assert bench["gpu"] == "cpu (dry run)" and bench["size"] == "64x48"
    before = steps_csv.read_bytes()
    again = campaign("--dry-run", out, "verify", timeout=60)
    assert again.returncode == 0 and "banked" in again.stdout and "skipped" in again.stdout
    assert steps_csv.read_bytes() == before


def test_a_stage_cut_by_its_budget_is_partial_and_not_banked(tmp_path):
    out = tmp_path / "gpu"
    done = campaign("--dry-run", "--budget", "0.3", out, "verify", timeout=120)
    assert done.returncode == 1
    (steps_csv,) = out.glob("*_verify_*.csv")
    statuses = {r["step"]: r["status"] for r in rows(steps_csv)}
    # the first step that needs time is cut; without gsplat nothing else can run, so the stage stops
    assert statuses == {"versions": "ok", "compile": "partial"}, statuses
    assert _module().banked(out, "verify", dry_run=True) is None


def test_without_cuda_the_real_campaign_refuses(tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("CUDA present")
    done = campaign(tmp_path, "verify", timeout=60)
    assert done.returncode == 2 and "no CUDA" in done.stderr
    assert campaign(tmp_path, "list", timeout=60).stdout.split() == list(_module().STAGES)


def test_dry_run_of_a_calibration_point_banks_its_run(tmp_path):
    out = tmp_path / "gpu"
    done = campaign("--dry-run", out, "cal7k-rs2", timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert [r["step"] for r in rows(next(out.glob("*_cal7k-rs2_cpu-dry-run.csv")))] == ["versions", "compile", "build_storeroom", "run"]
    (run,) = rows(next(out.glob("*_cal7k-rs2_run_cpu-dry-run.csv")))
    assert run["method"] == "3dgs" and run["iteration"] == "35" and run["label"] == "7K"


def test_30k_uses_the_banked_7k_point_closest_to_the_paper(tmp_path):
    mod = _module()
    for rs, cer in (("1.5", "0.95"), ("2", "0.70")):
        path = tmp_path / f"2020-03-01_cal7k-rs{rs}_run_nvidia-h100.csv"
        path.write_text(f"method,iteration,cer\n3dgs,7000,{cer}\n")
    assert mod._banked_7k(tmp_path)[0] == (pytest.approx(0.036), 2.0)
    done = campaign("--dry-run", tmp_path / "empty", "cal30k", timeout=60)  # nothing banked: a clear failure
    assert done.returncode == 1
    (steps_csv,) = (tmp_path / "empty").glob("*_cal30k_*.csv")
    (row,) = rows(steps_csv)
    assert row["step"] == "choose_setting" and row["status"] == "failed" and "cal7k" in row["detail"]


def test_a_later_round_skips_the_steps_already_banked(tmp_path):
    """The later round runs on the earlier one's date (a warm machine, two rounds in a day; the date is the
    test's, not the clock's): the earlier round's files stay as they were and the new round writes its own."""
    out = tmp_path / "gpu"
    out.mkdir()
    mod = _module()
    day = "2020-03-01"
    earlier = [{"date": day, "stage": "verify", "step": step, "status": status, "seconds": "1",
                "detail": "", "dry_run": "true"} for step, status in
               (("versions", "ok"), ("compile", "ok"), ("pytest_gpu", "ok"), ("benchmark_320x240", "partial"),
                ("paper_run", "partial"))]
    mod.Round.write(out / f"{day}_verify_cpu-dry-run.csv", mod.STEP_COLUMNS, earlier)
    # the earlier round's steps were cut, but after the 320x240 benchmark's rows and STRinGS' 7K cell
    (out / f"{day}_verify_benchmark_320x240_cpu-dry-run.csv").write_text(
        "method,size,device,steps_per_s,dry_run\n3dgs,64x48,cpu,9.0,true\n")
    (out / f"{day}_verify_paper_run_cpu-dry-run.csv").write_text(
        "method,iteration,label,cer,dry_run\nstrings,35,7K,0.9,true\n3dgs,15,3K,0.9,true\n")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # A budget that leaves the compile step and the scene build room on a slow clean clone (a 4 s budget
    # cut the compile step itself there: cold imports) and may or may not cut 3DGS' run and the last
    # benchmark (a stage cut by its budget: test_a_stage_cut_by_its_budget_is_partial_and_not_banked).
    done = campaign("--dry-run", "--budget", "45", "--date", day, out, "verify", timeout=180)
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name in before} == before  # nothing overwritten
    today = out / f"{day}.2_verify_cpu-dry-run.csv"
    steps = {r["step"]: r for r in rows(today)}
    assert {r["date"] for r in steps.values()} == {day}
    assert steps["compile"]["status"] == "ok", steps["compile"]
    assert steps["compile"]["detail"] != "" and "banked" not in steps["compile"]["detail"]  # a fresh machine compiles
    for name in ("pytest_gpu", "benchmark_320x240", "paper_run_strings"):
        assert steps[name]["status"] == "ok" and steps[name]["detail"].startswith(f"banked in {day}_"), steps[name]
    # 3DGS has only a 3K row banked: its run goes again (to the end, or cut: partial), into the new round's file
    ran = [steps[n]["status"] for n in ("paper_run_3dgs", "benchmark_1280x960") if n in steps]
    assert ran and set(ran) <= {"ok", "partial"} and "banked" not in steps["paper_run_3dgs"]["detail"]
    assert (out / f"{day}.2_verify_paper_run_3dgs_cpu-dry-run.csv").exists() or steps["paper_run_3dgs"]["status"] == "partial"
    assert done.returncode == (0 if ran == ["ok", "ok"] else 1)


def test_a_round_is_named_by_its_date_and_its_number_that_day(tmp_path):
    mod = _module()
    assert mod.round_stem(tmp_path, "2026-11-30", "verify", "nvidia-h200") == "2026-11-30"
    (tmp_path / "2026-11-30_verify_nvidia-h200.csv").write_text("")
    (tmp_path / "2026-11-30_x1-rooms_nvidia-h100.csv").write_text("")  # another stage or GPU: no matter
    assert mod.round_stem(tmp_path, "2026-11-30", "verify", "nvidia-h200") == "2026-11-30.2"
    assert mod.round_stem(tmp_path, "2020-03-01", "verify", "nvidia-h200") == "2020-03-01"
    assert mod.round_stem(tmp_path, "2026-11-30", "x1-rooms", "nvidia-h200") == "2026-11-30"
    (tmp_path / "2026-11-30.2_verify_nvidia-h200.csv").write_text("")
    assert mod.round_stem(tmp_path, "2026-11-30", "verify", "nvidia-h200") == "2026-11-30.3"
    bad = campaign("--dry-run", "--date", "1 December", tmp_path, "verify", timeout=60)
    assert bad.returncode == 2 and "YYYY-MM-DD" in bad.stderr


def test_the_next_real_round_skips_what_the_first_one_banked():
    """On the CSVs committed in docs/results/data/gpu (the first round, an H200, cut by its step limits):
    STRinGS' 7K run on books and the 320x240 benchmark are banked; 3DGS' run, the 1280x960 benchmark and
    pytest -m gpu (cut) are not."""
    mod = _module()
    out = ROOT / "docs" / "results" / "data" / "gpu"
    assert mod.banked_run(out, "verify", "paper_run*", ["strings"], "7K", False)
    assert mod.banked_run(out, "verify", "paper_run*", ["3dgs"], "7K", False) is None
    both = {(m, d) for m in ("3dgs", "strings") for d in ("cuda", "cpu")}
    assert mod.banked_benchmark(out, "verify", "benchmark_320x240", both, False)
    assert mod.banked_benchmark(out, "verify", "benchmark_1280x960", {("3dgs", "cuda")}, False) is None
    assert "pytest_gpu" not in mod.banked_steps(out, "verify", False)
    assert mod.banked(out, "verify", False) is None


@pytest.mark.heavy
def test_x1_rooms_builds_a_room_only_for_the_cells_it_runs(tmp_path):
    """Storeroom's four 7K cells banked by an earlier round: this round skips them without building
    storeroom, builds pantry (synthetic360-cpu's rooms with the text heights scaled with the width) and
    starts its cells in order until the budget cuts them. The kernels and rooms are prepared first into the round's
    cache (`--prepare`, as on a CPU before a GPU is lent), so that what the budget has to hold does not depend on
    how fast or loaded the machine is: a room found in the cache, then training."""
    cache = {"STRINGS_BENCH_CACHE": str(tmp_path / "cache")}
    warm = campaign("--dry-run", "--prepare", "--budget", "400", tmp_path / "warm", "x1-rooms", timeout=600, env=cache)
    assert warm.returncode == 0, warm.stdout[-3000:] + warm.stderr[-3000:]
    out = tmp_path / "gpu"
    out.mkdir()
    mod = _module()
    for method in mod.X1_METHODS:
        (out / f"2020-03-01_x1-rooms_x1_storeroom_{method}_7k_cpu-dry-run.csv").write_text(
            f"method,iteration,label,cer,dry_run\n{method},15,3K,0.9,true\n{method},35,7K,0.8,true\n")
    campaign("--dry-run", "--budget", "60", out, "x1-rooms", timeout=240, env=cache)
    (today,) = [p for p in out.glob("*_x1-rooms_cpu-dry-run.csv")]
    steps = [r["step"] for r in rows(today)]
    assert steps[:2] == ["versions", "compile"] and "build_storeroom" not in steps
    assert steps[2:6] == [f"x1_storeroom_{m}_7k" for m in mod.X1_METHODS]
    assert all(r["detail"].startswith("banked in 2020-03-01") for r in rows(today)[2:6])
    assert steps[6] == "build_pantry" and rows(today)[6]["status"] == "ok", rows(today)[6]
    pantry_cells = [f"x1_pantry_{m}_7k" for m in mod.X1_METHODS]
    assert len(steps) > 7 and steps[7:] == pantry_cells[:len(steps) - 7]  # in order, until the budget cut them
    pantry = Path((out / "runs" / "logs" / "x1-rooms_scene_pantry.path").read_text().strip())
    meta = json.loads((pantry / "scene_meta.json").read_text())
    assert meta["text_px"] == [2.0, 3.2]  # synthetic360-cpu's 10-16 px at 320 wide, at 64 wide
    assert (meta["settings"]["width"], meta["settings"]["n_views"]) == (64, 48)  # the configuration's 48 views


def test_prepare_compiles_and_builds_but_banks_nothing(tmp_path):
    out = tmp_path / "gpu"
    done = campaign("--dry-run", "--prepare", "--budget", "200", out, "verify,x1-rooms", timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert not list(out.glob("*.csv"))  # nothing a later round would take as banked
    logged = {r["stage"]: [x["step"] for x in rows(p)] for p in (out / "runs" / "logs").glob("*.csv")
              for r in rows(p)[:1]}
    assert logged == {"verify": ["versions", "compile", "build_books"],
                      "x1-rooms": ["versions", "compile", "build_storeroom", "build_pantry", "build_office"]}


def test_unknown_stage_is_refused_with_the_list(tmp_path):
    done = campaign("--dry-run", tmp_path, "verify,nope", timeout=60)
    assert done.returncode == 2 and "nope" in done.stderr and "x1-rooms" in done.stderr


def test_x1_rooms_320_builds_the_registered_cpu_rooms_and_1280_scales_their_text(tmp_path, monkeypatch):
    """x1-rooms-320's scenes are synthetic360-cpu's own (the same settings, so the same cache key as the
    CPU reference cells); x1-rooms' are the same rooms at 1280x960 with the word heights x4."""
    from dataclasses import replace

    from strings_bench.datasets.synthetic import default_settings

    mod = _module()
    for stage, (w, h, scale) in (("x1-rooms-320", (320, 240, 1)), ("x1-rooms", (1280, 960, 4))):
        built = []
        monkeypatch.setattr(mod.Round, "compile", lambda self: "ok")
        monkeypatch.setattr(mod.Round, "build", lambda self, scene, dataset=None, **kw: built.append((scene, dataset, kw)))
        monkeypatch.setattr(mod.Round, "run", lambda self, *a, **kw: None)
        s = mod.Round(tmp_path / stage, stage, dry_run=False, budget_s=60)
        mod.STAGES[stage](s)
        assert [b[0] for b in built] == list(mod.X1_ROOMS)  # a build that fails moves on to the next room
        for room, dataset, kw in built:
            registered = default_settings(room, dataset)
            assert dataset == "synthetic360-cpu"
            settings = replace(registered, width=kw["width"], height=kw["height"], text_px=tuple(kw["text_px"]))
            assert (settings.width, settings.height, settings.text_px) == (w, h, (10.0 * scale, 16.0 * scale))
            if scale == 1:
                assert settings == registered


# The capture's scene is built in the dry run (SfM and OCR masks of 9 photos: about two minutes on 2 cores), so
# opt-in; CI runs it in a step of its own (.ci/run).
@pytest.mark.slow
def test_captures_7k_dry_run_banks_each_cell_then_skips_it(tmp_path):
    out = tmp_path / "gpu"
    env_cache = {"STRINGS_BENCH_CACHE": str(tmp_path / "cache")}
    done = campaign("--dry-run", "--budget", "1200", out, "captures-7k", timeout=1500, env=env_cache)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    (steps_csv,) = out.glob(f"{ROUND_DATE}_captures-7k_cpu-dry-run.csv")
    steps = rows(steps_csv)
    assert [r["step"] for r in steps] == ["versions", "compile", "build_bundler_et", "bundler_et_3dgs_7k"]
    assert all(r["status"] == "ok" for r in steps), steps
    (cell,) = rows(next(out.glob("*_captures-7k_bundler_et_3dgs_7k_cpu-dry-run.csv")))
    assert cell["method"] == "3dgs" and cell["label"] == "7K" and float(cell["peak_memory_mb"]) > 0
    again = campaign("--dry-run", "--force", "--date", "2020-03-03", out, "captures-7k", timeout=600, env=env_cache)
    assert again.returncode == 0, again.stdout[-3000:]
    later = {r["step"]: r for r in rows(out / "2020-03-03_captures-7k_cpu-dry-run.csv")}
    assert "build_bundler_et" not in later  # every cell banked: the scene is not even looked for
    assert later["bundler_et_3dgs_7k"]["detail"].startswith(f"banked in {ROUND_DATE}_")
