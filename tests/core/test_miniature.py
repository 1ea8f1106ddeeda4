"""Miniatures: how a shrunk schedule stands in for the paper's (core/schedules.py MINIATURES, `run --miniature`)."""

from __future__ import annotations

import pytest

from _engine_helpers import make_tiny_scene  # noqa: E402

from strings_bench.core.errors import StringsBenchError  # noqa: E402
from strings_bench.core.schedules import MINIATURES, schedule  # noqa: E402


@pytest.fixture(scope="module")
def tiny_scene_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny")
    make_tiny_scene(root)
    return root


def _position_lr_sum(scale: float, miniature: str, extent: float = 2.0) -> float:
    """The position LR summed over a run to the paper's 30K, for 3DGS built at `scale` under `miniature`."""
    from strings_bench.methods.registry import get_method

    settings = schedule("paper", steps_scale=scale, miniature=miniature).miniature_settings()
    method = get_method("3dgs").build(steps_scale=scale, **settings)
    method.extent = extent
    return sum(method.position_lr(step) for step in range(1, round(30_000 * scale) + 1))


def test_lr_sum_keeps_the_papers_position_lr_sum():
    """Against the paper's own sum (3DGS' log-linear decay over 30 000 steps at scale 1): `shrink` gives s times
    it, `lr-sum` the same within the discretisation of the shorter run, `lr-sqrt` sqrt(s) times it."""
    paper = _position_lr_sum(1.0, "shrink")
    for s in (0.05, 0.1, 0.2):
        assert _position_lr_sum(s, "shrink") == pytest.approx(s * paper, rel=0.01)
        assert _position_lr_sum(s, "lr-sum") == pytest.approx(paper, rel=0.01)
        assert _position_lr_sum(s, "lr-sqrt") == pytest.approx(s ** 0.5 * paper, rel=0.01)


def test_miniatures_add_nothing_at_the_papers_scale_and_unknown_ones_are_refused():
    assert all(not schedule("cpu-long", steps_scale=1, miniature=m).miniature_settings() for m in MINIATURES)
    assert schedule("cpu-long").miniature == "shrink" and not schedule("cpu-long").miniature_settings()
    with pytest.raises(StringsBenchError, match=r"(?s)unknown miniature .lr-some.*lr-sum"):
        schedule("cpu-long", miniature="lr-some")


def test_the_plan_gives_every_training_method_the_miniature_and_set_values_win(tiny_scene_dir, tmp_path):
    from strings_bench.bench.plan import plan_run

    plan = plan_run(["3dgs", "strings", "edc-absgs"], [str(tiny_scene_dir)], schedule="cpu-long", miniature="lr-sum",
                    run_dir=tmp_path / "run", method_overrides={"edc-absgs": {"position_lr_gain": 2.0}})
    gains = {j.method: j.method_settings.get("position_lr_gain") for j in plan.jobs}
    assert gains == {"3dgs": pytest.approx(10.0), "strings": pytest.approx(10.0), "edc-absgs": 2.0}
    assert plan.manifest["schedule"]["miniature"] == "lr-sum"
    plain = plan_run(["3dgs"], [str(tiny_scene_dir)], schedule="cpu-long", run_dir=tmp_path / "run2")
    assert "position_lr_gain" not in plain.jobs[0].method_settings


def test_a_folder_of_one_miniature_refuses_another(tiny_scene_dir, tmp_path):
    from strings_bench.bench.plan import plan_run
    from strings_bench.store.manifest import check_manifest, write_manifest

    run_dir = tmp_path / "run"
    first = plan_run(["3dgs"], [str(tiny_scene_dir)], schedule="tiny", miniature="lr-sum", run_dir=run_dir)
    run_dir.mkdir()
    write_manifest(run_dir, first.manifest)
    again = plan_run(["3dgs"], [str(tiny_scene_dir)], schedule="tiny", miniature="lr-sum", run_dir=run_dir)
    check_manifest(run_dir, again.manifest)  # the same miniature resumes
    other = plan_run(["3dgs"], [str(tiny_scene_dir)], schedule="tiny", run_dir=run_dir)
    with pytest.raises(StringsBenchError, match="--miniature lr-sum; this run asks for shrink"):
        check_manifest(run_dir, other.manifest)


def test_the_gain_multiplies_the_first_position_step(tiny_scene_dir):
    """Adam's first step moves each coordinate by the LR, so the motion log of step 1 grows by the gain exactly."""
    from strings_bench.engine.splatting import GaussianSplatting, TrainConfig
    from strings_bench.engine.strategies import Strategy
    from strings_bench.engine.trainer import seed_everything
    from strings_bench.scene.scene import Scene

    paths = []
    for gain in (1.0, 10.0):
        seed_everything(0)
        method = GaussianSplatting(TrainConfig(sh_degree=0, position_lr_gain=gain), Strategy())
        method.setup(Scene.load(tiny_scene_dir), device="cpu")
        method.train_step(1)
        paths.append(method.motion_log["position_path"])
    assert paths[0] > 0 and paths[1] == pytest.approx(10 * paths[0], rel=1e-5)
    with pytest.raises(StringsBenchError, match="position_lr_gain"):
        TrainConfig(position_lr_gain=0.0)


