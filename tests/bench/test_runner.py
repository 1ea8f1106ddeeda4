"""Runner: cells, resume after interruption, results.csv, executor seam, adapters and entry points."""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.bench.plan import plan_run
from strings_bench.core.results import CellKey
from strings_bench.bench.plan import ALL_METHODS
from strings_bench.store import check_manifest
from strings_bench.bench.executors import LocalExecutor

import csv
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import runner_fakes as rf
import strings_bench.bench.runner as runner
from strings_bench.core.schedules import SCHEDULES
from strings_bench.core.errors import StringsBenchError
from strings_bench.methods.registry import MethodSpec, register_method
from strings_bench.eval.ocr import Word


@pytest.fixture(autouse=True)
def _reset_calls():
    rf.CALLS["train"].clear()
    rf.CALLS["yield"].clear()
    rf.register_fakes()


def _run(out, scene_dir, methods=("fake-a", "fake-b"), ocr=None, ocr_list="fake", **kw):
    return bench.run(list(methods), [str(scene_dir)], run_dir=out, schedule="tiny", ocr=ocr_list,
                      ocr_backend=ocr or rf.FakeOCR(), with_lpips=kw.pop("with_lpips", False), progress=False, **kw)


def _rows(out):
    with open(Path(out) / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_cells_and_results_csv(tmp_path, scene_dir):
    out = tmp_path / "run"
    _run(out, scene_dir, with_lpips=True)
    rows = _rows(out)
    its = SCHEDULES["tiny"].checkpoints()
    assert its == [15, 35, 150]
    assert len(rows) == 2 * len(its)
    required = {"method", "dataset", "scene", "iteration", "label", "cer", "cer_known", "psnr", "ssim", "lpips",
                "train_seconds", "gaussians", "ocr_failed", "gt_empty_ignored"}
    assert required <= set(rows[0])
    assert [r["label"] for r in rows if r["method"] == "fake-a"] == ["3K", "7K", "30K"]
    by = {(r["method"], int(r["iteration"])): r for r in rows}
    # fake-a at its last checkpoint renders the ground truth exactly.
    final = by[("fake-a", 150)]
    assert final["psnr"] == "inf" or float(final["psnr"]) > 50
    assert float(final["ssim"]) == pytest.approx(1.0, abs=1e-6)
    import strings_bench.eval.lpips_net as lpips_net

    if lpips_net.available():
        assert float(final["lpips"]) == pytest.approx(0.0, abs=1e-6)
        assert by[("fake-a", 15)]["lpips"] == ""  # LPIPS only at the last checkpoint by default
    else:
        assert final["lpips"] == ""
    assert float(final["cer"]) == 0.0 and float(final["cer_known"]) == 0.0
    # fake-b's first checkpoint is faded: FakeOCR reads "hallo" -> 1 error in 5 characters.
    assert float(by[("fake-b", 15)]["cer"]) == pytest.approx(0.2)
    assert float(by[("fake-b", 15)]["cer_known"]) == pytest.approx(0.2)
    assert int(by[("fake-b", 15)]["gaussians"]) == 1000
    # Cell contents: config, OCR words for GT and render, renders on disk.
    cell = CellKey("fake-b", "toy", "toy", 15).path(out)
    rec = json.loads((cell / "result.json").read_text())
    assert rec["config"]["schedule"] == "tiny" and rec["config"]["method"]["settings"]["blur"] == 0.9
    v = rec["ocr"]["views"]["view_00.png"]
    assert v["gt_words"][0]["text"] == "hello" and v["render_words"][0]["text"] == "hallo"
    assert v["mask"] == "dilated text mask"
    assert rec["ocr"]["backend"]["name"] == "fake"
    assert sorted(p.name for p in (cell / "renders").iterdir()) == ["view_00.png", "view_08.png"]
    assert (out / "gt" / "toy" / "toy" / "view_00.png").exists()
    # PSNR in the cell equals an independent computation from the saved render and GT images.
    from PIL import Image

    r = np.asarray(Image.open(cell / "renders" / "view_08.png"), dtype=np.float64) / 255
    from strings_bench.scene.scene import Scene

    g = Scene.load(scene_dir).load_image(8).astype(np.float64)
    mse = np.mean((r - g) ** 2)
    assert rec["metrics"]["per_view"]["view_08.png"]["psnr"] == pytest.approx(-10 * math.log10(mse), abs=0.05)
    assert (out / "report" / "report.md").exists()
    # Word-crop readability and text-region metrics (issue 14): fake-a's last render is the GT view, so
    # the render scores exactly its ceiling; the known word "hello" (18 px high) is the one headline word.
    from strings_bench.store import READABILITY_COLUMNS

    assert set(READABILITY_COLUMNS) <= set(rows[0])
    assert final["word_cer"] == final["word_cer_gt"] != "" and final["text_nll"] == final["text_nll_gt"] != ""
    assert int(final["read_words"]) == 2 and int(final["read_oov_chars"]) == 0
    assert final["text_psnr"] == "inf" or float(final["text_psnr"]) > 50
    assert float(final["text_ssim"]) == pytest.approx(1.0, abs=1e-6)
    faded = by[("fake-b", 15)]
    assert float(faded["text_psnr"]) < float(faded["psnr"])  # the fade is inside the text box
    view = rec["readability"]["views"]["view_00.png"]
    assert [(w["text"], w["source"], w["headline"]) for w in view] == [("hello", "known", True), ("hello", "gt_ocr", False)]
    assert set(rec["metrics"]["per_view"]["view_00.png"]) >= {"text_psnr", "text_ssim", "text_lpips"}


def test_resume_after_interrupt_does_not_recompute(tmp_path, scene_dir):
    out = tmp_path / "run"
    # First run: fake-a finishes; fake-b is interrupted after its first checkpoint.
    register_method(MethodSpec(name="fake-b", implementation=lambda **s: rf.FakeAdapter(tag="fake-b", blur=0.9, interrupt_after=1, **s)))
    with pytest.raises(KeyboardInterrupt):
        _run(out, scene_dir)
    rows = _rows(out)
    assert {(r["method"], r["iteration"]) for r in rows} == {("fake-a", "15"), ("fake-a", "35"), ("fake-a", "150"), ("fake-b", "15")}
    first_b = CellKey("fake-b", "toy", "toy", 15).path(out) / "result.json"
    a_cells = [CellKey("fake-a", "toy", "toy", i).path(out) / "result.json" for i in (15, 35, 150)]
    mtimes = {p: p.stat().st_mtime_ns for p in [first_b, *a_cells]}
    content_b = first_b.read_text()

    # Second run of the same command: fake-a is not trained again; fake-b is re-trained but its
    # finished checkpoint is neither re-evaluated nor rewritten.
    rf.CALLS["train"].clear()
    rf.register_fakes()
    ocr = rf.FakeOCR()
    _run(out, scene_dir, ocr=ocr)
    assert [c[0] for c in rf.CALLS["train"]] == ["fake-b"]
    assert {p: p.stat().st_mtime_ns for p in mtimes} == mtimes
    assert first_b.read_text() == content_b
    # 2 new cells x 2 test views x (render OCR) + 2 GT OCRs for the scene = 6 reads; 3 cells would be 8.
    assert ocr.calls == 6
    assert len(_rows(out)) == 6

    # Third run: nothing to do, nothing trained.
    rf.CALLS["train"].clear()
    _run(out, scene_dir)
    assert rf.CALLS["train"] == []


def test_interrupted_subprocess_keeps_finished_cells(tmp_path, scene_dir):
    """A process killed mid-run (KeyboardInterrupt through the CLI path) leaves complete cells only."""
    import subprocess

    out = tmp_path / "run"
    code = f"""
import sys; sys.path.insert(0, {str(Path(__file__).parents[1])!r})
import runner_fakes as rf
import strings_bench.bench as bench
from strings_bench.methods.registry import MethodSpec, register_method
from strings_bench.eval.ocr import Word
rf.register_fakes()
register_method(MethodSpec(name="fake-b", implementation=lambda **s: rf.FakeAdapter(tag="fake-b", blur=0.9, interrupt_after=2, **s)))
bench.run(["fake-b"], [{str(scene_dir)!r}], run_dir={str(out)!r}, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
           with_lpips=False, progress=False)
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0 and "KeyboardInterrupt" in proc.stderr
    assert [r["iteration"] for r in _rows(out)] == ["15", "35"]
    leftovers = [p for p in out.rglob("*.tmp")]
    assert leftovers == []


def test_manifest_mismatch_refused(tmp_path, scene_dir):
    out = tmp_path / "run"
    _run(out, scene_dir, methods=["fake-a"], write_report=False)
    with pytest.raises(StringsBenchError, match="schedule"):
        bench.run(["fake-a"], [str(scene_dir)], run_dir=out, schedule="quick", ocr="fake", ocr_backend=rf.FakeOCR(),
                   with_lpips=False, progress=False)


def test_resume_with_other_settings_refused(tmp_path, scene_dir):
    out = tmp_path / "run"
    _run(out, scene_dir, methods=["fake-a"], write_report=False, method_overrides={"fake-a": {"floor": 0.01}})
    n_train = len(rf.CALLS["train"])
    _run(out, scene_dir, methods=["fake-a"], write_report=False, method_overrides={"fake-a": {"floor": 0.01}})
    assert len(rf.CALLS["train"]) == n_train  # same settings: resumed, nothing retrained
    with pytest.raises(StringsBenchError, match="floor"):
        _run(out, scene_dir, methods=["fake-a"], write_report=False, method_overrides={"fake-a": {"floor": 0.02}})
    # Another method may join the folder with its own settings.
    _run(out, scene_dir, methods=["fake-b"], write_report=False, method_overrides={"fake-b": {"floor": 0.02}})
    assert {r["method"] for r in _rows(out)} == {"fake-a", "fake-b"}


def test_executor_seam(tmp_path, scene_dir):
    submitted = []

    class Recording(LocalExecutor):
        def submit(self, job):
            submitted.append(json.loads(json.dumps(dataclasses.asdict(job))))  # jobs are plain, serialisable data
            return super().submit(job)

    plan = plan_run(["fake-a", "fake-b"], [str(scene_dir)], run_dir=tmp_path / "run", schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
                    with_lpips=False)
    r = runner.Runner(plan.run_dir, ocr=rf.FakeOCR())
    runner.execute(plan, ocr=rf.FakeOCR(), executor=Recording(r), progress=False, write_report=False)
    assert [s["method"] for s in submitted] == ["fake-a", "fake-b"]
    assert len(_rows(tmp_path / "run")) == 6


def test_bad_render_size_is_clear(tmp_path, scene_dir):
    class Wrong(rf.FakeAdapter):
        def train(self, scene, checkpoints, downscale=1):
            for r in super().train(scene, checkpoints, downscale):
                r.renders = {k: v[:-1] for k, v in r.renders.items()}
                yield r

    register_method(MethodSpec(name="fake-wrong", implementation=lambda **s: Wrong(**s)))
    with pytest.raises(StringsBenchError, match="render of view_00.png"):
        _run(tmp_path / "run", scene_dir, methods=["fake-wrong"], write_report=False)


def test_unknown_method_is_clear(tmp_path, scene_dir):
    with pytest.raises(StringsBenchError, match="unknown method"):
        _run(tmp_path / "run", scene_dir, methods=["no-such-method"])


def test_scene_without_masks_uses_whole_image(tmp_path):
    scene = rf.make_scene(tmp_path / "set2", name="nomask", with_masks=False)
    (scene / "text_annotations.json").unlink()
    out = tmp_path / "run"
    _run(out, scene, methods=["fake-a"], write_report=False)
    rec = json.loads((CellKey("fake-a", "nomask", "nomask", 150).path(out) / "result.json").read_text())
    assert rec["ocr"]["views"]["view_00.png"]["mask"] == "whole image"
    assert rec["cer_known"] is None
    assert _rows(out)[0]["cer_known"] == ""


def test_entry_point_discovery(tmp_path, monkeypatch):
    """A method in a user's package is found through the `strings_bench.methods` entry point group."""
    pkg = tmp_path / "my_splat_plugin.py"
    pkg.write_text(
        "from strings_bench.methods.registry import MethodSpec\n"
        "from strings_bench.core.method import MethodAdapter\n"
        "class A(MethodAdapter):\n"
        "    name = 'plugin-splat'\n"
        "    def train(self, scene, checkpoints, downscale=1):\n"
        "        return iter(())\n"
        "SPEC = MethodSpec(name='plugin-splat', implementation=A, description='a plug-in method', paper='Plugin\\'26')\n")
    dist = tmp_path / "my_splat_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: my-splat-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[strings_bench.methods]\nplugin-splat = my_splat_plugin:SPEC\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import strings_bench.methods.registry as registry

    monkeypatch.setattr(registry, "_loaded", False)
    names = {s.name: s for s in registry.list_methods()}
    assert "plugin-splat" in names
    assert names["plugin-splat"].paper == "Plugin'26"


def test_methods_list_cli(capsys):
    import strings_bench.cli.methods as methods_cli

    rf.register_fakes()
    methods_cli.cmd_list(None)
    out = capsys.readouterr().out
    assert "fake-a" in out and "paper: Test'25" in out and "presets: tiny" in out


# ---- the external-command adapter ----------------------------------------------------------------
COPY_SCRIPT = r"""
import json, sys
from pathlib import Path
from PIL import Image
scene, out, it, mode = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
if mode == "fail":
    print("trainer exploded", file=sys.stderr); sys.exit(3)
names = sys.argv[5].split(",")
for n in names[: (1 if mode == "missing" else None)]:
    im = Image.open(scene / "images" / n)
    if mode == "small":
        im = im.resize((10, 10))
    im.save(out / (Path(n).stem + ".png"))
json.dump({"train_seconds": it / 10, "gaussians": 777}, open(out / "stats.json", "w"))
"""


def _external(tmp_path, scene_dir, mode, out_name="run"):
    script = tmp_path / "trainer.py"
    script.write_text(COPY_SCRIPT)
    cmd = f"{sys.executable} {script} {{scene}} {{out}} {{iteration}} {mode} {{test_views}}"
    return bench.run(["external"], [str(scene_dir)], run_dir=tmp_path / out_name, schedule="tiny", ocr="fake",
                      ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False, write_report=False,
                      method_overrides={"external": {"command": cmd}})


def test_external_adapter_reads_renders(tmp_path, scene_dir):
    out = _external(tmp_path, scene_dir, "ok")
    rows = _rows(out)
    assert [int(r["iteration"]) for r in rows] == [15, 35, 150]
    assert all(r["gaussians"] == "777" for r in rows)
    assert [float(r["train_seconds"]) for r in rows] == [1.5, 3.5, 15.0]
    assert all(float(r["cer"]) == 0.0 for r in rows)  # renders are the (PNG) ground truth


@pytest.mark.parametrize("mode,match", [("fail", "(?s)exit code 3.*trainer exploded"), ("missing", "no render for 1 test view"),
                                        ("small", "is 10x10, expected 64x48")])
def test_external_adapter_errors(tmp_path, scene_dir, mode, match):
    with pytest.raises(StringsBenchError, match=match):
        _external(tmp_path, scene_dir, mode)


def test_external_adapter_unknown_placeholder(tmp_path, scene_dir):
    from strings_bench.methods.external import ExternalCommandAdapter
    from strings_bench.scene.scene import Scene

    a = ExternalCommandAdapter(command="train {scene} {nope}")
    with pytest.raises(StringsBenchError, match="unknown placeholder"):
        a.build_command(Scene.load(scene_dir), tmp_path, 7000, 1)


def test_parse_settings():
    from strings_bench.cli.run import parse_settings

    assert parse_settings(["ply.ply_path=/m/{scene}.ply", "strings.n_max=25", "x.flag=true"]) == {
        "ply": {"ply_path": "/m/{scene}.ply"}, "strings": {"n_max": 25}, "x": {"flag": True}}
    # No '.' before the '=': every method of the run; dots in the value do not count.
    assert parse_settings(["lr_means=1.6e-3", "strings.n_max=25", "tag=a.b"]) == {
        ALL_METHODS: {"lr_means": 1.6e-3, "tag": "a.b"}, "strings": {"n_max": 25}}
    for bad in ["noequals", "=1", ".n_max=1", "strings.=1", "strings.n_max"]:
        with pytest.raises(StringsBenchError, match="KEY=VALUE"):
            parse_settings([bad])


def test_set_for_all_methods_reaches_every_job(tmp_path, scene_dir):
    """`--set KEY=VALUE` applies to every method; METHOD.KEY=VALUE wins for its method; both are recorded."""
    from strings_bench.cli.run import parse_settings

    over = parse_settings(["floor=0.05", "fake-b.floor=0.1", "fake-b.extra=1"])
    plan = plan_run(["fake-a", "fake-b"], [str(scene_dir)], run_dir=tmp_path / "run", schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
                           method_overrides=over)
    by = {j.method: j for j in plan.jobs}
    assert by["fake-a"].method_settings == {"floor": 0.05}
    assert by["fake-b"].method_settings == {"floor": 0.1, "extra": 1}
    assert plan.manifest["method_overrides"] == {"fake-a": {"floor": 0.05}, "fake-b": {"floor": 0.1, "extra": 1}}
    # The settings reach the built method: fake-a trains with floor 0.05.
    adapter = runner.build_method(by["fake-a"])
    assert adapter.settings["floor"] == 0.05
    # Resuming: the same settings, given per method instead of for all, are the same run; others are refused.
    _run(tmp_path / "run2", scene_dir, methods=["fake-a"], write_report=False, method_overrides=parse_settings(["floor=0.05"]))
    n_train = len(rf.CALLS["train"])
    _run(tmp_path / "run2", scene_dir, methods=["fake-a"], write_report=False,
         method_overrides=parse_settings(["fake-a.floor=0.05"]))
    assert len(rf.CALLS["train"]) == n_train
    with pytest.raises(StringsBenchError, match="floor"):
        _run(tmp_path / "run2", scene_dir, methods=["fake-a"], write_report=False,
             method_overrides=parse_settings(["floor=0.06"]))


def test_steps_scale_and_checkpoints_options(tmp_path, scene_dir):
    """`run --steps-scale S --checkpoints ...`: paper iterations, each trained as round(it x S), for every method."""
    register_method(MethodSpec(name="fake-scaled", implementation=lambda **s: rf.FakeAdapter(**s), defaults={"steps_scale": 1.0},
                               presets={"blurry": {"steps_scale": 0.005, "floor": 0.2}}))
    plan = plan_run(["fake-scaled", "fake-a"], [str(scene_dir)], run_dir=tmp_path, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
                           steps_scale=0.02, checkpoints=[7000, 3000], method_presets={"fake-scaled": ["blurry"]})
    by = {j.method: j for j in plan.jobs}
    # 3000 x 0.02 = 60, 7000 x 0.02 = 140: the schedule's scale wins over a preset's; its other settings stay.
    assert by["fake-scaled"].checkpoints == (60, 140) and by["fake-scaled"].labels == {60: "3K", 140: "7K"}
    assert by["fake-scaled"].method_settings == {} and by["fake-scaled"].steps_scale == 0.02
    built = runner.build_method(by["fake-scaled"])
    assert built.settings["steps_scale"] == 0.02 and built.settings["floor"] == 0.2
    assert by["fake-scaled"].method_presets == ("blurry",) and plan.manifest["method_presets"]["fake-scaled"] == ["blurry"]
    # A method without a steps_scale setting follows the run's scale.
    assert by["fake-a"].checkpoints == (60, 140) and by["fake-a"].method_settings == {}
    assert by["fake-a"].steps_scale == 0.02 and "steps_scale" not in runner.build_method(by["fake-a"]).settings
    assert plan.manifest["steps_scale"] == 0.02 and plan.manifest["checkpoints"] == [3000, 7000]
    assert plan.manifest["schedule"]["name"] == "tiny" and plan.manifest["schedule"]["steps_scale"] == 0.02
    assert SCHEDULES["tiny"].steps_scale == 0.005  # nothing global was changed
    # Each option alone; a --set steps_scale for a method wins over --steps-scale.
    only_scale = plan_run(["fake-scaled"], [str(scene_dir)], run_dir=tmp_path, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(), steps_scale=0.1)
    assert only_scale.jobs[0].checkpoints == (300, 700, 3000)
    only_its = plan_run(["fake-scaled"], [str(scene_dir)], run_dir=tmp_path, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(), checkpoints=[3000])
    assert only_its.jobs[0].checkpoints == (15,) and only_its.jobs[0].labels == {15: "3K"}
    mine = plan_run(["fake-scaled"], [str(scene_dir)], run_dir=tmp_path, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(), steps_scale=0.1,
                           method_overrides={"fake-scaled": {"steps_scale": 0.01}})
    assert mine.jobs[0].checkpoints == (30, 70, 300) and mine.jobs[0].steps_scale == 0.01
    assert runner.build_method(mine.jobs[0]).settings["steps_scale"] == 0.01  # built with the --set value
    for bad in ({"steps_scale": 0}, {"steps_scale": float("nan")}, {"checkpoints": []}, {"checkpoints": [0]}):
        with pytest.raises(StringsBenchError):
            plan_run(["fake-a"], [str(scene_dir)], run_dir=tmp_path, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(), **bad)


def test_steps_scale_and_checkpoints_recorded_and_kept_on_resume(tmp_path, scene_dir):
    out = tmp_path / "run"
    _run(out, scene_dir, methods=["fake-a"], write_report=False, steps_scale=0.002, checkpoints=[7000, 30000])
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["steps_scale"] == 0.002 and manifest["checkpoints"] == [7000, 30000]
    assert [int(r["iteration"]) for r in _rows(out)] == [14, 60] and [r["label"] for r in _rows(out)] == ["7K", "30K"]
    n_train = len(rf.CALLS["train"])
    _run(out, scene_dir, methods=["fake-a"], write_report=False, steps_scale=0.002, checkpoints=[7000, 30000])
    assert len(rf.CALLS["train"]) == n_train  # the same options resume
    with pytest.raises(StringsBenchError, match="--steps-scale"):
        _run(out, scene_dir, methods=["fake-a"], write_report=False, checkpoints=[7000, 30000])
    with pytest.raises(StringsBenchError, match="--steps-scale"):
        _run(out, scene_dir, methods=["fake-a"], write_report=False, steps_scale=0.003, checkpoints=[7000, 30000])
    with pytest.raises(StringsBenchError, match="--checkpoints"):
        _run(out, scene_dir, methods=["fake-a"], write_report=False, steps_scale=0.002, checkpoints=[7000])
    # Giving the preset's own values is the same run as giving none.
    plain = tmp_path / "plain"
    _run(plain, scene_dir, methods=["fake-a"], write_report=False)
    n_train = len(rf.CALLS["train"])
    _run(plain, scene_dir, methods=["fake-a"], write_report=False, steps_scale=SCHEDULES["tiny"].steps_scale,
         checkpoints=list(SCHEDULES["tiny"].paper_checkpoints))
    assert len(rf.CALLS["train"]) == n_train


def test_run_cli_schedule_and_set_options(monkeypatch):
    """The command line hands --steps-scale, --checkpoints and --set to the runner."""
    import strings_bench.bench.runner as runner_mod
    from strings_bench.cli import main

    seen = {}

    def fake_run(config):  # the command line hands down one RunConfig
        seen.update(dataclasses.asdict(config))
        return Path("out")

    monkeypatch.setattr(bench, "run", fake_run)
    assert main(["run", "--methods", "a,b", "--steps-scale", "0.2", "--checkpoints", "3K,7000",
                 "--set", "lr_means=1e-3", "--set", "a.n_max=25", "--no-progress"]) == 0
    assert seen["steps_scale"] == 0.2 and seen["checkpoints"] == [3000, 7000] and seen["methods"] == ["a", "b"]
    assert seen["method_overrides"] == {"*": {"lr_means": 1e-3}, "a": {"n_max": 25}}
    assert seen["schedule"] == "cpu" and seen["method_presets"] == {}
    assert main(["run", "--no-progress", "--schedule", "quick", "--presets", "strings=release", "--presets", "a=x+y,b=z"]) == 0
    assert seen["steps_scale"] is None and seen["checkpoints"] is None and seen["method_overrides"] == {}
    assert seen["schedule"] == "quick" and seen["method_presets"] == {"strings": ["release"], "a": ["x", "y"], "b": ["z"]}
    assert main(["run", "--no-progress", "--schedule", "tiny"]) == 0 and seen["schedule"] == "tiny"
    assert main(["run", "--no-progress", "--preset", "tiny"]) == 1  # the former name: refused, naming --schedule
    with pytest.raises(SystemExit):
        main(["run", "--checkpoints", "7000,x"])
    assert main(["run", "--presets", "strings"]) == 1  # not METHOD=PRESET


# ---- the PLY adapter ---------------------------------------------------------------------------------
def test_ply_adapter_evaluates_saved_model(tmp_path, scene_dir):
    from strings_bench.engine.gaussians import GaussianModel
    from strings_bench.engine.ply import write_ply
    from strings_bench.scene.scene import Scene

    scene = Scene.load(scene_dir)
    model = GaussianModel.from_points(scene.model.xyz, scene.model.rgb, sh_degree=1)
    n = model.params["means"].shape[0]
    write_ply(tmp_path / "models" / "toy" / "point_cloud.ply", model)
    out = bench.run(["ply"], [str(scene_dir)], run_dir=tmp_path / "run", schedule="tiny", ocr="fake",
                     ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False, write_report=False,
                     method_overrides={"ply": {"ply_path": str(tmp_path / "models" / "{scene}" / "point_cloud.ply")}})
    rows = _rows(out)
    assert len(rows) == 1 and rows[0]["iteration"] == "30000" and rows[0]["label"] == "30K"
    assert int(rows[0]["gaussians"]) == n and rows[0]["train_seconds"] == ""
    with pytest.raises(StringsBenchError, match="does not exist"):
        bench.run(["ply"], [str(scene_dir)], run_dir=tmp_path / "run2", schedule="tiny", ocr="fake",
                   ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False, write_report=False,
                   method_overrides={"ply": {"ply_path": str(tmp_path / "nowhere.ply")}})


# ---- end to end (opt-in) ------------------------------------------------------------------------------
@pytest.mark.slow
def test_end_to_end_cli_3dgs_on_synthetic_books(tmp_path):
    """The real pipeline: `strings-bench run --methods 3dgs --datasets synthetic/books --schedule tiny`."""
    from strings_bench.cli import main
    out = tmp_path / "run"
    rc = main(["run", "--methods", "3dgs", "--datasets", "synthetic/books", "--schedule", "tiny", "--out", str(out),
               "--no-progress"])
    assert rc == 0
    rows = _rows(out)
    assert [r["label"] for r in rows] == ["3K", "7K", "30K"]
    for r in rows:
        assert r["cer"] != "" and 0 <= float(r["cer"]) and float(r["psnr"]) > 5 and int(r["gaussians"]) > 0
        assert float(r["train_seconds"]) > 0
    assert (out / "report" / "report.md").exists()
    # Re-running the same command does nothing and keeps every cell.
    before = {p: p.stat().st_mtime_ns for p in out.rglob("result.json")}
    assert main(["run", "--methods", "3dgs", "--datasets", "synthetic/books", "--schedule", "tiny", "--out", str(out),
                 "--no-progress"]) == 0
    assert {p: p.stat().st_mtime_ns for p in out.rglob("result.json")} == before


def test_lpips_at_all_checkpoints(tmp_path, scene_dir):
    import strings_bench.eval.lpips_net as lpips_net

    if not lpips_net.available():
        pytest.skip("LPIPS weights not installed")
    out = _run(tmp_path / "run", scene_dir, methods=["fake-b"], with_lpips=True, lpips_at="all", write_report=False)
    lp = [float(r["lpips"]) for r in _rows(out)]
    assert lp[0] > lp[1] > lp[2] == pytest.approx(0.0, abs=1e-6)  # fades less with every checkpoint


def test_schedule_scales_every_method_and_never_picks_a_preset(tmp_path, scene_dir):
    """A schedule and a method preset are different things: a preset named like the schedule is not taken."""
    register_method(MethodSpec(name="fake-scaled", implementation=lambda **s: rf.FakeAdapter(**s), defaults={"steps_scale": 1.0},
                               presets={"quick": {"steps_scale": 0.5, "floor": 0.3}}))
    tiny = plan_run(["fake-scaled"], [str(scene_dir)], run_dir=tmp_path, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR())
    assert tiny.jobs[0].checkpoints == (15, 35, 150) and tiny.jobs[0].steps_scale == 0.005
    assert tiny.jobs[0].method_settings == {}
    quick = plan_run(["fake-scaled"], [str(scene_dir)], run_dir=tmp_path, schedule="quick", ocr="fake", ocr_backend=rf.FakeOCR())
    assert quick.jobs[0].checkpoints == (70, 300) and quick.jobs[0].method_presets == ()  # x0.01, not the preset's 0.5
    assert quick.jobs[0].labels == {70: "7K", 300: "30K"}
    assert "floor" not in runner.build_method(quick.jobs[0]).settings
    with pytest.raises(StringsBenchError, match="(?s)fake-scaled has no preset 'nope'.*presets of fake-scaled: quick"):
        plan_run(["fake-scaled"], [str(scene_dir)], run_dir=tmp_path, method_presets={"fake-scaled": ["nope"]})
    with pytest.raises(StringsBenchError, match="--presets names method.*fake-a"):
        plan_run(["fake-scaled"], [str(scene_dir)], run_dir=tmp_path, method_presets={"fake-a": ["x"]})


def test_presets_apply_per_dataset_and_the_release_preset_is_reachable(tmp_path, scene_dir):
    """STRinGS' N_max per dataset comes from its spec's @apply presets (the release's full_eval.py values)."""
    from strings_bench.methods.registry import get_method

    spec = get_method("strings")
    assert spec.presets_for("strings360", "books") == ["n-max-strings360"]
    assert spec.presets_for("tandt", "truck") == ["n-max-truck"] and spec.presets_for("tandt", "train") == ["n-max-train"]
    n_max = {s: spec.resolve(spec.presets_for("dl3dv", s))["n_max"] for s in ("3", "21", "80", "92", "107", "132", "136")}
    assert n_max == {"3": 20, "21": 20, "80": 15, "92": 20, "107": 20, "132": 15, "136": 15}
    assert spec.presets_for("synthetic", "books") == [] and spec.presets_for("dl3dv", "4") == []
    plan = plan_run(["strings", "3dgs"], [str(scene_dir)], run_dir=tmp_path, schedule="tiny",
                           method_presets={"strings": ["release"]})
    by = {j.method: j for j in plan.jobs}
    assert by["strings"].method_presets == ("release",) and by["3dgs"].method_presets == ()
    built = runner.build_method(by["strings"])
    assert built.st.gamma == 12000 and built.st.gamma_counter == "phase2"  # the release's, reached from the run
    assert built.settings["steps_scale"] == SCHEDULES["tiny"].steps_scale  # the schedule still scales it
    # resuming with other presets is refused, as with other --set values
    from strings_bench.core.io import atomic_write_json

    atomic_write_json(tmp_path / "run.json", {**plan.manifest})
    with pytest.raises(StringsBenchError, match="presets"):
        check_manifest(tmp_path, {**plan.manifest, "method_presets": {"strings": [], "3dgs": []}})


class _BowtieOCR(rf.FakeOCR):
    """FakeOCR whose word boxes come out self-intersecting (corners 2 and 3 swapped), as real engines sometimes give."""

    def read(self, image, mask=None):
        return [Word(w.text, w.polygon[[0, 2, 1, 3]]) for w in super().read(image, mask)]


def test_cer_profile_is_chosen_recorded_and_kept_on_resume(tmp_path, scene_dir):
    out_paper, out_robust = tmp_path / "paper", tmp_path / "robust"
    _run(out_paper, scene_dir, methods=["fake-a"], ocr=_BowtieOCR(), write_report=False)
    _run(out_robust, scene_dir, methods=["fake-a"], ocr=_BowtieOCR(), write_report=False, cer_profile="robust")
    assert json.loads((out_paper / "run.json").read_text())["cer_profile"] == "paper"  # the default
    assert json.loads((out_robust / "run.json").read_text())["cer_profile"] == "robust"
    final = CellKey("fake-a", "toy", "toy", 150)
    rec_p = json.loads((final.path(out_paper) / "result.json").read_text())
    rec_r = json.loads((final.path(out_robust) / "result.json").read_text())
    assert rec_p["config"]["cer_profile"] == "paper" and rec_p["cer"]["profile"]["polygons"] == "strict"
    assert rec_r["config"]["cer_profile"] == "robust" and rec_r["cer"]["profile"]["polygons"] == "repair"
    assert rec_r["cer_known"]["profile"]["name"] == "robust"
    # The render is the ground truth and both read "hello", but in bow-tie boxes: the authors' rule
    # never matches them (5 errors / 5 per view), the repair does (0).
    n_views = len(rec_p["cer"]["images"])
    assert n_views >= 1
    assert (rec_p["cer"]["errors"], rec_p["cer"]["chars"]) == (5 * n_views, 5 * n_views)
    assert (rec_r["cer"]["errors"], rec_r["cer"]["chars"]) == (0, 5 * n_views)
    # Resuming with another profile would mix scorings in one folder.
    with pytest.raises(StringsBenchError, match="cer-profile"):
        _run(out_paper, scene_dir, methods=["fake-a"], ocr=_BowtieOCR(), write_report=False, cer_profile="robust")
    # A folder from before the option was scored with what is now "robust".
    manifest = json.loads((out_robust / "run.json").read_text())
    del manifest["cer_profile"]
    (out_robust / "run.json").write_text(json.dumps(manifest))
    with pytest.raises(StringsBenchError, match="before --cer-profile existed"):
        _run(out_robust, scene_dir, methods=["fake-a"], ocr=_BowtieOCR(), write_report=False)
    _run(out_robust, scene_dir, methods=["fake-a"], ocr=_BowtieOCR(), write_report=False, cer_profile="robust")
    with pytest.raises(StringsBenchError, match="unknown CER profile"):
        _run(tmp_path / "x", scene_dir, methods=["fake-a"], cer_profile="nope")


def test_schedule_scale_reaches_a_spec_with_no_defaults(tmp_path, scene_dir):
    """A method spec with no defaults at all (no steps_scale in its defaults) trains the run's scaled number of
    steps, and its internal schedules (densification, SH degree, position LR) are scaled with it."""
    from strings_bench.bench.plan import takes_steps_scale
    from strings_bench.store import read_cell

    spec = MethodSpec(name="bare-3dgs", implementation="strings_bench.methods.gs3d:GS3D")
    assert spec.defaults == {} and takes_steps_scale(spec)
    register_method(spec)
    plan = plan_run(["bare-3dgs"], [str(scene_dir)], run_dir=tmp_path / "run", schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
                           checkpoints=[3000, 7000])
    job = plan.jobs[0]
    assert job.checkpoints == (15, 35) and job.steps_scale == 0.005 and job.method_settings == {}
    method = runner.build_method(job)
    assert method.config.steps_scale == 0.005
    # 3DGS' nominal schedules, scaled: densification stops at 15K -> 75 steps, the SH degree rises every 1K -> 50
    # steps (the floor of a scaled interval) instead of every 1 000.
    assert method.at(15_000) == 75 and method.every(1_000) == 50
    assert method.sh_degree_for_step(50) == 1 and method.sh_degree_for_step(49) == 0
    assert method.strategy.at(method.strategy.refine_stop_iter) == 75  # the strategy scales as its method does
    bench.run(["bare-3dgs"], [str(scene_dir)], run_dir=tmp_path / "run", schedule="tiny", ocr="fake",
               ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False, write_report=False, checkpoints=[3000, 7000],
               method_overrides={"bare-3dgs": {"sh_degree": 0}})
    rec = read_cell(tmp_path / "run", CellKey("bare-3dgs", job.dataset, job.scene, 35))
    assert rec["extra"]["steps_scale"] == 0.005 and rec["extra"]["paper_iteration"] == 7000
    assert rec["config"]["method"]["settings"]["steps_scale"] == 0.005


def test_a_resumed_run_with_a_changed_plan_is_refused_and_run_json_is_no_configuration(tmp_path, scene_dir):
    """run.json is the plan's record: a re-run whose new plan differs (here the OCR engine list, the CER profile)
    is refused with an error naming the folder, both values and the way out, and nothing is trained or written;
    an edited value run.json records but the plan does not compare (the device asked for) configures nothing."""
    out = tmp_path / "run"
    _run(out, scene_dir, methods=["fake-a"], write_report=False)
    cells = sorted(p.stat().st_mtime_ns for p in out.rglob("result.json"))
    n_train = len(rf.CALLS["train"])
    with pytest.raises(StringsBenchError, match="profile 'paper'; this run asks for 'robust'") as err:
        _run(out, scene_dir, methods=["fake-a"], write_report=False, cer_profile="robust")
    assert str(out) in err.value.message and "--out" in err.value.hint
    with pytest.raises(StringsBenchError, match="--ocr engine list 'fake'; this run asks for 'fake,tesseract'"):
        _run(out, scene_dir, methods=["fake-a"], write_report=False, ocr_list="fake,tesseract")
    assert len(rf.CALLS["train"]) == n_train and sorted(p.stat().st_mtime_ns for p in out.rglob("result.json")) == cells
    record = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps({**record, "device": "cuda:7"}))
    plan = plan_run(["fake-a"], [str(scene_dir)], run_dir=out, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
                    with_lpips=False)
    assert {j.device for j in plan.jobs} == {plan.device} and plan.device in ("cpu", "cuda")
    runner.execute(plan, ocr=rf.FakeOCR(), progress=False, write_report=False)  # resumes: nothing left to do
    assert json.loads((out / "run.json").read_text())["device"] == "auto"  # the plan's record, written again
