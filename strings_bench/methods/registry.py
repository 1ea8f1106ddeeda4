"""The registry of method specs: the built-in ones, found beside their methods, and plug-ins.

Each built-in method's spec lives beside its code (nerfbaselines style): `methods/<name>_spec.py` defines `SPEC`,
a package's `spec.py` defines `SPECS` (STRinGS and its ablations). `BUILTIN_SPEC_MODULES` lists them in the paper's
row order (Table 1), the order the reports list methods in: registration is explicit, never an import side
effect. A user's package adds more through the entry-point group `strings_bench.methods`, whose entries point at
a MethodSpec (or a callable returning one). The spec machinery itself is methods/spec.py.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
from importlib.metadata import entry_points

from strings_bench.core.errors import StringsBenchError
from strings_bench.methods.spec import MethodSpec, PaperFigures

__all__ = ["BUILTIN_SPEC_MODULES", "MethodSpec", "PaperFigures", "builtin_specs", "get_method", "list_methods",
           "register_method", "registered", "show_method"]

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "strings_bench.methods"

# In the paper's row order (Table 1), then the newer methods, STRinGS and its variants, the adapters.
BUILTIN_SPEC_MODULES = (
    "strings_bench.methods.gs3d_spec",
    "strings_bench.methods.mip_splatting_spec",
    "strings_bench.methods.mcmc_spec",
    "strings_bench.methods.absgs_spec",
    "strings_bench.methods.edc_absgs_spec",
    "strings_bench.methods.improved_gs_spec",
    "strings_bench.methods.perceptual_gs_spec",
    "strings_bench.methods.strings.spec",
    "strings_bench.methods.ply_adapter_spec",
    "strings_bench.methods.external_spec",
)


def builtin_specs() -> list[MethodSpec]:
    """The built-in specs, module by module in `BUILTIN_SPEC_MODULES` order (a module's `SPEC`, or its `SPECS`)."""
    out: list[MethodSpec] = []
    for name in BUILTIN_SPEC_MODULES:
        module = importlib.import_module(name)
        out.extend(getattr(module, "SPECS", None) or [module.SPEC])
    return out


_METHODS: dict[str, MethodSpec] = {}
_loaded = False


def register_method(spec: MethodSpec) -> MethodSpec:
    """Make `spec` a method of this process (`run`, `methods list`) under its name, replacing one of that name.

    A method in a package of your own needs no call: the `strings_bench.methods` entry point of its pyproject.toml
    registers it in every process. For the duration of a block only: `registered(spec)`.

    Returns:
        `spec` (so that it can be used as `SPEC = register_method(MethodSpec(...))`).
    """
    _METHODS[spec.name] = spec
    return spec


@contextlib.contextmanager
def registered(spec: MethodSpec):
    """`spec` registered under its name for the duration (e.g. `methods check` of a spec not registered),
    then whatever was registered under that name before."""
    _load()
    previous = _METHODS.get(spec.name)
    register_method(spec)
    try:
        yield spec
    finally:
        if previous is None:
            _METHODS.pop(spec.name, None)
        else:
            _METHODS[spec.name] = previous


def _load() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for spec in builtin_specs():
        register_method(spec)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
            spec = obj() if callable(obj) and not isinstance(obj, MethodSpec) else obj
            if not isinstance(spec, MethodSpec):
                raise TypeError(f"entry point {ep.name} gave {type(spec).__name__}, not MethodSpec")
            register_method(spec)
        except Exception as exc:  # a broken plug-in must not break the suite
            log.warning("could not load method plug-in %s: %s", ep.name, exc)


def list_methods() -> list[MethodSpec]:
    _load()
    return list(_METHODS.values())


def get_method(name: str) -> MethodSpec:
    _load()
    if name not in _METHODS:
        raise StringsBenchError(f"unknown method {name!r}", hint=f"known methods: {', '.join(sorted(_METHODS))}")
    return _METHODS[name]


def show_method(name: str) -> str:
    """What `strings-bench methods show NAME` prints: every setting with its default and meaning."""
    return get_method(name).show()