def _refinement_rounds(scale: float, miniature: str) -> int:
    """The steps at which 3DGS' default strategy refines (start < step < stop, step % interval == 0), for 3DGS built
    at `scale` under `miniature`, counted from the strategy's own schedule helpers."""
    from strings_bench.methods.registry import get_method

    settings = schedule("paper", steps_scale=scale, miniature=miniature).miniature_settings()
    method = get_method("3dgs").build(steps_scale=scale, **settings)
    st = method.strategy
    start, stop, every = st.at(st.refine_start_iter), st.at(st.refine_stop_iter), st.every(st.refine_every)
    return sum(1 for step in range(start + 1, stop) if step % every == 0)


def test_rounds_keeps_the_papers_number_of_refinement_rounds():
    """3DGS refines every 100 steps after 500 and before 15 000: 144 rounds. Shrunk by s with the 50-step floor it
    refines far fewer times (28 at x0.1, 14 at x0.05); `rounds` and `lr-sum-rounds` scale the interval too and keep
    144."""
    paper = _refinement_rounds(1.0, "shrink")
    assert paper == 144
    assert _refinement_rounds(0.1, "shrink") == 28 and _refinement_rounds(0.05, "shrink") == 14
    for s in (0.05, 0.1, 0.2):
        assert _refinement_rounds(s, "rounds") == paper
        assert _refinement_rounds(s, "lr-sum-rounds") == paper
    assert schedule("cpu-long", miniature="lr-sum-rounds").miniature_settings() == {
        "position_lr_gain": pytest.approx(10.0), "interval_floor": 1}
    assert schedule("cpu-long", miniature="rounds").miniature_settings() == {"interval_floor": 1}


def test_the_interval_floor_reaches_the_strategy_and_the_sh_schedule(tiny_scene_dir):
    """A trained method under `rounds` at x0.05 refines every 5 steps (100 x 0.05) and raises the SH degree every 50
    (1 000 x 0.05); without it, every 50 and every 50. A floor below 1 step is refused."""
    from strings_bench.engine.splatting import GaussianSplatting, TrainConfig
    from strings_bench.engine.strategies import DefaultStrategy
    from strings_bench.scene.scene import Scene

    intervals = {}
    for floor in (50, 1):
        method = GaussianSplatting(TrainConfig(steps_scale=0.05, interval_floor=floor), DefaultStrategy())
        method.setup(Scene.load(tiny_scene_dir), device="cpu")
        intervals[floor] = (method.strategy.every(method.strategy.refine_every),
                            method.every(method.config.sh_increase_every),
                            method.strategy.reset_interval(method.strategy.reset_every))
    assert intervals == {50: (50, 50, 200), 1: (5, 50, 200)}  # opacity resets keep their own 200-step floor
    with pytest.raises(StringsBenchError, match="interval_floor"):
        TrainConfig(interval_floor=0)


def _agreement_module():
    from _scripts import load_study

    return load_study("miniature")


def _cells(cers: dict) -> list[dict]:
    return [{"method": m, "scene": sc, "label": lab, "cer_known": str(v), "cer": str(v)} for (m, sc, lab), v in cers.items()]


def test_agreement_counts_pairs_ordered_alike_with_ties():
    """Three methods on one scene at 3K (3 pairs): a candidate that swaps one pair agrees on 2 of 3; differences
    under the tie band are ties, which agree only with ties; cells only one side has are left out."""
    agreement = _agreement_module().agreement
    ref = _cells({("a", "s", "3K"): 0.10, ("b", "s", "3K"): 0.50, ("c", "s", "3K"): 0.30, ("a", "s", "7K"): 0.1})
    same = _cells({("a", "s", "3K"): 0.20, ("b", "s", "3K"): 0.90, ("c", "s", "3K"): 0.40})
    swapped = _cells({("a", "s", "3K"): 0.10, ("b", "s", "3K"): 0.30, ("c", "s", "3K"): 0.50})
    tied = _cells({("a", "s", "3K"): 0.30, ("b", "s", "3K"): 0.31, ("c", "s", "3K"): 0.305})
    [row] = agreement(ref, same, tie=0.02)
    alike = "ordered alike (known-text CER)"
    assert (row["ckpt"], row["cells"], row["pairs (known-text CER)"], row[alike]) == ("3K", 3, 3, "1.00")
    assert row["mean abs. difference (known-text CER)"] == "0.200"
    assert agreement(ref, swapped, tie=0.02)[0][alike] == "0.67"
    assert agreement(ref, tied, tie=0.02)[0][alike] == "0.00"
    assert agreement(tied, tied, tie=0.02)[0][alike] == "1.00"


