"""The verdict engine: one rule, planted cells for each of its outcomes, its false-call rate against the exact
combinatorial value, and `strings-bench verdicts` regenerating the committed tables byte for byte."""

from __future__ import annotations

import shutil
from math import comb
from pathlib import Path

import numpy as np
import pytest

from strings_bench.eval.floors import MIN_GT_CHARS, MIN_READ_CHARS
from strings_bench.reports import verdicts as V

ROOT = Path(__file__).resolve().parents[2]
CER_CLAIM = next(c for c in V.CLAIMS if c.key == "cer-7k")
TIME_CLAIM = next(c for c in V.CLAIMS if c.key == "time-30k")


def cells(method: str, values_by_seed: dict, chars: int = 300, errors=None, label: str = "7K", metric: str = "cer",
          scene: str = "room", kernels: str = "cpu_model=A") -> list[dict]:
    """Planted banked records: one per seed, `metric` set to the value; GT characters and errors as given (errors
    default to CER x characters)."""
    out = []
    for seed, v in values_by_seed.items():
        e = round(v * chars) if errors is None else errors
        out.append({"method": method, "scene": scene, "draw": 0, "seed": seed, "checkpoint": label, metric: v,
                    "cer_chars": chars if metric == "cer" else "", "cer_errors": e if metric == "cer" else "",
                    "kernels": kernels})
    return out


def verdict(rows, claim=CER_CLAIM, interleaved=True):
    figs = V.figures_rows(rows, claim.metric, claim.checkpoint, None, "checkpoint")
    others = {m: f for m, f in figs.items() if m != V.REFERENCE}
    return V.judge(claim, figs.get(V.REFERENCE), others, interleaved=interleaved)


def test_apart_on_the_claimed_side_is_holding():
    rows = cells("strings", {0: 0.20, 1: 0.22, 2: 0.21}) + cells("3dgs", {0: 0.40, 1: 0.38, 2: 0.41})
    v = verdict(rows)
    assert v.verdict == "holding" and v.sides == {"3dgs": "below"}


def test_apart_on_the_other_side_is_not_holding():
    rows = (cells("strings", {0: 0.40, 1: 0.42, 2: 0.41}) + cells("3dgs", {0: 0.60, 1: 0.65, 2: 0.62})
            + cells("edc-absgs", {0: 0.20, 1: 0.22, 2: 0.21}))
    v = verdict(rows)
    assert v.verdict == "not holding" and "edc-absgs" in v.reason


def test_overlapping_ranges_are_not_decided():
    rows = cells("strings", {0: 0.20, 1: 0.30, 2: 0.25}) + cells("3dgs", {0: 0.28, 1: 0.35, 2: 0.40})
    assert verdict(rows).verdict == "not decided"


def test_one_seed_is_not_judged_however_far_apart():
    rows = cells("strings", {0: 0.10}) + cells("3dgs", {0: 0.90})
    v = verdict(rows)
    assert v.verdict == "not judged" and "1 replicate" in v.reason


def test_two_seeds_are_not_judged_either():
    rows = cells("strings", {0: 0.10, 1: 0.11}) + cells("3dgs", {0: 0.90, 1: 0.91})
    assert verdict(rows).verdict == "not judged"


def test_gt_below_its_floor_is_not_scorable():
    rows = (cells("strings", {0: 0.2, 1: 0.2, 2: 0.2}, chars=MIN_GT_CHARS - 1)
            + cells("3dgs", {0: 0.9, 1: 0.9, 2: 0.9}, chars=MIN_GT_CHARS - 1))
    v = verdict(rows)
    assert v.verdict == "not scorable" and "GT reads" in v.reason


