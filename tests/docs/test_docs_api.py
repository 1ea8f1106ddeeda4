"""The API reference (docs/reference/api.md): it names every object users call and subclass, each one exists under
the name it is shown by, each hook of GaussianSplatting says when the loop calls it, and the contracts' examples run.

docs/reference/api.md is the one list of the reference's objects (its `::: path` lines); this file reads it."""

from __future__ import annotations

import doctest
import importlib
import inspect
import io
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
API_PAGE = ROOT / "docs" / "reference" / "api.md"

# What users call and subclass, by the name they import it under: each must be in the reference.
REQUIRED = ["run", "RunConfig", "Method", "MethodAdapter", "MethodSpec", "GaussianSplatting", "Strategy",
            "DefaultStrategy", "Scene", "GaussianModel", "RasterOutput", "OCRBackend", "evaluate", "EvaluateOptions"]


def api_objects() -> list[str]:
    """The dotted paths of docs/reference/api.md's `::: path` entries, in page order."""
    return re.findall(r"^::: ([\w.]+)\s*$", API_PAGE.read_text(encoding="utf-8"), re.M)


def _members(path: str) -> list[str]:
    """The members an entry lists explicitly (`members: [...]` or a `- name` list under it)."""
    text = API_PAGE.read_text(encoding="utf-8")
    block = re.search(rf"^::: {re.escape(path)}\s*\n((?:    .*\n)*)", text, re.M)
    if not block:
        return []
    inline = re.search(r"members: \[(.*?)\]", block.group(1))
    if inline:
        return [m.strip() for m in inline.group(1).split(",") if m.strip()]
    return re.findall(r"^        - (\w+)\s*$", block.group(1), re.M)


def resolve(path: str):
    parts = path.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(path)


def test_every_required_object_is_in_the_reference():
    names = {p.rsplit(".", 1)[-1] for p in api_objects()}
    missing = [n for n in REQUIRED if n not in names]
    assert not missing, f"docs/reference/api.md lacks {missing}"


@pytest.mark.parametrize("path", api_objects())
def test_each_object_exists_and_has_a_docstring(path):
    obj = resolve(path)
    assert inspect.getdoc(obj), f"{path} has no docstring"
    for member in _members(path):
        assert inspect.getdoc(getattr(obj, member)), f"{path}.{member} has no docstring"


def test_the_list_parser_reads_the_page():
    """The page lists the objects the parser finds (a format change would make the tests above check nothing)."""
    assert len(api_objects()) >= 20
    assert "loss" in _members("strings_bench.engine.splatting.GaussianSplatting")
    assert "read" in _members("strings_bench.eval.ocr.OCRBackend")


WHEN = re.compile(r"\b(Called|called|calls)\b")


def test_each_hook_says_when_it_runs():
    from strings_bench.engine.splatting import GaussianSplatting

    hooks = _members("strings_bench.engine.splatting.GaussianSplatting")
    silent = [h for h in hooks if h not in ("at", "every")
              and not WHEN.search(inspect.getdoc(getattr(GaussianSplatting, h)) or "")]
    assert not silent, f"hooks whose docstring does not say when the loop calls them: {silent}"


def test_hooks_document_their_arguments():
    """Each GaussianSplatting hook with a step or view argument documents it (Args:) or defers to Method's."""
    from strings_bench.engine.splatting import GaussianSplatting

    undocumented = []
    for name in _members("strings_bench.engine.splatting.GaussianSplatting"):
        fn = getattr(GaussianSplatting, name)
        params = [p for p in inspect.signature(fn).parameters if p not in ("self", "cls", "settings", "kw", "step")]
        doc = inspect.getdoc(fn) or ""
        for p in params:
            # an Args: entry, or the argument named in the text (`model`), or Method's contract referred to
            if not re.search(rf"^\s+\**{p}:", doc, re.M) and f"`{p}`" not in doc and "see `Method." not in doc:
                undocumented.append(f"{name}({p})")
    assert not undocumented, undocumented


@pytest.mark.parametrize("path", ["strings_bench.scene.scene.Scene"])
def test_contract_examples_run(path):
    obj = resolve(path)
    tests = [t for t in doctest.DocTestFinder().find(obj, module=inspect.getmodule(obj)) if t.examples]
    assert tests
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    out = io.StringIO()
    for t in tests:
        runner.run(t, out=out.write)
    assert runner.summarize(verbose=False).failed == 0, out.getvalue()
