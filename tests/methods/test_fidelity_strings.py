"""Issue 15 §3-§4: STRinGS' gamma counter, whole-run timings, the 3DGS scale floor, exponential_lr at
zero, seed routing, dataset-card imports, the baselines script's presets, phase-1 loss and
--no-progress. Expected numbers are evaluated by hand from the published formulas (see comments)."""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.core.results import CellKey

from strings_bench.core.schedules import get_schedule

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from _engine_helpers import make_tiny_scene, train
from strings_bench.core.errors import StringsBenchError
from strings_bench.methods.registry import get_method
from strings_bench.engine.optim import exponential_lr

REPO = Path(__file__).resolve().parents[2]
TEXT_BOX = (8, 6, 20, 14)  # x0, y0, x1, y1 on the 32 x 24 views


pytestmark = pytest.mark.usefixtures("private_cache")  # tests/conftest.py


@pytest.fixture(scope="module")
def text_scene(tmp_path_factory):
    from strings_bench.scene.scene import Scene

    root = tmp_path_factory.mktemp("fid") / "scene"
    scene = make_tiny_scene(root, n_views=9, n_points=60)
    (root / "masks").mkdir()
    x0, y0, x1, y1 = TEXT_BOX
    for c in scene.model.cameras:
        m = np.zeros((c.height, c.width), np.uint8)
        m[y0:y1, x0:x1] = 255
        Image.fromarray(m).save(root / "masks" / c.name)
    return Scene.load(root)


QUIET = dict(mask_dilation_fraction=0.0, mask_dilation_px=None, n_max=3, sh_degree=1)


def _strings_trainer(scene, preset, **settings):
    """STRinGS at the paper's schedule, as the paper ("paper") or with the release's preset ("release")."""
    m = get_method("strings").build(None if preset == "paper" else preset, **{"steps_scale": get_schedule("paper").steps_scale, **QUIET, **settings})
    m.progress = False
    m.setup(scene, downscale=1, device="cpu")
    return m


# ---- §3 gamma: which counter ------------------------------------------------------------------------
# eta_r(t) = 0.5 / (1 + exp(-0.0005 (t - gamma))), evaluated by hand:
#   x = -0.0005 (t - 15000) on the global counter (paper);
#   release: t = step - 3000 (phase-2 counter), gamma 12000 -> the same x.
#   step  3001: x =  5.9995 -> 0.5 / (1 + 403.2264) = 0.00123692836
#   step  9000: x =  3      -> 0.5 / (1 + 20.085537) = 0.02371293659
#   step 15000: x =  0      -> 0.25
#   step 21000: x = -3      -> 0.5 / (1 + 0.0497871) = 0.47628706341
#   step 30000: x = -7.5    -> 0.5 / (1 + 5.5308e-4) = 0.49972361068
FULL_SCALE = {3001: 0.0012369283590600297, 9000: 0.02371293658878339, 15000: 0.25,
              21000: 0.4762870634112167, 30000: 0.4997236106815382}


@pytest.mark.parametrize("preset", ["paper", "release"])
def test_gamma_full_schedule_both_presets(text_scene, preset):
    trainer = _strings_trainer(text_scene, preset)
    assert trainer.t1 == 3000
    for step, want in FULL_SCALE.items():
        text, non_text = trainer.lr_factors(step)
        assert text == pytest.approx(want, rel=1e-9), step
        assert non_text == 0.5
    # The old release preset (gamma 12000 on the global counter) gave 0.5 / (1 + e^-1.5) = 0.4088 at 15000.
    assert trainer.lr_factors(15000)[0] != pytest.approx(0.4087872380968218)


def test_release_preset_settings():
    rel = get_method("strings").build("release").settings
    assert rel["gamma"] == 12000 and rel["gamma_counter"] == "phase2"
    paper = get_method("strings").build(steps_scale=get_schedule("paper").steps_scale).settings
    assert "gamma_counter" not in paper  # paper preset unchanged: default gamma 15000 on the global counter
    from strings_bench.methods.strings.method import StringsSettings

    assert StringsSettings().gamma == 15000 and StringsSettings().gamma_counter == "global"
    with pytest.raises(StringsBenchError, match="gamma_counter"):
        StringsSettings(gamma_counter="phase1")


