"""The layout and docs rules: the lint step (`pytest tests/lint`), each rule stated once, here.

A rule is a property of how the code and the docs are written, checked on their text (mostly with `ast`) rather than
by running them. Each row: the rule, and the tests that hold it (this file unless named).

| #  | Rule | Tests |
|----|------|-------|
| 1  | No import cycles in strings_bench/, imports inside functions counted (docs/architecture.md). | test_no_import_cycles |
| 2  | Every folder of strings_bench/ has a layer, and imports only its own row or rows below: cli > bench > reports > store > datasets > methods > engine > eval, raster, scene > core (so eval/ imports no method and no runner; store/ neither bench, reports nor cli). One named exception: core/method.py names scene.Scene for type checking. | test_every_folder_has_a_layer, test_folders_import_only_folders_below |
| 3  | bench/ imports one name of reports/: the report writer. | test_bench_imports_only_the_report_writer_from_reports |
| 4  | The runner takes the plan's value types (its dataclasses) only; a method's build takes no schedule. | test_runner_imports_only_the_plans_value_types, test_method_build_takes_no_schedule |
| 5  | Job, CellConfig, RunPlan, MethodPlan and Budget are frozen and keyword-only, and no code builds one (or a CellRecord) with a positional argument. | test_job_and_cell_config_are_keyword_only_and_frozen, test_no_positional_construction_of_a_job_or_a_cell |
| 6  | No private name crosses a module boundary: the package imports no other module's `_name` (a private module only from its own package); tools/ and studies/ import no `_name` of the package at all. | test_no_private_imports_across_modules, test_tools_and_studies_import_no_private_name |
| 7  | Nothing in the package, tools/, studies/ or scripts/ edits sys.path. | test_no_sys_path_edits_in_the_package_tools_studies_and_scripts |
| 8  | Every file of tools/, studies/ (and each study's folder) and scripts/ is named in its folder's README.md. | test_every_script_is_in_its_folders_readme |
| 9  | The module size limit: a module over SIZE_LIMIT (450) lines says why in a docstring line `Size (~N lines): why`. | test_long_modules_say_why_they_are_long |
| 10 | Nothing the scene build computes (datasets/, scene/, eval/ocr/, eval/text_masks.py) goes through BLAS; core/vec3.py sums in a written order. | test_nothing_the_scene_build_computes_goes_through_blas |
| 11 | No work-log words (issue numbers, pointers outside the repository, "session", "the lead", ...) where users read: the docs, CHANGELOG.md, --help, the code's docstrings, comments and strings, the reports' captions. | test_docs_rules.py: test_no_worklog_words_in_docs, _in_help, _in_code, _in_report_strings |
| 12 | The README and the user guide hold the user's task only: no dates, commit hashes, load figures or the project's own run folders. | test_docs_rules.py: test_no_history_in_the_guide |
| 13 | Links resolve: every relative link of README.md, CHANGELOG.md and docs/ names a file, README's anchors name a heading, and docs/README.md links every guide and design page. | test_docs_rules.py: test_relative_links_resolve, test_readme_links_resolve_with_their_anchors, test_index_links_every_page |
| 14 | Every docs/ file that the code, the scripts or the docs name exists. | test_docs_rules.py: test_doc_paths_named_in_code_and_docs_exist |
| 15 | Figures are generated, never typed: README and the results pages hold no table of figures outside a generated block; a figure stated in several places has one source (the default run's time: DEFAULT_RUN_TIME, held to its measurement; the counts of methods and scenes: the registries). | test_docs_rules.py: test_results_tables_are_all_generated, test_default_run_time_is_its_measurement, test_default_run_time_is_stated_from_its_one_source, test_counts_of_methods_and_scenes_are_the_registries |
| 16 | The public API's docstrings are contracts: their examples run, the key objects carry their own example, every public callable names each parameter, constructors and result fields are described, every strategy setting has a meaning. | test_docstrings.py |
"""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "strings_bench"


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


def test_no_import_cycles():
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


# The layers of docs/architecture.md, top to bottom; one row's folders may import each other.
LAYERS = [["cli"], ["bench"], ["reports"], ["store"], ["datasets"], ["methods"], ["engine"], ["eval", "raster", "scene"],
          ["core"]]


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


