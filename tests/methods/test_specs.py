"""Method specs as data: lazy implementations, every setting listed, --set checked before any scene is built."""

from __future__ import annotations

from strings_bench.bench.plan import plan_run
from strings_bench.bench.plan import ALL_METHODS

from strings_bench.core.schedules import get_schedule

import dataclasses
import subprocess
import sys

import pytest

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.optim import LearningRates
from strings_bench.engine.splatting import TrainConfig
from strings_bench.engine.strategies.default import DefaultStrategy
from strings_bench.bench.plan import with_steps_scale
from strings_bench.methods.registry import builtin_specs, get_method, show_method
from strings_bench.methods.strings.method import StringsSettings


def test_registry_imports_no_implementation():
    """Listing methods must not import a method module (implementations are "module:Class" strings): only the
    registry, the spec machinery and the specs beside the methods (and the strings package that holds one)."""
    code = ("import sys; from strings_bench.methods.registry import list_methods; list_methods(); "
            "print(sorted(m for m in sys.modules if m.startswith('strings_bench.methods.') "
            "or m.startswith('strings_bench.engine')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    loaded = eval(out.strip())
    allowed = {"strings_bench.methods.registry", "strings_bench.methods.spec", "strings_bench.methods.strings"}
    assert loaded and all(m in allowed or m.endswith("_spec") or m.endswith(".spec") for m in loaded), loaded


def test_every_builtin_implementation_loads_under_its_name():
    for spec in builtin_specs():
        impl = spec.load()
        assert isinstance(impl, type), spec.name
        obj = spec.build(**with_steps_scale(spec, get_schedule("tiny").steps_scale))  # as a run builds it
        assert obj.name == spec.name


def test_show_lists_every_setting_with_default_and_meaning():
    text = show_method("strings")
    expected = ([f.name for f in dataclasses.fields(TrainConfig) if f.name != "lrs"]
                + [f"lr_{f.name}" for f in dataclasses.fields(LearningRates)]
                + [f.name for f in dataclasses.fields(DefaultStrategy) if f.metadata.get("setting", True)]
                + [f.name for f in dataclasses.fields(StringsSettings)])
    lines = {line.split()[0]: line for line in text.splitlines() if line.startswith("  ")}
    missing = [k for k in expected if k not in lines]
    assert not missing, missing
    undocumented = [k for k in expected if len(lines[k].split(None, 2)) < 3]
    assert not undocumented, f"settings without a meaning: {undocumented}"
    assert "gamma  " in text and "15000" in lines["gamma"] and "paper" in lines["gamma"]
    # the paper's published figures (docs/sources.md §5) travel with the spec
    assert "strings360: cer 7K 0.177, 30K 0.106; minutes 7K 1.9, 30K 12.6" in text
    assert "release" in text and "gamma_counter" in text


def test_spec_defaults_show_as_the_methods_defaults():
    lines = {ln.split()[0]: ln for ln in show_method("edc-absgs").splitlines() if ln.startswith("  ")}
    assert lines["lr_means"].split()[1] == "4e-05"  # the spec's default, not 3DGS' 1.6e-4


def test_unknown_setting_names_the_valid_ones():
    with pytest.raises(StringsBenchError, match=r"(?s)mcmc has no setting\(s\) cap_maxx.*valid settings:.*cap_max"):
        get_method("mcmc").build(cap_maxx=3)


def test_bad_set_is_refused_before_any_scene_is_built(monkeypatch, tmp_path):
    import strings_bench.datasets.registry as datasets
    from strings_bench.bench import runner

    def no_scenes(*a, **k):
        raise AssertionError("scenes were resolved before the settings were checked")

    monkeypatch.setattr(datasets, "resolve_scenes", no_scenes)
    with pytest.raises(StringsBenchError, match="strings has no setting.*n_maxx"):
        plan_run(["strings", "3dgs"], ["synthetic"], run_dir=tmp_path, method_overrides={"strings": {"n_maxx": 3}})
    with pytest.raises(StringsBenchError, match="no method of this run has the setting.*n_maxx"):
        plan_run(["strings", "3dgs"], ["synthetic"], run_dir=tmp_path, method_overrides={ALL_METHODS: {"n_maxx": 3}})
    with pytest.raises(StringsBenchError, match="does not train"):
        plan_run(["3dgs"], ["synthetic"], run_dir=tmp_path, method_overrides={"strngs": {"n_max": 3}})
    with pytest.raises(StringsBenchError, match="device"):
        plan_run(["3dgs"], ["synthetic"], run_dir=tmp_path, device="tpu")
    with pytest.raises(StringsBenchError, match="save-every"):
        plan_run(["3dgs"], ["synthetic"], run_dir=tmp_path, save_every="often")


def test_all_methods_setting_goes_to_the_methods_that_have_it(tmp_path):
    import runner_fakes as rf

    scene = rf.make_scene(tmp_path / "scenes")  # a scene folder on disk: planning reads it, builds nothing
    plan = plan_run(["strings", "ply"], [str(scene)], run_dir=tmp_path / "run",
                    method_overrides={ALL_METHODS: {"n_max": 20, "iteration": 7000}})
    by = {j.method: j.method_settings for j in plan.jobs}
    assert by["strings"]["n_max"] == 20 and "iteration" not in by["strings"]
    assert by["ply"]["iteration"] == 7000 and "n_max" not in by["ply"]


def test_methods_show_cli(capsys):
    from strings_bench.cli import main

    assert main(["methods", "show", "3dgs"]) == 0
    out = capsys.readouterr().out
    assert "grow_grad2d" in out and "0.0002" in out and "densify when" in out
    assert main(["methods", "show", "no-such-method"]) == 1


def test_spec_is_keyword_only_and_its_paper_figures_are_named():
    from strings_bench.methods.registry import MethodSpec

    with pytest.raises(TypeError):
        MethodSpec("x", "strings_bench.methods.gs3d:GS3D")  # positional rows are gone: every field by name
    strings = get_method("strings")
    assert strings.paper_figures.get("strings360", "cer", 30000) == 0.106
    assert strings.paper_figures.get("tandt", "cer", 7000) == 0.122
    assert strings.paper_results["strings360"] == {"cer": {7000: 0.177, 30000: 0.106}, "minutes": {7000: 1.9, 30000: 12.6}}
    assert get_method("ply").paper_results == {}
    # the name lives on the spec only; a built method carries it
    from strings_bench.methods.mip_splatting import MipSplatting

    assert "name" not in vars(MipSplatting) and get_method("mip-splatting").build(steps_scale=get_schedule("tiny").steps_scale).name == "mip-splatting"


def test_ablations_are_named_by_their_specs_and_read_by_the_tables():
    import pandas as pd

    from strings_bench.methods.registry import MethodSpec, registered
    from strings_bench.reports.ablations import ablation_table

    assert (get_method("strings-no-densify").ablation_of, get_method("strings-no-densify").ablation_at) == ("strings", 7000)
    assert (get_method("strings-pos-lr").ablation_of, get_method("strings-pos-lr").ablation_at) == ("strings", 3000)
    with pytest.raises(StringsBenchError, match="ablation_at"):
        MethodSpec(name="half", implementation="strings_bench.methods.gs3d:GS3D", ablation_of="3dgs")
    spec = MethodSpec(name="3dgs-no-reset", implementation="strings_bench.methods.gs3d:GS3D", ablation_of="3dgs",
                      ablation_at=30000, ablation_effect="the opacity reset")
    assert spec.group == "ablation"
    rows = [{"method": m, "dataset": "synthetic", "scene": "books", "label": label, "iteration": it, "cer": cer}
            for m, label, it, cer in (("3dgs", "7K", 35, 0.9), ("3dgs", "30K", 150, 0.5),
                                      ("3dgs-no-reset", "7K", 35, 0.8), ("3dgs-no-reset", "30K", 150, 0.7))]
    with registered(spec):
        t = ablation_table(pd.DataFrame(rows))
    assert t.methods == ["3dgs", "3dgs-no-reset"]
    assert t.rows == [("Effect of the opacity reset", "3dgs-no-reset", "30K", [(0.7, 0.5)])]


def test_each_builtin_spec_is_found_beside_its_method():
    """Every built-in spec lives in a spec module beside its implementation's module (nerfbaselines' *_spec.py):
    `gs3d_spec.py` next to `gs3d.py`, STRinGS' `strings/spec.py` inside its package; methods/registry.py and
    methods/spec.py hold no spec of their own."""
    import importlib
    from pathlib import Path

    import strings_bench.methods.registry as registry
    import strings_bench.methods.spec as machinery
    from strings_bench.methods.registry import BUILTIN_SPEC_MODULES

    seen = []
    for module_name in BUILTIN_SPEC_MODULES:
        module = importlib.import_module(module_name)
        specs = getattr(module, "SPECS", None) or [module.SPEC]
        for spec in specs:
            impl_module = spec.implementation.partition(":")[0]
            impl_file = Path(importlib.util.find_spec(impl_module).origin)
            assert Path(module.__file__).parent == impl_file.parent, (spec.name, module_name, impl_module)
            stem = Path(module.__file__).stem
            assert stem == "spec" or stem == impl_file.stem + "_spec", (spec.name, module_name)
            seen.append(spec.name)
    assert seen == [s.name for s in builtin_specs()] and len(seen) == len(set(seen)) == 13
    for holder in (registry, machinery):
        assert "MethodSpec(\n" not in Path(holder.__file__).read_text() and "MethodSpec(name=" not in \
            Path(holder.__file__).read_text(), holder.__name__


def test_paper_figures_are_keyed_by_dataset_metric_and_iteration():
    from strings_bench.methods.spec import PaperFigures

    f = get_method("3dgs").paper_figures
    assert isinstance(f, PaperFigures) and f.get("dl3dv", "cer", 30000) == 0.157 and f.get("dl3dv", "cer", 3000) is None
    assert f.get("strings360", "minutes", 7000) == 2.5 and set(f.by_dataset()) == {"tandt", "dl3dv", "strings360"}
