"""The package layout: no import cycles, counting imports inside functions too (docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "strings_bench"


def _modules() -> dict[str, Path]:
    out = {}
    for path in PKG.rglob("*.py"):
        parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def import_graph() -> dict[str, set[str]]:
    """module -> package modules it imports (anywhere in the file), resolved to the most specific module."""
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    name = ".".join(base + ([node.module] if node.module else []))
                else:
                    name = node.module or ""
                # `from pkg import sub` imports the submodule when there is one
                subs = [f"{name}.{a.name}" for a in node.names if f"{name}.{a.name}" in mods]
                targets = subs if subs and len(subs) == len(node.names) else [name, *subs]
            for t in targets:
                while t and t not in mods:  # an attribute path: its module
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    graph[mod].add(t)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_cycle_finder_finds_a_planted_cycle():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(g) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_graph_sees_imports_inside_functions():
    g = import_graph()
    # the runner imports the report writer inside a function
    assert "strings_bench.reports" in g["strings_bench.bench.runner"]


def test_no_import_cycles():
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_eval_depends_on_no_method_and_no_runner():
    """A metric must not depend on one method's package, nor on the runner that calls it (issue 26)."""
    g = import_graph()
    bad = sorted((m, t) for m, ts in g.items() if m.startswith("strings_bench.eval")
                 for t in ts if t.startswith(("strings_bench.methods", "strings_bench.bench")))
    assert not bad, "eval/ imports: " + ", ".join(f"{m} -> {t}" for m, t in bad)


def test_eval_layer_rule_can_fail():
    g = import_graph()
    g["strings_bench.eval.protocol"] = g["strings_bench.eval.protocol"] | {"strings_bench.methods.strings.method"}
    bad = [t for t in g["strings_bench.eval.protocol"] if t.startswith("strings_bench.methods")]
    assert bad  # the planted import is seen


# The layers of docs/architecture.md, top to bottom; one row's folders may import each other.
LAYERS = [["cli"], ["bench"], ["reports"], ["datasets"], ["methods"], ["engine"], ["eval", "raster", "scene"], ["core"]]


def _layer_of(module: str) -> int | None:
    parts = module.split(".")
    if len(parts) < 2:
        return None  # strings_bench itself, __main__
    for rank, row in enumerate(LAYERS):
        if parts[1] in row:
            return rank
    return None


def upward_imports(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    out = []
    for mod, targets in graph.items():
        lm = _layer_of(mod)
        for t in targets:
            lt = _layer_of(t)
            if lm is not None and lt is not None and lt < lm:
                out.append((mod, t))
    return sorted(out)


def test_every_folder_has_a_layer():
    folders = {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert folders == {f for row in LAYERS for f in row}


def test_folders_import_only_folders_below():
    # docs/architecture.md, "Arrows that run back up": core/method.py names scene.Scene for type checking only.
    allowed = {("strings_bench.core.method", "strings_bench.scene.scene")}
    bad = [e for e in upward_imports(import_graph()) if e not in allowed]
    assert not bad, "imports of a folder above: " + ", ".join(f"{m} -> {t}" for m, t in bad)


def test_upward_import_finder_finds_a_planted_one():
    g = {"strings_bench.core.io": {"strings_bench.bench.runner"}, "strings_bench.bench.runner": set()}
    assert upward_imports(g) == [("strings_bench.core.io", "strings_bench.bench.runner")]


SIZE_LIMIT = 450  # lines; a longer module says why in its docstring (issue 29)


def oversized_without_reason(modules: dict[str, Path]) -> list[str]:
    """Modules longer than SIZE_LIMIT whose docstring has no 'Size (~N lines): why' line."""
    found = []
    for name, path in modules.items():
        text = path.read_text()
        if len(text.splitlines()) <= SIZE_LIMIT:
            continue
        doc = ast.get_docstring(ast.parse(text)) or ""
        if not any(line.startswith("Size (~") and "):" in line for line in doc.splitlines()):
            found.append(name)
    return found


def test_long_modules_say_why_they_are_long():
    assert oversized_without_reason(_modules()) == []


def test_size_rule_can_fail(tmp_path):
    long_module = tmp_path / "long.py"
    long_module.write_text('"""A module."""\n' + "x = 1\n" * (SIZE_LIMIT + 1))
    assert oversized_without_reason({"long": long_module}) == ["long"]
    long_module.write_text('"""A module.\n\nSize (~450 lines): a reason.\n"""\n' + "x = 1\n" * (SIZE_LIMIT + 1))
    assert oversized_without_reason({"long": long_module}) == []


BENCHMARKS = PKG.parent / "benchmarks"


def private_imports(paths) -> list[str]:
    """`file:line name` for every import of a private name (a module or a name starting with '_', `__future__`
    aside) in `paths`: what a script needs from the package is public, written once there."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(Path(path).read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module != "__future__":
                parts = (node.module or "").split(".") + [a.name for a in node.names]
            elif isinstance(node, ast.Import):
                parts = [p for a in node.names for p in a.name.split(".")]
            else:
                continue
            bad = [p for p in parts if p.startswith("_") and p != "__init__"]
            if bad:
                found.append(f"{Path(path).name}:{node.lineno} {', '.join(bad)}")
    return found


def test_benchmarks_import_no_private_name():
    assert private_imports(sorted(BENCHMARKS.glob("*.py"))) == []


def test_private_import_rule_can_fail(tmp_path):
    script = tmp_path / "bench.py"
    script.write_text("from __future__ import annotations\nfrom strings_bench.scene.scene import _load_rgb\n"
                      "import strings_bench.raster._kernels\nfrom strings_bench.eval.protocol import to_uint8 as _u8\n")
    assert private_imports([script]) == ["bench.py:2 _load_rgb", "bench.py:3 _kernels"]
