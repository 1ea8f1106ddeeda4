"""The equal Gaussian budget (issue 42): the setting `gaussian_budget` (`StrategyContext.budget`), honoured by every trainable method at every step.

The selection under a budget is checked against by-hand references (plain sorting of constructed statistics); the
per-step test trains every registered trainable method a few dozen steps with densification made aggressive, so
that the cap binds, and fails as soon as one holds more Gaussians than the cap after any step.
"""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.bench.plan import plan_run

import math

import numpy as np
import pandas as pd
import pytest
import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.strategies import StrategyContext
from strings_bench.engine.strategies.base import keep_within_budget


# ---- keep_within_budget against brute force --------------------------------------------------------------------
def _by_hand(candidates, scores, cost, room):
    order = sorted((i for i, c in enumerate(candidates) if c), key=lambda i: (-scores[i], i))
    kept, used = set(), 0
    for i in order:
        if used + cost[i] > room:
            break
        kept.add(i)
        used += cost[i]
    return [i in kept for i in range(len(candidates))]


@pytest.mark.parametrize("seed", range(6))
def test_keep_within_cap_matches_a_by_hand_greedy(seed):
    rng = np.random.default_rng(seed)
    n = 40
    cand = rng.random(n) < 0.6
    scores = np.round(rng.random(n), 1)  # ties on purpose: the lower index first
    cost = rng.integers(1, 3, n)
    room = int(rng.integers(0, 30))
    got = keep_within_budget(torch.from_numpy(cand), torch.from_numpy(scores), torch.from_numpy(cost), room)
    assert got.tolist() == _by_hand(cand.tolist(), scores.tolist(), cost.tolist(), room)
    assert int((torch.from_numpy(cost) * got).sum()) <= room


def test_keep_within_cap_without_budget_or_with_room_keeps_every_candidate():
    cand = torch.tensor([True, False, True])
    assert keep_within_budget(cand, torch.zeros(3), 1, None).tolist() == [True, False, True]
    assert keep_within_budget(cand, torch.zeros(3), 1, 2).tolist() == [True, False, True]
    assert keep_within_budget(cand, torch.zeros(3), 1, 0).tolist() == [False, False, False]


def test_budget_must_be_a_positive_count():
    from strings_bench.engine.splatting import TrainConfig

    for bad in (0, -5, 2.5):
        with pytest.raises(StringsBenchError, match="gaussian_budget must be a positive"):
            TrainConfig(gaussian_budget=bad)


# ---- each strategy's selection under a budget, on constructed statistics ----------------------------------------
def _model(n, big=()):
    from strings_bench.engine.gaussians import GaussianModel

    rng = np.random.default_rng(0)
    model = GaussianModel.from_points(rng.normal(size=(n, 3)), np.full((n, 3), 128, np.uint8), sh_degree=0)
    with torch.no_grad():
        model.params["log_scales"].fill_(math.log(0.001))
        for i in big:
            model.params["log_scales"][i] = math.log(0.5)  # > grow_scale3d x extent (0.01 x 1): a split
    return model


def test_default_strategy_grows_the_largest_mean_gradients_first():
    from strings_bench.engine.strategies import DefaultStrategy

    n = 10
    model = _model(n, big=(1, 6))
    strategy = DefaultStrategy(context=StrategyContext(budget=n + 3))
    state = strategy.initialize_state(scene_extent=1.0)
    grad = [5, 9, 1, 8, 0.5, 7, 6, 0.1, 4, 3]  # x 1e-4; threshold 2e-4 -> candidates 0,1,3,5,6,8,9
    state.update(grad2d=torch.tensor(grad) * 1e-4 * 2, count=torch.full((n,), 2.0), max_radii=torch.ones(n))
    clone, split = strategy._fit_budget(model, state, 600, *strategy._select(model, state, 600))
    # by hand: candidates by decreasing mean gradient: 1 (split), 3, 5, 6 (split), ...; room 3, each costs 1
    assert clone.nonzero().squeeze(1).tolist() == [3, 5] and split.nonzero().squeeze(1).tolist() == [1]
    assert strategy.dropped_for_budget == 7 - 3