TOOLS = PKG.parent / "tools"
STUDIES = PKG.parent / "studies"


def tool_and_study_scripts() -> list[Path]:
    """The tools (tools/*.py) and the studies' scripts (studies/NAME/*.py)."""
    return sorted([*TOOLS.glob("*.py"), *STUDIES.glob("*/*.py")])


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


def test_tools_and_studies_import_no_private_name():
    assert private_imports(tool_and_study_scripts()) == []


# ---- the run's parameters, the run folder and the scripts ----------------------------------------------------
def _imports_of(path: Path) -> list[tuple[int, str, list[str]]]:
    """(line, module, names) of every import in `path`, anywhere in the file; relative imports resolved against
    the package the file is in (`import a.b` gives module "a.b" and no names)."""
    mod = ".".join(path.relative_to(PKG.parent).with_suffix("").parts) if PKG in path.parents else path.stem
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            name = node.module or ""
            if node.level:
                base = mod.split(".")[: -node.level] if path.name != "__init__.py" else mod.split(".")[: len(mod.split(".")) - node.level]
                name = ".".join(base + ([node.module] if node.module else []))
            out.append((node.lineno, name, [a.name for a in node.names]))
    return out


def reports_imports_of_bench(root: Path = PKG) -> list[str]:
    """`file:line module names` for every import of reports/ in bench/."""
    return [f"{p.name}:{line} {m} {','.join(names)}" for p in sorted((root / "bench").glob("*.py"))
            for line, m, names in _imports_of(p) if m == "strings_bench.reports" or m.startswith("strings_bench.reports.")]


def test_bench_imports_only_the_report_writer_from_reports():
    found = reports_imports_of_bench()
    assert len(found) == 1 and found[0].startswith("records.py:") and found[0].endswith(
        "strings_bench.reports write_report"), found


def cross_module_private_imports(paths) -> list[str]:
    """`file:line name` for every private name (starting with '_') imported from another module of the package; a
    private module (`eval/ocr/_ort_guard.py`) may be imported from inside its own package only, and a package's
    `__init__.py` may import its own modules' private names."""
    found = []
    for path in paths:
        path = Path(path)
        here = ".".join(path.relative_to(PKG.parent).with_suffix("").parts[:-1]) if PKG in path.parents else ""
        for line, module, names in _imports_of(path):
            parts = module.split(".")
            for i, part in enumerate(parts):
                if part.startswith("_") and part not in ("__init__", "__future__") and ".".join(parts[:i]) != here:
                    found.append(f"{path.name}:{line} {part}")
            if module not in ("__future__", here):  # the package's own private names are its own
                found += [f"{path.name}:{line} {n}" for n in names if n.startswith("_") and n != "__version__"]
    return found


def test_no_private_imports_across_modules():
    assert cross_module_private_imports(sorted(PKG.rglob("*.py"))) == []