def _timed(cers: dict, seconds: float) -> list[dict]:
    rows = _cells(cers)
    for r in rows:
        r["iteration"] = "3000" if r["label"] == "3K" else "7000"
        r["train_seconds"] = str(seconds if r["label"] == "7K" else seconds / 2)
    return rows


def test_choose_applies_the_rule_coverage_cost_score_then_cost():
    """The rule of docs/miniature.md: a candidate missing a reference cell, or costing more than twice the
    baseline, is not eligible; the best score wins unless a cheaper one is level (within 0.05); nothing is chosen
    while no candidate is eligible."""
    choose = _agreement_module().choose
    ref = {("a", "s", "3K"): 0.1, ("b", "s", "3K"): 0.5, ("c", "s", "3K"): 0.3,
           ("a", "s", "7K"): 0.1, ("b", "s", "7K"): 0.5, ("c", "s", "7K"): 0.3}
    swap = {**ref, ("b", "s", "3K"): 0.2}  # one pair of three out of order at 3K
    reference = _cells(ref)
    cands = {"base": _timed(swap, 100.0), "good": _timed(ref, 150.0), "dear": _timed(ref, 250.0),
             "partial": _timed({k: v for k, v in ref.items() if k[2] == "3K"}, 10.0)}
    rows, chosen, reason = choose(reference, cands, "base")
    by = {r["candidate"]: r for r in rows}
    assert chosen == "good" and "good" in reason
    assert by["dear"]["eligible"] == "no" and by["dear"]["cost / baseline"] == "2.50"
    assert by["partial"]["eligible"] == "no" and by["partial"]["reference cells missing"] == 3
    assert by["good"]["score"] == "1.000" and by["base"]["score"] == "0.833"
    # a level candidate (score within 0.05) that is cheaper wins
    rows, chosen, reason = choose(reference, {"base": _timed(swap, 100.0), "good": _timed(ref, 150.0)}, "base",
                                  level=0.2)
    assert chosen == "base" and "cheaper" in reason
    assert all("0.1" not in str(r.get("cer", "")) for r in rows)  # no CER in the rows
    rows, chosen, _ = choose(reference, {"partial": cands["partial"]}, "partial")
    assert chosen is None


def test_the_reference_verdicts_hold_claims_per_room_and_cer(tmp_path):
    """STRinGS behind a baseline on one room and ahead on the other: mixed; behind the lock's ablation everywhere: no;
    fewer Gaussians than 3DGS by more than 5 % on both rooms: yes; within 5 %: not yes. The column lands in a
    verdict table before its "flips?" column, and a claim the reference cannot speak to says so."""
    mini = _agreement_module()
    rows = []
    for scene, s, g3, e, lock_free, n_s, n_3 in (("a", 0.10, 0.20, 0.15, 0.05, 90, 100), ("b", 0.30, 0.20, 0.25, 0.10, 80, 100)):
        for label in ("3K", "7K"):
            for method, cer, n in (("strings", s, n_s), ("3dgs", g3, n_3), ("edc-absgs", e, n_3),
                                   ("strings-pos-lr", lock_free, n_3)):
                rows.append({"method": method, "scene": scene, "label": label, "cer": f"{cer}",
                             "cer_known": f"{cer}", "gaussians": f"{n}", "train_seconds": "10"})
    got = mini.reference_verdicts(rows, tie=0.02)
    assert got["lower CER than every baseline at 7K"].startswith("mixed (STRinGS; 7K known-text CER: a 0.100 against")
    assert got["the phase-1 position lock helps"].startswith("no (")
    assert got["fewer Gaussians"].startswith("yes at 7K")
    assert got["lower CER at 30K"].startswith("not measured")
    level = [dict(r, gaussians="97") if r["method"] == "strings" else r for r in rows]
    assert mini.reference_verdicts(level)["fewer Gaussians"].startswith("mixed")
    table = tmp_path / "verdicts.csv"
    table.write_text("the paper's claim,x0.1,flips?\nfewer Gaussians,no,no\nsomething else,no,no\n")
    from strings_bench.reports.doc_tables import set_table_column

    set_table_column(table, mini.REFERENCE_COLUMN, got)
    import csv

    lines = list(csv.reader(table.open(newline="")))
    assert lines[0] == ["the paper's claim", "x0.1", mini.REFERENCE_COLUMN, "flips?"]
    assert lines[1][2].startswith("yes at 7K") and lines[2] == ["something else", "no", "not measured", "no"]