def test_absgs_ranks_clones_and_splits_by_their_statistic_over_its_threshold():
    from strings_bench.engine.strategies.absgs import AbsGSStrategy

    n = 6
    model = _model(n, big=(0, 1, 2))
    strategy = AbsGSStrategy(context=StrategyContext(budget=n + 2))
    state = strategy.initialize_state(scene_extent=1.0)
    # large (0-2) split on |grad| >= 4e-4; small (3-5) clone on grad >= 2e-4
    grad = torch.tensor([0, 0, 0, 3e-4, 5e-4, 2.2e-4])
    absgrad = torch.tensor([9e-4, 5e-4, 4.4e-4, 0, 0, 0])
    state.update(grad2d=grad, grad2d_abs=absgrad, count=torch.ones(n), max_radii=torch.ones(n))
    clone, split = strategy._fit_budget(model, state, 600, *strategy._select(model, state, 600))
    # over threshold: 0: 2.25, 1: 1.25, 2: 1.1, 3: 1.5, 4: 2.5, 5: 1.1 -> the two best: 4 (clone), 0 (split)
    assert clone.nonzero().squeeze(1).tolist() == [4] and split.nonzero().squeeze(1).tolist() == [0]


@pytest.mark.parametrize("release", [False, True])
def test_edc_ranks_by_the_absolute_gradient_it_selects_on(release):
    from strings_bench.engine.strategies.edc import EDCStrategy

    n = 5
    model = _model(n)
    strategy = EDCStrategy(context=StrategyContext(budget=n + 2), release_schedule=release)
    state = strategy.initialize_state(scene_extent=1.0)
    count = torch.tensor([1.0, 100, 1, 1, 1])
    absgrad = torch.tensor([9e-4, 5e-4, 8e-4, 4e-4, 2e-4]) * count
    state.update(grad2d=torch.zeros(n), grad2d_abs=absgrad, count=count, max_radii=torch.ones(n))
    clone, split = strategy._fit_budget(model, state, 20_000, *strategy._select(model, state, 20_000))
    assert not clone.any()
    # mean |grad|: 9, 5, 8, 4, 2 (e-4); the release multiplies the 100-view one by 1.3 -> 6.5 (still below 8)
    assert split.nonzero().squeeze(1).tolist() == [0, 2]
    strategy.grow_grad2d_abs = 1e-5
    clone, split = strategy._fit_budget(model, state, 20_000, *strategy._select(model, state, 20_000))
    assert split.nonzero().squeeze(1).tolist() == [0, 2]


def test_mcmc_takes_the_budget_as_its_cap():
    from strings_bench.engine.strategies.mcmc import MCMCStrategy

    assert MCMCStrategy(context=StrategyContext(budget=1234), cap_max=99).initialize_state(1.0)["cap"] == 1234
    assert MCMCStrategy(cap_max=99).initialize_state(1.0)["cap"] == 99


def test_eq1_under_a_budget_densifies_the_least_observed_points_first():
    from strings_bench.methods.strings.densify import fit_factors_to_budget

    k = np.array([3, 15, 1, 8, 15, 2])
    # 6 Gaussians, budget 25 -> 19 children to spare: 15 (index 1, +14) then 15 (index 4, +14) does not fit: stop
    assert fit_factors_to_budget(k, 25).tolist() == [1, 15, 1, 1, 1, 1]
    assert fit_factors_to_budget(k, 34).tolist() == [1, 15, 1, 1, 15, 1]
    assert fit_factors_to_budget(k, 1000).tolist() == k.tolist()
    assert fit_factors_to_budget(k, None).tolist() == k.tolist()


