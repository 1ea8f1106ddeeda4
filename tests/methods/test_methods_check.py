"""`strings-bench methods check`: every built-in method conforms; broken adapters fail, naming the check."""

from __future__ import annotations

import dataclasses
import shlex
import sys

import numpy as np
import pytest
import torch

import broken_methods
from strings_bench.bench.check import check_method, first_difference
from strings_bench.methods.registry import builtin_specs, get_method

BUILTIN = [s.name for s in builtin_specs()]
ADAPTERS = {"ply", "external"}


def _by_check(results):
    return {r.check: r for r in results}


def _broken(cls) -> object:
    """3DGS' spec (defaults, tiny preset) with a broken implementation."""
    return dataclasses.replace(get_method("3dgs"), name=f"broken-{cls.__name__.lower()}", implementation=cls)


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_method_passes_the_check(name):
    # LPIPS (two VGG passes) once, for 3dgs; the runner's other metrics and the real OCR for every method.
    results = _by_check(check_method(name, devices=["cpu"], with_lpips=name == "3dgs"))
    failed = {k: r.detail for k, r in results.items() if r.failed}
    assert not failed, failed
    expected = {"settings", "builds", "trains (cpu)", "renders (cpu)", "runner"}
    if name not in ADAPTERS:
        expected |= {"save/load", "re-save"}
    assert {k for k, r in results.items() if r.status == "pass"} == expected
    if name not in ADAPTERS:
        assert "reproduced" in results["save/load"].detail
    assert "1 cell(s)" in results["runner"].detail and "PSNR" in results["runner"].detail


@pytest.mark.parametrize("cls, check, reason", [
    (broken_methods.DropsTensorOnLoad, "save/load", "after save -> load differs by up to"),
    (broken_methods.NaNRender, "renders (cpu)", "NaN/Inf value"),
    (broken_methods.WrongSizeRender, "renders (cpu)", "has shape (71, 96, 3), expected (72, 96, 3)"),
    (broken_methods.ConstantRender, "renders (cpu)", "is constant"),
    (broken_methods.UnstableState, "re-save", "state['saves']"),
    (broken_methods.NoSettingsSchema, "settings", "no settings_schema()"),
])
def test_broken_method_fails_naming_the_check(cls, check, reason):
    results = _by_check(check_method(_broken(cls), devices=["cpu"], runner=False))
    failed = {k for k, r in results.items() if r.failed}
    assert failed == {check}, {k: r.detail for k, r in results.items()}
    assert reason in results[check].detail
    assert results[check].line().startswith(f"FAIL  {check}")
    assert results["builds"].status == "pass"


def test_runner_check_fails_on_nan_renders():
    results = _by_check(check_method(_broken(broken_methods.NaNRender), devices=["cpu"], runner=True))
    assert results["runner"].failed and "NaN/Inf value(s)" in results["runner"].detail


def test_dependent_checks_are_skipped_when_the_method_does_not_build():
    results = check_method("3dgs", {"no_such_setting": 1}, devices=["cpu"], runner=False)
    by = _by_check(results)
    assert by["builds"].failed and "no_such_setting" in by["builds"].detail
    assert by["trains (cpu)"].status == "skip" and "needs builds" in by["trains (cpu)"].detail
    assert by["save/load"].status == "skip"


def test_external_command_is_checked_with_the_users_command(tmp_path):
    # A command that writes its renders at half the size: the adapter's own error names the size.
    script = tmp_path / "half.py"
    script.write_text("import sys, pathlib\nfrom PIL import Image\nscene, out, views = sys.argv[1:4]\n"
                      "for v in views.split(','):\n"
                      "    im = Image.open(pathlib.Path(scene) / 'images' / v)\n"
                      "    im.resize((im.width // 2, im.height // 2)).save(pathlib.Path(out) / (pathlib.Path(v).stem + '.png'))\n")
    cmd = shlex.join([sys.executable, str(script)]) + " {scene} {out} {test_views}"
    by = _by_check(check_method("external", {"command": cmd}, devices=["cpu"], runner=False))
    assert by["trains (cpu)"].failed and "is 48x36, expected 96x72" in by["trains (cpu)"].detail
    assert "stand-in" not in by["builds"].detail


def test_cli_check_exit_status_and_lines(capsys):
    from strings_bench.cli import main

    assert main(["methods", "check", "broken_methods:WrongSizeRender", "--no-runner", "--device", "cpu"]) == 1
    out = capsys.readouterr().out
    assert "FAIL  renders (cpu)" in out and "expected (72, 96, 3)" in out
    assert "FAILED 1 check(s): renders (cpu)" in out
    assert main(["methods", "check", "3dgs", "--no-runner", "--device", "cpu", "--set", "lr_means=1e-4"]) == 0
    out = capsys.readouterr().out
    assert "pass  save/load" in out and "all 6 checks passed" in out


def test_cli_check_unknown_method_is_a_clear_error(capsys):
    from strings_bench.cli import main

    assert main(["methods", "check", "no-such-method"]) == 1
    out = capsys.readouterr().out
    assert "FAIL  builds" in out and "unknown method 'no-such-method'" in out and "known methods: 3dgs" in out


def test_first_difference_names_the_path():
    a = {"model": {"means": torch.zeros(3, 2), "n": 1}, "rng": np.arange(3), "loss": float("nan"), "views": [1, 2]}
    assert first_difference(a, {"model": {"means": torch.zeros(3, 2), "n": 1}, "rng": np.arange(3),
                                "loss": float("nan"), "views": [1, 2]}) is None
    b = {**a, "model": {"means": torch.tensor([[0.0, 0], [0, 1e-7], [0, 0]]), "n": 1}}
    assert first_difference(a, b) == "state['model']['means']: 1 of 6 values differ"
    assert first_difference(a, {**a, "views": [1, 3]}) == "state['views'][1]: 2 against 3"
    assert "missing rng" in first_difference(a, {k: v for k, v in a.items() if k != "rng"})
    assert "torch.float32 (3, 2) against torch.float64 (3, 2)" in first_difference(
        a, {**a, "model": {"means": torch.zeros(3, 2, dtype=torch.float64), "n": 1}})


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA GPU")
def test_builtin_methods_train_on_cuda():
    for name in BUILTIN:
        by = _by_check(check_method(name, devices=["cpu", "cuda"], runner=False))
        failed = {k: r.detail for k, r in by.items() if r.failed}
        assert not failed, (name, failed)
        if name not in ADAPTERS:
            assert by["trains (cuda)"].status == "pass" and by["renders (cuda)"].status == "pass"