def test_gamma_counter_follows_t1(text_scene):
    # With T1 = 2000 the counters differ by 2000 instead of 3000, so the presets part:
    #   release, step 14000: t = 12000 -> x = 0    -> 0.25
    #   release, step 15000: t = 13000 -> x = -0.5 -> 0.5 / (1 + 0.6065307) = 0.31122966560
    #   paper,   step 14000: x = 0.5               -> 0.5 / (1 + 1.6487213) = 0.18877033440
    rel = _strings_trainer(text_scene, "release", t1=2000)
    pap = _strings_trainer(text_scene, "paper", t1=2000)
    assert rel.lr_factors(14000)[0] == pytest.approx(0.25, rel=1e-12)
    assert rel.lr_factors(15000)[0] == pytest.approx(0.3112296656009273, rel=1e-9)
    assert pap.lr_factors(14000)[0] == pytest.approx(0.1887703343990727, rel=1e-9)
    assert pap.lr_factors(15000)[0] == pytest.approx(0.25, rel=1e-12)


@pytest.mark.parametrize("preset", ["paper", "release"])
def test_gamma_scaled_schedule(text_scene, preset):
    # steps_scale 0.01: T1 = 30, beta 0.05, gamma 150 (paper, global) or 120 on t = step - 30 (release):
    #   step  31: x = -0.05 (31 - 150) = 5.95 -> 0.5 / (1 + 383.7533) = 0.00129953388
    #   step 100: x = 2.5                     -> 0.5 / (1 + 12.182494) = 0.03792909001
    #   step 150: x = 0                       -> 0.25
    #   step 300: x = -7.5                    -> 0.49972361068
    trainer = _strings_trainer(text_scene, preset, steps_scale=0.01)
    assert trainer.t1 == 30
    for step, want in {31: 0.0012995338811616734, 100: 0.03792909001062177, 150: 0.25,
                       300: 0.4997236106815382}.items():
        assert trainer.lr_factors(step)[0] == pytest.approx(want, rel=1e-9), step


def test_position_lr_scale_rows_use_the_counter(text_scene):
    # The per-row factor handed to Adam in phase 2 (release, T1 = 2000): text rows 0.25 at step 14000.
    trainer = _strings_trainer(text_scene, "release", t1=2000, steps_scale=1.0)
    from strings_bench.engine.gaussians import GaussianModel

    model = GaussianModel.from_points(np.eye(3), np.full((3, 3), 128, np.uint8), sh_degree=1,
                                      extras={"is_text": torch.tensor([True, False, True])})
    trainer.model = model
    scale = trainer.position_lr_scale(14000)
    assert scale.tolist() == pytest.approx([0.25, 0.5, 0.25])


# ---- §3 timings -------------------------------------------------------------------------------------
def test_strings_reports_preprocess_time(text_scene, monkeypatch):
    import time

    import strings_bench.eval.text_masks as masks_mod

    real = masks_mod.text_masks

    def slow_masks(*a, **k):
        time.sleep(0.3)  # stands for Hi-SAM / mask loading: must be in preprocess, not in train
        return real(*a, **k)

    monkeypatch.setattr(masks_mod, "text_masks", slow_masks)
    m = get_method("strings").build(None, **QUIET, steps_scale=0.001)  # T1 = 3 steps
    results = train(m, text_scene, [2, 5])
    for r in results:
        assert r.preprocess_seconds >= 0.3
        # the loop times the whole set-up: masks and Algorithm 1, then the initial model with Eq. 1
        assert r.preprocess_seconds > r.extra["masks_segmentation_seconds"] >= 0.3
    assert results[0].preprocess_seconds == results[1].preprocess_seconds
    assert results[0].train_seconds < results[1].train_seconds


def test_3dgs_reports_its_init_as_preprocess(text_scene):
    m = get_method("3dgs").build(None, sh_degree=1, steps_scale=0.001)
    (r,) = train(m, text_scene, [2])
    assert r.preprocess_seconds > 0


def _fake_registry():
    import runner_fakes as rf
    from strings_bench.core.method import CheckpointResult
    from strings_bench.methods.registry import MethodSpec, register_method

    class PreAdapter(rf.FakeAdapter):
        def train(self, scene, checkpoints, downscale=1):
            for r in super().train(scene, checkpoints, downscale):
                yield CheckpointResult(r.iteration, r.renders, r.train_seconds, r.gaussians,
                                       preprocess_seconds=float(self.settings.get("pre", 0.0)))

    register_method(MethodSpec(name="fake-pre", implementation=lambda **s: PreAdapter(tag="fake-pre", blur=0.2, pre=30.0, **s),
                               description="pre"))
    rf.register_fakes()
    return rf


