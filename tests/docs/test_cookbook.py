"""The cookbook (docs/cookbook/): every recipe is a file of examples/cookbook/ that runs here, does what its page
says, and its page shows the file's own code, the command and the output it prints (numbers aside).

Each recipe's `main()` runs in this process on a tiny scene and schedule; the CPU seconds it took are printed
(`pytest tests/docs/test_cookbook.py -s`), the figures the pages' "Cost" lines state."""

from __future__ import annotations

import importlib
import re
import resource
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
COOKBOOK = ROOT / "examples" / "cookbook"
PAGES = ROOT / "docs" / "cookbook"

# recipe file -> its page
RECIPES = {
    "clone_only": "densification.md",
    "per_gaussian_lr": "per-gaussian.md",
    "nearest_view": "not-3dgs.md",
    "wrap_external": "external.md",
    "upscale_ocr": "ocr-engine.md",
    "score_folder": "score-folder.md",
}


@pytest.fixture
def recipe(monkeypatch):
    monkeypatch.syspath_prepend(str(COOKBOOK))
    loaded = []

    def load(name):
        sys.modules.pop(name, None)
        loaded.append(name)
        return importlib.import_module(name)

    yield load
    for name in loaded:
        sys.modules.pop(name, None)


def _run(module, capsys, *args) -> list[str]:
    def cpu_seconds() -> float:  # this process and the programs it ran (the external trainer)
        return sum(u.ru_utime + u.ru_stime for u in (resource.getrusage(resource.RUSAGE_SELF),
                                                     resource.getrusage(resource.RUSAGE_CHILDREN)))

    before = cpu_seconds()
    module.main(*args)
    cpu = cpu_seconds() - before
    out = capsys.readouterr().out
    with capsys.disabled():
        print(f"\n{module.__name__}: {cpu:.2f} CPU s")
    return out.splitlines()


def _masked(line: str) -> str:
    return re.sub(r"-?\d+(?:\.\d+)?|\binf\b|\bnan\b", "N", line.rstrip())


def _page_output(page: str) -> list[str]:
    """The lines of the page's output block (the ```text block after "Output")."""
    text = (PAGES / page).read_text(encoding="utf-8")
    m = re.search(r"Output[^\n]*\n+```text\n(.*?)```", text, re.S)
    assert m, f"docs/cookbook/{page} shows no output block"
    return m.group(1).rstrip("\n").splitlines()


def _check_page(name: str, lines: list[str]) -> None:
    page = RECIPES[name]
    text = (PAGES / page).read_text(encoding="utf-8")
    assert f"python examples/cookbook/{name}.py" in text, f"{page} does not show the command"
    assert re.search(r"^\*\*Cost\*\*", text, re.M), f"{page} states no cost"
    source = (COOKBOOK / f"{name}.py").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks, f"{page} shows no code"
    for block in blocks:
        assert block.strip() in source, f"{page}: a code block is not part of {name}.py:\n{block[:300]}"
    assert [_masked(x) for x in _page_output(page)] == [_masked(x) for x in lines], \
        f"{page}'s output differs from what {name}.py prints:\n" + "\n".join(lines)


def test_every_recipe_has_a_page_and_a_test():
    files = {p.stem for p in COOKBOOK.glob("*.py")} - {"mean_image_trainer"}  # the trainer wrap_external runs
    assert files == set(RECIPES), files ^ set(RECIPES)
    index = (PAGES / "README.md").read_text(encoding="utf-8")
    for page in [*RECIPES.values(), "../guide/adding-a-method.md"]:
        assert f"]({page})" in index, f"docs/cookbook/README.md does not link {page}"


def test_densification_strategy(recipe, capsys):
    lines = _run(recipe("clone_only"), capsys)
    base, clone_only = (re.search(r"(\d+) cloned, (\d+) split", line).groups() for line in lines)
    assert int(base[1]) > 0 and int(clone_only[1]) == 0  # 3DGS splits; the recipe's strategy never does
    assert int(clone_only[0]) > int(base[0])  # what 3DGS would split is cloned instead
    _check_page("clone_only", lines)


def test_per_gaussian_value(recipe, capsys):
    module = recipe("per_gaussian_lr")
    lines = _run(module, capsys)
    counts = [tuple(map(int, re.search(r"(\d+) Gaussians, +(\d+) factors", line).groups())) for line in lines]
    assert all(g == f for g, f in counts) and counts[-1][0] > counts[0][0]  # densified, one factor per Gaussian
    _check_page("per_gaussian_lr", lines)


def test_per_gaussian_value_reaches_the_update(recipe):
    """The factor is what moves: a Gaussian with factor 0 keeps its position through a step."""
    import torch

    from strings_bench.bench.check import tiny_scene
    from strings_bench.scene.scene import Scene

    module = recipe("per_gaussian_lr")
    method = module.SPEC.build(steps_scale=0.01)
    method.setup(Scene.load(tiny_scene()))
    method.model.extras["lr_gain"][:10] = 0.0
    before = method.model.means.detach().clone()
    method.train_step(1)
    moved = (method.model.means.detach() - before).norm(dim=1) > 0
    assert not moved[:10].any() and moved[10:].any()


def test_method_that_is_not_3dgs(recipe, capsys):
    module = recipe("nearest_view")
    lines = _run(module, capsys)
    assert lines and all("PSNR" in line for line in lines)
    _check_page("nearest_view", lines)


def test_method_that_is_not_3dgs_passes_the_check(recipe):
    from strings_bench.bench.check import check_method
    from strings_bench.methods.registry import registered

    module = recipe("nearest_view")
    with registered(module.SPEC):
        results = check_method(module.SPEC.name, devices=["cpu"], with_lpips=False, runner=False)
    failed = {r.check: r.detail for r in results if r.failed}
    assert not failed, failed


def test_external_trainer(recipe, capsys):
    lines = _run(recipe("wrap_external"), capsys)
    assert [line.split(":")[0] for line in lines] == ["iteration 100", "iteration 300"]
    _check_page("wrap_external", lines)


def test_ocr_engine_of_your_own(recipe, capsys):
    module = recipe("upscale_ocr")
    lines = _run(module, capsys)
    assert "rapidocr-upscaled" in lines[1] and "READ" in lines[1]
    engine = module.UpscaledRapidOCR(factor=2)
    assert engine.describe()["name"] == "rapidocr-upscaled" and engine.describe()["settings"] == {"factor": 2}
    _check_page("upscale_ocr", lines)


def test_scoring_a_folder_from_python(recipe, capsys, tmp_path):
    lines = _run(recipe("score_folder"), capsys, tmp_path)
    sharp, blurred = (float(re.search(r"OCR-CER ([\d.]+)", line).group(1)) for line in lines)
    assert sharp == 0.0 and blurred > sharp  # the scene's own views read as their ground truth; blur costs characters
    assert all(int(re.search(r"over (\d+) GT", line).group(1)) >= 10 for line in lines)  # a CER over real text
    assert (tmp_path / "scored-blur0.8" / "results.csv").is_file()
    _check_page("score_folder", lines)