# ---- every trainable method, every step -------------------------------------------------------------------------
# Settings that make densification aggressive in a few dozen steps at steps_scale 1 (each applied where the method
# has the key). A new method whose growth these keys do not reach must add its own: the test also checks that the
# cap was reached, so a method that never grows cannot pass unnoticed.
DENSIFY_FAST = {
    "steps_scale": 1.0, "refine_start_iter": 2, "refine_every": 5, "grow_grad2d": 1e-9, "grow_grad2d_abs": 1e-9,
    "grow_rate": 0.5, "t1": 15, "sh_degree": 0,
    "growth_full_iter": 20, "score_views": 2,  # improved-gs: its growth control reaches the budget at step 20
}
STEPS = 40
CAP = 1800  # the check scene has 1429 SfM points (340 text points, 1089 non-text)


def _trainable():
    from strings_bench.core.method import Method
    from strings_bench.methods.registry import list_methods

    return [s.name for s in list_methods() if isinstance(s.load(), type) and issubclass(s.load(), Method)]


def _train_capped(name, cap, steps=STEPS):
    from strings_bench.bench.check import tiny_scene
    from strings_bench.methods.registry import get_method
    from strings_bench.scene.scene import Scene

    spec = get_method(name)
    keys = {s.name for s in spec.settings()}
    settings = {k: v for k, v in DENSIFY_FAST.items() if k in keys}
    method = spec.build(gaussian_budget=cap, **settings)
    method.progress = False
    torch.manual_seed(0)
    method.setup(Scene.load(tiny_scene()), device="cpu", seed=0)
    counts = [method.num_gaussians()]
    method.dropped = []  # the strategy's count of candidates the budget dropped, after each refine (0 if it keeps none)
    for step in range(1, steps + 1):
        method.train_step(step)
        counts.append(method.num_gaussians())
        method.refine(step)
        counts.append(method.num_gaussians())
        method.dropped.append(getattr(method.strategy, "dropped_for_budget", 0))
    return method, counts


SLOW_METHODS = {"strings-no-densify", "strings-pos-lr"}  # STRinGS' ablations: the same growth code as strings


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_METHODS else n
                                  for n in _trainable()])