def test_renders_reading_too_little_are_not_scorable():
    # 200 GT characters, CERs apart (0.93 against 1.0) but the best method reads only 14 of them
    rows = (cells("strings", {0: 0.93, 1: 0.93, 2: 0.93}, chars=200, errors=186)
            + cells("3dgs", {0: 1.0, 1: 1.01, 2: 1.0}, chars=200, errors=200))
    v = verdict(rows)
    assert v.verdict == "not scorable" and "best method reads 14" in v.reason
    # the same CERs reading enough: judged
    rows = (cells("strings", {0: 0.80, 1: 0.81, 2: 0.80}, chars=200)
            + cells("3dgs", {0: 1.0, 1: 1.01, 2: 1.0}, chars=200))
    assert 200 * 0.2 >= MIN_READ_CHARS and verdict(rows).verdict == "holding"


def test_time_is_judged_only_on_interleaved_cells():
    rows = (cells("strings", {0: 500, 1: 510, 2: 505}, label="30K", metric="train_cpu_seconds")
            + cells("3dgs", {0: 700, 1: 690, 2: 720}, label="30K", metric="train_cpu_seconds"))
    assert verdict(rows, TIME_CLAIM, interleaved=True).verdict == "holding"
    v = verdict(rows, TIME_CLAIM, interleaved=False)
    assert v.verdict == "not judged" and "interleaved" in v.reason
    # interleaved, but 3DGS' cells on another machine: CPU seconds of two CPUs are not one measure
    rows = (cells("strings", {0: 500, 1: 510, 2: 505}, label="30K", metric="train_cpu_seconds")
            + cells("3dgs", {0: 700, 1: 690, 2: 720}, label="30K", metric="train_cpu_seconds", kernels="cpu_model=B"))
    v = verdict(rows, TIME_CLAIM, interleaved=True)
    assert v.verdict == "not judged" and "2 machines" in v.reason


def test_a_seed_counts_only_once_it_holds_every_scene():
    """Cells banked as they finish: a seed with one of the scale's rooms missing is left out of the figure (a mean
    over fewer rooms is another quantity), and counts once its last room is banked."""
    rows = []
    for scene, offset in (("storeroom", 0.0), ("pantry", 0.1)):
        rows += cells("strings", {0: 0.30 + offset, 1: 0.31 + offset, 2: 0.32 + offset}, scene=scene)
        rows += cells("3dgs", {0: 0.60 + offset, 1: 0.61 + offset}, scene=scene)
    rows += cells("3dgs", {2: 0.62}, scene="storeroom")  # seed 2's pantry still running
    figs = V.figures_rows(rows, "cer", "7K", None, "checkpoint")
    assert figs["3dgs"].seeds == 2 and figs["3dgs"].mean == pytest.approx((0.65 + 0.66) / 2)
    assert figs["strings"].seeds == 3 and figs["strings"].scenes == 2
    rows += cells("3dgs", {2: 0.72}, scene="pantry")
    figs = V.figures_rows(rows, "cer", "7K", None, "checkpoint")
    assert figs["3dgs"].seeds == 3 and figs["3dgs"].hi == pytest.approx(0.67)
    # a scale that names its rooms: a room no method has banked yet leaves every seed out
    assert V.figures_rows(rows, "cer", "7K", None, "checkpoint", ("storeroom", "pantry", "office")) == {}


def test_a_method_not_run_is_named_and_a_missing_reference_is_not_measured():
    rows = cells("3dgs", {0: 0.4, 1: 0.4, 2: 0.4})
    assert verdict(rows).verdict == "not measured"


def test_every_claim_names_its_scope_and_the_papers_figures():
    keys = [c.key for c in V.CLAIMS]
    assert len(set(keys)) == len(keys)
    for c in V.CLAIMS:
        assert c.against and c.checkpoint in ("3K", "7K", "30K") and c.paper and c.source and c.datasets
    assert next(c for c in V.CLAIMS if c.key == "lock-3k").checkpoint == "3K"  # Table 4: end of phase 1
    assert next(c for c in V.CLAIMS if c.key == "gaussians-30k").checkpoint == "30K"  # Table 3