def test_results_csv_timing_columns_old_cells_and_tables(tmp_path):
    import strings_bench.bench.runner as runner
    import strings_bench.reports.figures as figures
    import strings_bench.reports.tables as tables
    from strings_bench.reports.aggregate import load_results

    rf = _fake_registry()
    scene_dir = rf.make_scene(tmp_path / "scenes" / "toyset")
    out = tmp_path / "run"

    def run():
        return bench.run(["fake-pre", "fake-a"], [str(scene_dir)], run_dir=out, schedule="tiny", ocr="fake",
                          ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False)

    run()
    rows = {(r["method"], int(r["iteration"])): r for r in csv.DictReader(open(out / "results.csv"))}
    # FakeAdapter: train_seconds = 10 (k + 1) (1 + blur) = 12, 24, 36 for blur 0.2.
    assert float(rows[("fake-pre", 35)]["train_seconds"]) == pytest.approx(24.0)
    assert float(rows[("fake-pre", 35)]["preprocess_seconds"]) == pytest.approx(30.0)
    assert float(rows[("fake-pre", 35)]["total_seconds"]) == pytest.approx(54.0)
    assert float(rows[("fake-a", 35)]["preprocess_seconds"]) == 0.0
    assert float(rows[("fake-a", 35)]["total_seconds"]) == pytest.approx(24.0)

    # The training-time table and the scatter show total minutes at 7K: fake-pre 54 s = 0.9 min,
    # fake-a 24 s = 0.4 min (train only would give 0.4 for both).
    df = load_results(out)
    t = next(t for t in tables.build_tables(df) if t.name == "training_time")
    col = next(c for c in t.columns if c.sub == "7K")
    assert col.values["fake-pre"] == pytest.approx(0.9) and col.values["fake-a"] == pytest.approx(0.4)
    assert "preprocessing" in t.caption and "total_seconds" in t.caption
    seen = {}

    def grab(fig, path):
        # one point per method; the Pareto front's circles (issue 30) are drawn over them, labelled
        seen["x"] = sorted(float(c.get_offsets()[0][0]) for c in fig.axes[0].collections
                           if c.get_label() != "Pareto front")
        seen["front"] = sorted(float(x) for c in fig.axes[0].collections if c.get_label() == "Pareto front"
                               for x, _ in c.get_offsets())
        seen["xlabel"] = fig.axes[0].get_xlabel()
        return Path(path)

    import unittest.mock as mock

    with mock.patch.object(figures, "_save", grab):
        figures.cer_vs_time(df, tmp_path / "x.png", "7K")
    assert seen["x"] == pytest.approx([0.4, 0.9]) and "preprocessing" in seen["xlabel"]
    assert seen["front"] and set(seen["front"]) <= set(seen["x"])  # the front circles method points

    # A cell written before the new columns: no preprocess/total in timings. STRinGS' old cells kept
    # their preprocessing in extra["preprocess_seconds"]; other methods had none.
    cell = CellKey("fake-pre", "toy", "toy", 35).path(out) / "result.json"
    rec = json.loads(cell.read_text())
    rec["timings"] = {"train_seconds": 24.0, "eval_seconds": 1.0}
    rec["extra"] = {"preprocess_seconds": 7.0}
    cell.write_text(json.dumps(rec))
    cell_a = CellKey("fake-a", "toy", "toy", 35).path(out) / "result.json"
    rec = json.loads(cell_a.read_text())
    rec["timings"] = {"train_seconds": 24.0, "eval_seconds": 1.0}
    cell_a.write_text(json.dumps(rec))
    run()  # resume: every cell is finished, nothing retrains, results.csv is rebuilt
    rows = {(r["method"], int(r["iteration"])): r for r in csv.DictReader(open(out / "results.csv"))}
    assert float(rows[("fake-pre", 35)]["preprocess_seconds"]) == 7.0
    assert float(rows[("fake-pre", 35)]["total_seconds"]) == pytest.approx(31.0)
    assert float(rows[("fake-a", 35)]["total_seconds"]) == pytest.approx(24.0)

    # A results.csv without the new columns (and no cells to rebuild it from): total = train.
    old = tmp_path / "old"
    old.mkdir()
    (old / "results.csv").write_text("method,dataset,scene,iteration,label,cer,cer_known,psnr,ssim,lpips,"
                                     "train_seconds,gaussians,ocr_failed\n"
                                     "m,d,s,70,7K,0.5,,20,0.5,,120,10,0\n")
    df_old = load_results(old)
    assert float(df_old["total_seconds"].iloc[0]) == 120.0
    t = next(t for t in tables.build_tables(df_old) if t.name == "training_time")
    assert t.columns[0].values["m"] == pytest.approx(2.0)