def test_no_method_exceeds_the_budget_at_any_step(name):
    method, counts = _train_capped(name, CAP)
    over = [(i // 2, c) for i, c in enumerate(counts) if c > CAP]
    assert not over, f"{name} exceeded the budget of {CAP} Gaussians at (step, count) {over[:5]}"
    assert max(counts) >= 0.95 * CAP, (f"{name} never came near the cap ({max(counts)} < 0.95 x {CAP}): "
                                       "add the settings that make it densify fast to DENSIFY_FAST")
    # the cell's record of the size (result.json extra) against the counts seen from outside
    assert method.checkpoint_extra(STEPS)["peak_gaussians"] == max(counts)
    if not name.startswith("strings"):  # STRinGS' phase-1 cap is lower (test_strings_keeps_room_...)
        after_refine = counts[2::2]  # the count after refine(step), step = 1..STEPS
        first = next((s for s, (c, d) in enumerate(zip(after_refine, method.dropped), start=1) if c >= CAP or d > 0),
                     None)
        assert first is not None  # the cap binds in this test (above), so the record must say when
        assert method.checkpoint_extra(STEPS)["budget_reached_at"] == first


def test_strings_keeps_room_for_the_non_text_points_in_phase_1():
    method, counts = _train_capped("strings", CAP, steps=16)
    n_non_text = int((~method.segmentation.is_text).sum())
    phase1 = counts[:2 * 15 + 1]
    assert max(phase1) <= CAP - n_non_text
    assert method.densify_stats["text_densify_budget"] == CAP - n_non_text
    assert method.phase == 2 and counts[-1] <= CAP
    # phase 1's budget is the reduced one: the record says when the text Gaussians filled it, if they did
    reached = method.checkpoint_extra(16)["budget_reached_at"]
    full = [s for s, (c, d) in enumerate(zip(counts[2::2], method.dropped), start=1)
            if c >= (CAP - n_non_text if s <= 15 else CAP) or d > 0]
    assert reached == (full[0] if full else None)


def test_a_budget_below_the_initial_model_is_a_clear_error():
    with pytest.raises(StringsBenchError, match="cannot remove initial Gaussians"):
        _train_capped("3dgs", 1000, steps=1)
    with pytest.raises(StringsBenchError, match="and 1089 it adds later"):
        _train_capped("strings", 1200, steps=1)  # 340 text points + 1089 non-text > 1200


# ---- the run option ----------------------------------------------------------------------------------------------
FAST_RUN = {"refine_every": 5, "refine_start_iter": 2, "grow_grad2d": 1e-9, "grow_grad2d_abs": 1e-9, "sh_degree": 0,
            "grow_rate": 0.5}


def _run(tmp_path, methods, budget, out="run", **kw):
    import runner_fakes as rf
    import strings_bench.bench.runner as runner
    from strings_bench.bench.check import tiny_scene

    from strings_bench.methods.registry import get_method

    overrides = {m: {k: v for k, v in FAST_RUN.items() if k in {s.name for s in get_method(m).settings()}}
                 for m in methods}
    return bench.run(methods, [str(tiny_scene())], run_dir=tmp_path / out, schedule="tiny", steps_scale=0.02,
                      checkpoints=[1000], ocr="fake", ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False,
                      write_report=False, method_overrides=overrides, budget=budget, **kw)


def _cell(run_dir, method):
    import json

    (path,) = (run_dir / "cells" / method).rglob("result.json")
    return json.loads(path.read_text())


@pytest.mark.parametrize("text, value", [("40000", 40000), ("40k", 40000), (1500, 1500), (None, None), ("3dgs", "3dgs")])
def test_parse_budget(text, value):
    from strings_bench.bench.budget import Budget

    b = Budget.parse(text)
    assert (None if b is None else b.rule) == value
    assert b is None or (b.count, b.reference) == ((value, None) if isinstance(value, int) else (None, value))


@pytest.mark.parametrize("bad", ["0", "-3", 2.5, "1.5k", True])
def test_parse_budget_refuses_what_is_not_a_count_or_a_name(bad):
    from strings_bench.bench.budget import Budget

    with pytest.raises(StringsBenchError, match="budget"):
        Budget.parse(bad)


@pytest.mark.parametrize("value", [None, 40000])
def test_budget_from_goes_with_a_method_name_only(value):
    from strings_bench.bench.budget import Budget

    with pytest.raises(StringsBenchError, match="--budget-from goes with --budget METHOD"):
        Budget.parse(value, "runs/seed0")
    assert Budget.parse("3dgs", "runs/seed0") == Budget(reference="3dgs", folder="runs/seed0")


def test_budget_records_and_caps():
    from strings_bench.bench.budget import Budget, budget_of

    count = Budget.parse("40k")
    assert count.manifest() == {"budget": 40000}
    rec = count.record("absgs", "d", "s", (10, 20), "unused")
    assert rec == {"rule": "40000", "count": 40000, "reference": None} and budget_of(rec) == 40000
    assert budget_of({"rule": "40000", "max_gaussians": 40000, "reference": None}) == 40000  # a cell before the rename
    ref = Budget.parse("3dgs", "/runs/seed0")
    assert ref.manifest() == {"budget": "3dgs", "budget_from": "/runs/seed0"}
    assert ref.record("3dgs", "d", "s", (10, 20), "unused") == "reference" and budget_of("reference") is None
    assert ref.is_reference("3dgs") and not ref.is_reference("absgs") and not count.is_reference("absgs")
    assert ref.reference_cell("d", "s", (10, 20)).iteration == 20


def test_budget_3dgs_trains_3dgs_first_and_caps_the_others_at_its_count(tmp_path):
    out = _run(tmp_path, ["absgs", "3dgs"], "3dgs")
    ref, capped = _cell(out, "3dgs"), _cell(out, "absgs")
    assert ref["config"]["budget"] == "reference" and "gaussian_budget" not in ref["config"]["method"]["settings"]
    n = ref["gaussians"]
    assert n > 1429  # 3DGS grew past the SfM points, so the budget is its own count
    assert capped["config"]["budget"] == {"rule": "3dgs", "count": n,
                                          "reference": {"method": "3dgs", "iteration": 20}}
    assert capped["config"]["method"]["settings"]["gaussian_budget"] == n  # in the training state's fingerprint too
    assert capped["gaussians"] <= n
    import json

    assert json.loads((out / "run.json").read_text())["budget"] == "3dgs"
    rows = pd.read_csv(out / "results.csv", dtype=str).set_index("method")["budget"]
    assert rows.to_dict() == {"3dgs": "reference", "absgs": str(n)}
    # the same folder without the budget (or with another) is refused: its cells are budgeted
    with pytest.raises(StringsBenchError, match="--budget 3dgs; this run asks for no budget"):
        _run(tmp_path, ["absgs", "3dgs"], None)
    with pytest.raises(StringsBenchError, match="this run asks for --budget 1600"):
        _run(tmp_path, ["absgs"], 1600)
    # the reference's cells are in the folder: a run of another method alone resumes under the same budget
    _run(tmp_path, ["edc-absgs"], "3dgs")
    assert _cell(out, "edc-absgs")["config"]["budget"]["count"] == n


def test_budget_from_reads_the_reference_count_from_another_folder(tmp_path):
    import json
    import shutil

    import strings_bench.bench.runner as runner
    from strings_bench.bench.check import tiny_scene

    ref_dir = _run(tmp_path, ["3dgs"], None, out="seed0")  # the reference, uncapped, in its own folder
    n = _cell(ref_dir, "3dgs")["gaussians"]
    assert n > 1429
    out = _run(tmp_path, ["absgs"], "3dgs", out="seed1", budget_from=ref_dir)
    capped = _cell(out, "absgs")
    assert capped["config"]["budget"] == {"rule": "3dgs", "count": n, "reference": {
        "method": "3dgs", "iteration": 20, "folder": str(ref_dir.resolve())}}
    assert capped["config"]["method"]["settings"]["gaussian_budget"] == n and capped["gaussians"] <= n
    assert not (out / "cells" / "3dgs").exists()  # the reference is not trained again
    assert json.loads((out / "run.json").read_text())["budget_from"] == str(ref_dir.resolve())
    # the folder resumes only with the same reference folder
    with pytest.raises(StringsBenchError, match="made with --budget-from .*: give it again to resume"):
        _run(tmp_path, ["absgs"], "3dgs", out="seed1")
    other = tmp_path / "seed0-copy"
    shutil.copytree(ref_dir, other)
    with pytest.raises(StringsBenchError, match="holds results made with --budget 3dgs --budget-from .*seed0; this "
                                                "run asks for --budget 3dgs --budget-from .*seed0-copy"):
        _run(tmp_path, ["absgs"], "3dgs", out="seed1", budget_from=other)

    scene = str(tiny_scene())

    def plan(**kw):
        return plan_run(["absgs"], [scene], schedule="tiny", steps_scale=0.02, checkpoints=[1000], **kw)

    with pytest.raises(StringsBenchError, match="goes with --budget METHOD"):
        plan(run_dir=tmp_path / "e1", budget=2000, budget_from=ref_dir)
    with pytest.raises(StringsBenchError, match="3dgs is not trained in this run"):
        plan_run(["3dgs", "absgs"], [scene], run_dir=tmp_path / "e2", schedule="tiny", steps_scale=0.02,
                        budget="3dgs", budget_from=ref_dir)
    with pytest.raises(StringsBenchError, match="not a run folder"):
        plan(run_dir=tmp_path / "e3", budget="3dgs", budget_from=tmp_path / "nowhere")
    with pytest.raises(StringsBenchError, match="holds no mcmc cells"):
        plan(run_dir=tmp_path / "e4", budget="mcmc", budget_from=ref_dir)
    with pytest.raises(StringsBenchError, match="--steps-scale 0.02; this run asks for 0.05"):
        plan_run(["absgs"], [scene], run_dir=tmp_path / "e5", schedule="tiny", steps_scale=0.05,
                        budget="3dgs", budget_from=ref_dir)
    with pytest.raises(StringsBenchError, match="were trained under a budget"):  # a budgeted folder's counts are no reference
        plan(run_dir=tmp_path / "e6", budget="3dgs", budget_from=_run(tmp_path, ["3dgs"], 1500, out="capped"))


def test_numeric_budget_caps_every_method(tmp_path):
    out = _run(tmp_path, ["3dgs", "mcmc"], 1600)
    for m in ("3dgs", "mcmc"):
        cell = _cell(out, m)
        assert cell["config"]["budget"] == {"rule": "1600", "count": 1600, "reference": None}
        assert cell["config"]["method"]["settings"]["gaussian_budget"] == 1600
        assert 1429 < cell["gaussians"] <= 1600
        assert cell["gaussians"] <= cell["extra"]["peak_gaussians"] <= 1600
    rows = pd.read_csv(out / "results.csv").set_index("method")
    assert (rows["peak_gaussians"] <= 1600).all() and (rows["peak_gaussians"] >= rows["gaussians"]).all()


def test_budget_errors_are_clear(tmp_path):
    import strings_bench.bench.runner as runner
    from strings_bench.bench.check import tiny_scene

    scene = str(tiny_scene())
    with pytest.raises(StringsBenchError, match="needs 3dgs among the run's methods"):
        plan_run(["absgs"], [scene], run_dir=tmp_path / "r1", schedule="tiny", budget="3dgs")
    with pytest.raises(StringsBenchError, match="set with --budget, not --set"):
        plan_run(["absgs"], [scene], run_dir=tmp_path / "r2", schedule="tiny",
                        method_overrides={"absgs": {"gaussian_budget": 5}})
    with pytest.raises(StringsBenchError, match=r"max_gaussians is set with --budget.*called gaussian_budget now"):
        plan_run(["absgs"], [scene], run_dir=tmp_path / "r2", schedule="tiny",
                        method_overrides={"absgs": {"max_gaussians": 5}})
    with pytest.raises(StringsBenchError, match="method ply takes no Gaussian budget"):
        plan_run(["ply"], [scene], run_dir=tmp_path / "r3", schedule="tiny", budget=2000)


def test_cli_run_takes_budget():
    from strings_bench.cli import build_parser
    from strings_bench.cli.run import run_config

    args = build_parser().parse_args(["run", "--methods", "3dgs,absgs", "--budget", "3dgs"])
    assert run_config(args).budget == "3dgs" and run_config(args).budget_from is None
    args = build_parser().parse_args(["run", "--methods", "absgs", "--budget", "3dgs", "--budget-from", "runs/a"])
    assert run_config(args).budget_from == "runs/a"


# ---- the report's size/accuracy front ------------------------------------------------------------------------------
def _cells():
    """Constructed results.csv rows: 2 scenes x 4 methods (and an ablation, never on a front) at 30K."""
    rows = []
    by_method = {  # (Gaussians, CER) on scene a, then scene b
        "3dgs": [(30_000, 0.50), (34_000, 0.60)],        # mean 32k, 0.55
        "strings": [(48_000, 0.30), (50_000, 0.36)],     # mean 49k, 0.33: beaten by edc-absgs on both
        "absgs": [(20_000, 0.70), (22_000, 0.70)],       # mean 21k, 0.70: the smallest
        "edc-absgs": [(40_000, 0.15), (44_000, 0.19)],   # mean 42k, 0.17
        "strings-no-densify": [(1_000, 0.0), (1_000, 0.0)],  # an ablation: left out of the fronts
    }
    for m, cells in by_method.items():
        for scene, (n, cer) in zip("ab", cells):
            rows.append({"method": m, "dataset": "d", "scene": scene, "label": "30K", "iteration": 1500,
                         "gaussians": n, "cer": cer, "word_cer": cer / 2, "train_seconds": 60.0,
                         "preprocess_seconds": 0.0, "evaluation": "full"})
    return pd.DataFrame(rows)


def test_size_front_on_constructed_cells():
    from strings_bench.reports import readability_analysis as ra

    fr = ra.fronts(_cells(), x="gaussians")
    cer = next(f for f in fr if f["metric"] == "cer" and f["label"] == "30K")
    assert cer["x"] == "gaussians"
    assert cer["points"]["edc-absgs"] == pytest.approx((42_000, 0.17))
    assert "strings-no-densify" not in cer["points"]
    # by hand: absgs (fewest), 3dgs (fewer than edc, worse), edc-absgs (best CER); strings is beaten by edc on both
    assert sorted(cer["front"]) == ["3dgs", "absgs", "edc-absgs"]
    csv = ra.fronts_csv(fr).splitlines()
    assert csv[0] == "label,metric,method,gaussians,value,on_front"
    assert any(ln.startswith("30K,cer,strings,49000.0,0.3") and ln.endswith(",False") for ln in csv)
    (line,) = [ln for ln in ra.front_lines([cer]) if ln.startswith("- 30K, OCR-CER")]
    assert line.startswith("- 30K, OCR-CER vs Gaussian count: 3DGS (32,000 Gaussians, OCR-CER 0.550)")
    # the time front of the same cells is unchanged by the axis option: every method took 1 min, so the best CER wins
    assert next(f for f in ra.fronts(_cells()) if f["metric"] == "cer")["front"] == ["edc-absgs"]


def test_size_front_in_the_html_and_the_figure(tmp_path):
    from strings_bench.reports import readability_analysis as ra
    from strings_bench.reports.figures import metric_vs_gaussians
    from strings_bench.reports.html import _fronts_html

    fr = ra.fronts(_cells(), x="gaussians")
    html = _fronts_html(fr)
    assert 'id="table-size-front"' in html and 'data-front="3dgs,absgs,edc-absgs"' in html
    assert "tables/size_front.csv" in html
    png = metric_vs_gaussians(_cells(), tmp_path / "cer_vs_gaussians_30K.png", "30K", "cer")
    assert png is not None and png.stat().st_size > 1000


def test_compare_refuses_folders_of_different_budgets(tmp_path):
    import json

    from strings_bench.reports.compare import compare

    for name, budget in (("a", None), ("b", "3dgs")):
        (tmp_path / name).mkdir()
        manifest = {"schedule": {"name": "cpu"}, "downscale": 1.0, "ocr": "rapidocr", "methods": {}, "datasets": []}
        if budget:
            manifest["budget"] = budget
        (tmp_path / name / "run.json").write_text(json.dumps(manifest))
    with pytest.raises(StringsBenchError, match="different Gaussian budgets.*b: --budget 3dgs"):
        compare([tmp_path / "a", tmp_path / "b"])


def test_a_training_state_saved_before_the_budget_was_renamed_still_matches():
    """A state saved with the setting max_gaussians is read as one of gaussian_budget (trainer.RENAMED_SETTINGS);
    any other difference still refuses it."""
    from strings_bench.engine.trainer import Trainer

    old = {"version": 1, "settings": {"max_gaussians": 40000, "seed": 0}, "scene": "s"}
    assert Trainer._renamed(old) == {"version": 1, "settings": {"gaussian_budget": 40000, "seed": 0}, "scene": "s"}
    assert Trainer._renamed({"settings": {"seed": 0}}) == {"settings": {"seed": 0}}
    assert Trainer._renamed(None) is None
