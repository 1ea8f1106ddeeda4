"""Method specs with presets, in the style of nerfbaselines.

Built-in methods register themselves when their module is imported (see BUILTIN_MODULES). A
user's package registers more through the entry-point group `strings_bench.methods`, whose
entries point at a MethodSpec object (or a callable returning one).
"""

from __future__ import annotations

import importlib
import logging
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Callable

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.method import MethodAdapter

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "strings_bench.methods"

# One module per method; each calls register_method() at import.
BUILTIN_MODULES: list[str] = [
    "strings_bench.methods.gs3d",
    "strings_bench.methods.strings.method",
    "strings_bench.methods.absgs",
    "strings_bench.methods.edc_absgs",
    "strings_bench.methods.mip_splatting",
    "strings_bench.methods.mcmc",
    "strings_bench.methods.ply_adapter",
    "strings_bench.methods.external",
]


@dataclass
class MethodSpec:
    name: str
    factory: Callable[..., MethodAdapter]  # called with the merged settings
    description: str = ""
    paper: str = ""
    defaults: dict = field(default_factory=dict)
    presets: dict[str, dict] = field(default_factory=dict)  # preset name -> settings overriding defaults

    def build(self, preset: str | None = None, **overrides) -> MethodAdapter:
        settings = dict(self.defaults)
        if preset is not None:
            if preset not in self.presets:
                raise StringsBenchError(f"method {self.name} has no preset {preset!r}",
                                        hint=f"presets: {', '.join(self.presets) or 'none'}")
            settings.update(self.presets[preset])
        settings.update(overrides)
        return self.factory(**settings)


_METHODS: dict[str, MethodSpec] = {}
_loaded = False


def register_method(spec: MethodSpec) -> MethodSpec:
    _METHODS[spec.name] = spec
    return spec


def _load() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for mod in BUILTIN_MODULES:
        importlib.import_module(mod)
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