# ---- §3 initial scale floor ----------------------------------------------------------------------
def test_initial_scale_floor_is_3dgs_1e7():
    from strings_bench.engine.gaussians import GaussianModel

    h = 1e-5
    xyz = np.array([[0, 0, 0], [h, 0, 0], [0, h, 0], [0, 0, h], [1, 0, 0]], dtype=np.float64)
    model = GaussianModel.from_points(xyz, np.full((5, 3), 128, np.uint8))
    got = model.params["log_scales"].detach().numpy().astype(np.float64)
    # Points 0-3: mean squared 3-NN distance 1e-10 (point 0) or 5/3 e-10 (points 1-3), both < 1e-7,
    # so 3DGS clamps to 1e-7: scale sqrt(1e-7) = 3.1622776601683794e-4, log = -8.059047825479161.
    assert np.allclose(got[:4], -8.059047825479161, atol=1e-6)
    # Point 4 (1, 0, 0): 3 nearest d^2 = (1 - 1e-5)^2 = 0.9999800001, 1, 1 + 1e-10 -> mean 0.99999333340,
    # scale 0.99999666669, log = -3.33334e-6 (unclamped).
    assert np.allclose(got[4], math.log(math.sqrt((0.9999800001 + 1 + 1.0000000001) / 3)), atol=1e-6)
    assert np.allclose(got[4], -3.33334e-6, atol=1e-8)


# ---- §4 exponential_lr at zero -----------------------------------------------------------------------
def test_exponential_lr_values_by_hand():
    # Log-linear: lr_init^(1-t) lr_final^t.  t = 0.5: sqrt(1e-2 * 1e-4) = 1e-3;  t = 0.25: 10^(-1.5 - 1) = 10^-2.5.
    assert exponential_lr(50, 1e-2, 1e-4, 100) == pytest.approx(1e-3, rel=1e-12)
    assert exponential_lr(25, 1e-2, 1e-4, 100) == pytest.approx(0.0031622776601683794, rel=1e-12)
    assert exponential_lr(400, 1e-2, 1e-4, 100) == pytest.approx(1e-4, rel=1e-12)


def test_exponential_lr_zero_end_points():
    # lr_final = 0: the limit of lr_init^(1-t) eps^t as eps -> 0 is lr_init at t = 0 and 0 for t > 0
    # (3DGS: exp(log(0) t) = 0 for t > 0). It no longer stays at lr_init.
    assert exponential_lr(0, 1e-3, 0.0, 100) == 1e-3
    for step in (1, 50, 99, 100, 1000):
        assert exponential_lr(step, 1e-3, 0.0, 100) == 0.0
    # The limit from above: tiny positive finals approach 0 at t = 0.5 (1e-3 * eps)^0.5.
    assert exponential_lr(50, 1e-3, 1e-20, 100) == pytest.approx(math.sqrt(1e-23), rel=1e-9)
    # lr_init = 0: 0 before max_steps, lr_final from there on.
    for step in (0, 1, 99):
        assert exponential_lr(step, 0.0, 1e-3, 100) == 0.0
    assert exponential_lr(100, 0.0, 1e-3, 100) == 1e-3 and exponential_lr(150, 0.0, 1e-3, 100) == 1e-3
    assert exponential_lr(10, 0.0, 0.0, 100) == 0.0
    with pytest.raises(StringsBenchError):
        exponential_lr(10, -1e-3, 1e-4, 100)
    with pytest.raises(StringsBenchError):
        exponential_lr(10, 1e-3, float("nan"), 100)


# ---- §4 seed routing -------------------------------------------------------------------------------
def test_seed_reaches_mcmc_and_the_trainer(text_scene):
    from strings_bench.cli.run import parse_settings
    from strings_bench.engine.strategies.mcmc import MCMCStrategy
    from strings_bench.engine.splatting import config_from_settings

    config, strategy = config_from_settings({"seed": 7}, strategy_cls=MCMCStrategy)
    assert config.seed == 7 and strategy.seed == 7
    over = parse_settings(["mcmc.seed=11"])
    trainer = get_method("mcmc").build(steps_scale=get_schedule("tiny").steps_scale, **over["mcmc"])
    assert trainer.config.seed == 11 and trainer.strategy.seed == 11
    state = trainer.strategy.initialize_state(1.0)
    # made at first use, on the model's device (a CPU generator cannot sample CUDA tensors)
    gen = trainer.strategy.generator(state, torch.device("cpu"))
    assert gen is not None and gen.initial_seed() == 11 and gen.device.type == "cpu"
    assert trainer.strategy.generator(state, torch.device("cpu")) is gen  # one stream for the whole run
    # Without a seed MCMC samples from torch's global RNG (seeded by the trainer's default 0), as documented.
    plain = get_method("mcmc").build(steps_scale=get_schedule("tiny").steps_scale)
    assert plain.config.seed == 0 and plain.strategy.seed is None
    # A seed for a method whose strategy has none still reaches only the trainer.
    t3 = get_method("3dgs").build(steps_scale=get_schedule("tiny").steps_scale, seed=5)
    assert t3.config.seed == 5


