"""The docstring rules of the lint step (the table of every rule is tests/lint/test_rules.py's docstring): the public
API's docstrings are contracts, their examples run and every parameter is documented.

Covers `rasterize` and `RasterOutput` (strings_bench.raster), the strategy interface (`Strategy`,
`DefaultStrategy`) and `GaussianModel`: the objects docs/raster.md and docs/engine.md point users
at. The examples are run with doctest, so a changed signature, shape or default breaks this test
instead of silently rotting the docstring.
"""

from __future__ import annotations

import dataclasses
import doctest
import inspect
import io
import re

import pytest

from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.strategies.base import Strategy
from strings_bench.engine.strategies.default import DefaultStrategy
from strings_bench.raster import pick_backend, rasterize
from strings_bench.raster.types import RasterOutput

FUNCTIONS = [rasterize, pick_backend]
CLASSES = [RasterOutput, Strategy, DefaultStrategy, GaussianModel]

# Objects whose own docstring must carry a runnable example (not only some method of theirs).
MUST_HAVE_EXAMPLE = [rasterize, pick_backend, RasterOutput, Strategy, DefaultStrategy, GaussianModel,
                     GaussianModel.from_points, GaussianModel.render]


def _doctests(obj) -> list[doctest.DocTest]:
    """The doctests of `obj` and of the members defined with it (methods, nested objects)."""
    finder = doctest.DocTestFinder(exclude_empty=True)
    module = inspect.getmodule(obj)
    return [t for t in finder.find(obj, module=module, globs={}) if t.examples]


@pytest.mark.parametrize("obj", FUNCTIONS + CLASSES, ids=lambda o: o.__qualname__)
def test_docstring_examples_run(obj):
    tests = _doctests(obj)
    assert tests, f"{obj.__qualname__} has no example in its docstrings"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    out = io.StringIO()
    for t in tests:
        runner.run(t, out=out.write)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, out.getvalue()


@pytest.mark.parametrize("obj", MUST_HAVE_EXAMPLE, ids=lambda o: o.__qualname__)
def test_key_objects_have_their_own_example(obj):
    parsed = doctest.DocTestParser().get_examples(inspect.getdoc(obj) or "")
    assert parsed, f"{obj.__qualname__}'s own docstring has no `>>>` example"


def _public_callables(cls) -> list[tuple[str, object]]:
    """(name, function) for every public method, classmethod and staticmethod of `cls`, inherited
    ones from the package included; properties as (name, property)."""
    out = []
    for name, raw in inspect.getmembers(cls):
        if name.startswith("_"):
            continue
        static = inspect.getattr_static(cls, name)
        if isinstance(static, property):
            out.append((name, static))
        elif isinstance(static, (classmethod, staticmethod)) or inspect.isfunction(raw):
            out.append((name, raw))
    return out


def _params(fn) -> list[str]:
    sig = inspect.signature(fn)
    return [p for p in sig.parameters if p not in ("self", "cls")]


def missing_params(fn, doc: str | None) -> list[str]:
    """Parameters of `fn` that its docstring does not name (as a whole word)."""
    doc = doc or ""
    return [p for p in _params(fn) if not re.search(rf"(?<![\w]){re.escape(p)}(?![\w])", doc)]


def _api_callables():
    items = [(f.__qualname__, f) for f in FUNCTIONS]
    for cls in CLASSES:
        for name, member in _public_callables(cls):
            items.append((f"{cls.__name__}.{name}", member))
    return items


@pytest.mark.parametrize("qualname,member", _api_callables(), ids=lambda x: x if isinstance(x, str) else "")
def test_every_public_callable_documents_each_parameter(qualname, member):
    if isinstance(member, property):
        assert (member.__doc__ or "").strip(), f"property {qualname} has no docstring"
        return
    doc = inspect.getdoc(member)
    assert doc and doc.strip(), f"{qualname} has no docstring"
    missing = missing_params(member, doc)
    assert not missing, f"{qualname}'s docstring does not name parameter(s) {missing}"


def test_constructor_parameters_are_documented():
    # A plain class documents its constructor in the class docstring.
    assert not missing_params(GaussianModel.__init__, inspect.getdoc(GaussianModel))
    # A dataclass result type documents every field.
    doc = inspect.getdoc(RasterOutput)
    missing = [f.name for f in dataclasses.fields(RasterOutput) if not re.search(rf"\b{f.name}\b", doc)]
    assert not missing, f"RasterOutput's docstring does not describe field(s) {missing}"


def test_every_strategy_setting_has_a_meaning():
    """DefaultStrategy's fields are settings: `methods show` prints the comment beside each."""
    from strings_bench.core.settings import dataclass_settings

    settings = dataclass_settings(DefaultStrategy)
    assert {s.name for s in settings} == {f.name for f in dataclasses.fields(DefaultStrategy)
                                          if f.metadata.get("setting", True)}  # its context is no setting
    assert [s.name for s in settings if not s.help] == []