def sys_path_edits(paths) -> list[str]:
    """`file:line` for every change of sys.path (a call of its methods, an assignment to it) in `paths`."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(Path(path).read_text(encoding="utf-8"))):
            target = None
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                target = node.func.value
            elif isinstance(node, (ast.Assign, ast.AugAssign)):
                target = node.targets[0] if isinstance(node, ast.Assign) else node.target
            if (isinstance(target, ast.Attribute) and target.attr == "path" and isinstance(target.value, ast.Name)
                    and target.value.id == "sys"):
                found.append((Path(path).name, node.lineno))
    return [f"{name}:{line}" for name, line in sorted(found)]


def test_no_sys_path_edits_in_the_package_tools_studies_and_scripts():
    root = PKG.parent
    paths = sorted([*PKG.rglob("*.py"), *tool_and_study_scripts(), *(root / "scripts").glob("*.py")])
    assert sys_path_edits(paths) == []


def unlisted_scripts(folder: Path) -> list[str]:
    """The files and folders of `folder` (its README and `__pycache__` aside) that its README.md does not name as
    `NAME` (a folder as `NAME/`)."""
    readme = (folder / "README.md").read_text(encoding="utf-8")
    return sorted(p.name for p in folder.iterdir()
                  if p.name not in ("README.md", "__pycache__") and f"`{p.name}{'/' * p.is_dir()}`" not in readme)


def test_every_script_is_in_its_folders_readme():
    root = PKG.parent
    assert unlisted_scripts(root / "tools") == []
    assert unlisted_scripts(root / "studies") == []
    for study in sorted(p for p in (root / "studies").iterdir() if p.is_dir()):
        assert unlisted_scripts(study) == [], study.name
    assert unlisted_scripts(root / "scripts") == []


def value_types_only(importer: Path, source: Path, module: str) -> list[str]:
    """The names `importer` imports from `module` (the file `source`) that are not dataclasses defined there."""
    defined = {n.name for n in ast.parse(source.read_text(encoding="utf-8")).body if isinstance(n, ast.ClassDef)
               and any("dataclass" in ast.unparse(d) for d in n.decorator_list)}
    return sorted(n for _, m, names in _imports_of(importer) if m == module for n in names if n not in defined)


def test_runner_imports_only_the_plans_value_types():
    assert value_types_only(PKG / "bench" / "runner.py", PKG / "bench" / "plan.py", "strings_bench.bench.plan") == []
    # and nothing of the plan module as a whole
    assert not any(m == "strings_bench.bench.plan" and not names for _, m, names in _imports_of(PKG / "bench" / "runner.py"))


def test_method_build_takes_no_schedule():
    import inspect

    from strings_bench.methods.registry import MethodSpec

    assert "schedule" not in inspect.signature(MethodSpec.build).parameters


def test_job_and_cell_config_are_keyword_only_and_frozen():
    import dataclasses

    from strings_bench.bench.executors import Job
    from strings_bench.store import CellConfig
    from strings_bench.bench.budget import Budget
    from strings_bench.bench.plan import MethodPlan, RunPlan

    for cls in (Job, CellConfig, RunPlan, MethodPlan, Budget):
        assert cls.__dataclass_params__.frozen, cls
        with __import__("pytest").raises(TypeError):
            cls("positional")
        assert all(f.kw_only for f in dataclasses.fields(cls))


def positional_constructions(paths, names=("Job", "CellConfig", "CellRecord", "RunPlan", "MethodPlan", "Budget")) -> list[str]:
    """`file:line` for every call of one of `names` with a positional argument."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(Path(path).read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in names
                    and node.args):
                found.append(f"{Path(path).name}:{node.lineno}")
    return found


def test_no_positional_construction_of_a_job_or_a_cell():
    root = PKG.parent
    paths = sorted([*PKG.rglob("*.py"), *tool_and_study_scripts(), *(root / "tests").rglob("*.py")])
    assert positional_constructions([p for p in paths if p.name != "test_rules.py"]) == []


# ---- the scene build's arithmetic ------------------------------------------------------------------------------
# The modules whose results reach a scene's files (pixels, masks, cameras, points, split, annotations): the
# dataset builders, the scene model, the OCR that makes a prepared scene's masks. BLAS (numpy's @, dot, einsum,
# matmul, linalg) rounds by the CPU model's kernels there; core/vec3.py does the same sums in a written order.
SCENE_BUILD = ("datasets", "scene", "eval/ocr", "eval/text_masks.py")
BLAS_CALLS = {"dot", "einsum", "matmul", "tensordot", "inner", "vdot"}


def blas_calls(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult):
            found.append(f"{path}:{node.lineno}: @")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            f = node.func
            if f.attr in BLAS_CALLS and not (isinstance(f.value, ast.Name) and f.value.id == "vec3"):
                found.append(f"{path}:{node.lineno}: .{f.attr}()")
            elif isinstance(f.value, ast.Attribute) and f.value.attr == "linalg":
                found.append(f"{path}:{node.lineno}: linalg.{f.attr}()")
    return found


def test_nothing_the_scene_build_computes_goes_through_blas():
    files = [p for part in SCENE_BUILD for p in ((PKG / part).rglob("*.py") if (PKG / part).is_dir()
                                                  else [PKG / part])]
    assert len(files) > 20
    found = [hit for p in files for hit in blas_calls(p)]
    assert not found, "use strings_bench.core.vec3 (written-order sums) instead: " + "; ".join(found)