# ---- §4 dataset cards -------------------------------------------------------------------------------
def test_broken_import_inside_cards_surfaces(monkeypatch):
    import strings_bench.datasets as pkg
    import strings_bench.datasets.card as card
    import strings_bench.datasets.registry as registry

    registry.list_datasets()  # cards imported normally
    assert {"strings360", "tandt", "dl3dv"} <= {c.id for c in registry.list_datasets()}
    # A bug inside cards.py: it imports a name card.py does not have. It must not be swallowed.
    monkeypatch.delitem(sys.modules, "strings_bench.datasets.cards")
    monkeypatch.delattr(pkg, "cards")
    monkeypatch.delattr(card, "local_root")
    monkeypatch.setattr(registry, "_BUILTINS_REGISTERED", False)  # as in a fresh process
    with pytest.raises(ImportError, match="local_root"):
        registry.list_datasets()


# ---- §4 tools/baselines.py schedules ------------------------------------------------------------
def _load_script(name):
    from _scripts import load_tool

    return load_tool(name)


def test_baselines_script_uses_the_suite_schedule_table():
    from strings_bench.core.schedules import SCHEDULES

    mod = _load_script("baselines")
    assert set(mod.parser()._option_string_actions["--schedule"].choices) == set(SCHEDULES)
    # quick = x0.01 in the suite: 7K -> 70, 30K -> 300 steps (the script's own table said x0.05 -> 350).
    adapter, s, its = mod.build("3dgs", "quick", [7000, 30000])
    assert s == 0.01 and its == [70, 300] and adapter.settings["steps_scale"] == 0.01
    _, s, its = mod.build("mcmc", "standard", [7000, 30000])
    assert s == 0.05 and its == [350, 1500]
    _, s, its = mod.build("absgs", "quick", [7000], steps_scale=0.02)
    assert its == [140]


# ---- §4 docs drift: one phase-1 loss ----------------------------------------------------------------
def test_phase1_loss_is_losses_masked_l1(text_scene, monkeypatch):
    import strings_bench.engine.losses as losses

    calls = []
    real = losses.masked_l1

    def spy(pred, target, mask):
        calls.append(tuple(mask.shape))
        return real(pred, target, mask)

    monkeypatch.setattr(losses, "masked_l1", spy)
    m = get_method("strings").build(None, **QUIET, steps_scale=0.001)  # T1 = 3
    train(m, text_scene, [4])
    assert len(calls) == 3  # steps 1..3 (phase 1); step 4 is phase 2 (3DGS loss)


def test_engine_doc_has_no_placeholder():
    text = (REPO / "docs" / "engine.md").read_text()
    assert "placeholder until" not in text


# ---- §4 --no-progress --------------------------------------------------------------------------------
def test_no_progress_reaches_trainer_and_mask_bar(text_scene, monkeypatch):
    import strings_bench.eval.text_masks as masks_mod

    seen = []
    real = masks_mod.text_masks
    monkeypatch.setattr(masks_mod, "text_masks", lambda *a, **k: seen.append(k.get("progress")) or real(*a, **k))
    from strings_bench.engine.trainer import Trainer

    for name in ("3dgs", "mcmc", "mip-splatting", "absgs", "edc-absgs", "strings"):
        for progress in (False, True):
            a = get_method(name).build(steps_scale=get_schedule("tiny").steps_scale, **({"mask_dilation_fraction": 0.0} if name == "strings" else {}))
            next(iter(Trainer(a, text_scene, [2], progress=progress).train()))
            assert a.progress is progress, name  # the loop hands its setting to the method
    assert seen == [False, True]  # STRinGS' mask bar follows it


def test_no_progress_run_writes_no_training_bar(tmp_path, capfd):
    import strings_bench.bench.runner as runner

    rf = _fake_registry()
    scene_dir = rf.make_scene(tmp_path / "scenes" / "toyset")

    def run(out, progress):
        bench.run(["3dgs"], [str(scene_dir)], run_dir=out, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
                   with_lpips=False, progress=progress, write_report=False,
                   method_overrides={"3dgs": {"steps_scale": 0.0002, "sh_degree": 0}})  # checkpoints 1, 6
        return capfd.readouterr().err

    assert "train toy" not in run(tmp_path / "quiet", False)
    assert "train toy" in run(tmp_path / "loud", True)  # the same run with bars does show it