def test_false_call_rate_matches_the_exact_chance_of_ranges_apart():
    # Null cells: every replicate from one distribution. Against one method the rule calls a difference exactly
    # when the two samples' ranges are apart: probability 2 / C(2n, n) (0.1 at n = 3).
    rng = np.random.default_rng(7)
    claim = V.Claim("sim", "sim", "x", "7K", ("a",), "", "", "")
    n, trials = 3, 4000
    called = 0
    for _ in range(trials):
        r, o = rng.standard_normal(n), rng.standard_normal(n)
        f = lambda x: V.Figure(float(x.mean()), float(x.min()), float(x.max()), seeds=n)  # noqa: E731
        called += V.judge(claim, f(r), {"a": f(o)}).verdict in ("holding", "not holding")
    exact = 2 / comb(2 * n, n)
    se = (exact * (1 - exact) / trials) ** 0.5
    assert abs(called / trials - exact) < 4 * se


def test_banked_false_call_table_agrees_with_the_exact_values():
    import csv

    rows = list(csv.DictReader((ROOT / "docs/results/data/verdicts/false_calls.csv").open()))
    for r in rows:
        if r["methods held against"] == "1":
            exact, trials = float(r["exact, one method (2/C(2n,n))"]), int(r["trials"])
            se = (exact * (1 - exact) / trials) ** 0.5
            assert abs(float(r["false call"]) - exact) < 4 * se + 1e-4


def test_verdicts_command_regenerates_the_committed_files_byte_for_byte():
    files = V.outputs(ROOT)
    assert files, "no outputs"
    for rel, text in files.items():
        assert (ROOT / rel).read_text(encoding="utf-8") == text, f"{rel} differs from what the banked data give"


def test_verdicts_check_fails_when_a_banked_figure_changes(tmp_path):
    from strings_bench.cli import main

    root = tmp_path / "repo"
    for rel in {s.file(c.checkpoint) for s in V.SCALES for c in V.CLAIMS if s.file(c.checkpoint)} | {
            "docs/results/data/verdicts"}:
        src = ROOT / rel
        dst = root / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_dir():
            shutil.copytree(src, dst, dirs_exist_ok=True)
        else:
            shutil.copy(src, dst)
    for bank, _ in V.BANKS:
        if (ROOT / bank).is_dir():
            shutil.copytree(ROOT / bank, root / bank, dirs_exist_ok=True)
    assert main(["verdicts", "--check", "--root", str(root)]) == 0
    x1 = root / "docs/results/data/full-schedule/results.csv"
    text = x1.read_text()
    assert ",3000,3K,0.67601246105919," in text  # STRinGS' 3K OCR-CER on pantry
    x1.write_text(text.replace(",3000,3K,0.67601246105919,", ",3000,3K,0.11601246105919,"))
    assert main(["verdicts", "--check", "--root", str(root)]) == 1
    assert main(["verdicts", "--root", str(root)]) == 0
    assert main(["verdicts", "--check", "--root", str(root)]) == 0


@pytest.mark.parametrize("verdict_name", ["holding", "not holding", "not decided", "not judged", "not scorable"])
def test_the_committed_table_holds_each_outcome_with_its_reason(verdict_name):
    import csv

    rows = list(csv.DictReader((ROOT / "docs/results/data/verdicts/verdicts.csv").open()))
    hits = [r for r in rows if r["verdict"] == verdict_name]
    assert hits and all(r["reason"] and r["data"] for r in hits)


def test_a_scale_whose_seeds_are_incomplete_says_so():
    """x0.05's records with STRinGS and 3DGS banked on two of the three rooms: every claim there is "not measured",
    and the reason says that no seed holds all the rooms yet, naming them."""
    rows = []
    for scene in ("storeroom", "office"):
        for method in ("strings", "3dgs"):
            for label in ("3K", "7K", "30K"):
                rows += cells(method, {0: 0.5, 1: 0.6, 2: 0.55}, label=label, scene=scene)
    verdicts, _ = V.evaluate(ROOT, {V.ROOMS_RECORDS: rows})
    x005 = [v for v in verdicts if v["scale_key"] == "x0.05"]
    assert x005 and all(v["verdict"] == "not measured" for v in x005)
    assert all("no seed holds all 3 of the scale's scenes yet (storeroom, pantry, office" in v["reason"] for v in x005)
