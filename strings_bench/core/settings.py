"""Settings described as data: every setting of a method with its default and its meaning.

A setting's meaning is the comment beside its dataclass field (`name: type = default  # meaning`),
so the code and `strings-bench methods show` say the same thing.
"""

from __future__ import annotations

import dataclasses
import inspect
import io
import tokenize
from dataclasses import dataclass
from functools import lru_cache
from typing import Any


@dataclass(frozen=True)
class Setting:
    name: str
    default: Any
    help: str = ""
    group: str = ""  # where it goes: "training", "learning rate", "strategy", the method's name, ...


@lru_cache(maxsize=None)
def _comments(cls: type) -> dict[str, str]:
    """Field name -> trailing comment, from the source of `cls` and its dataclass bases."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass) or klass is object:
            continue
        try:
            src = inspect.getsource(klass)
        except (OSError, TypeError):
            continue
        names = {f.name for f in dataclasses.fields(klass)}
        line_field: dict[int, str] = {}
        for tok in tokenize.generate_tokens(io.StringIO(src).readline):
            if tok.type == tokenize.NAME and tok.string in names and tok.start[1] == 4 and tok.start[0] not in line_field:
                line_field[tok.start[0]] = tok.string
            elif tok.type == tokenize.COMMENT and tok.start[0] in line_field:
                out[line_field[tok.start[0]]] = tok.string.lstrip("#").strip()
    return out


def dataclass_settings(cls: type, group: str = "", prefix: str = "", skip: tuple[str, ...] = ()) -> list[Setting]:
    """One Setting per field of dataclass `cls` (default from the class, meaning from its comment)."""
    docs = _comments(cls)
    out = []
    for f in dataclasses.fields(cls):
        if f.name in skip or f.name.startswith("_") or not f.metadata.get("setting", True):
            continue  # metadata {"setting": False}: a field that is no setting (a strategy's context)
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
            default = f.default_factory()  # type: ignore[misc]
        else:
            default = None
        out.append(Setting(prefix + f.name, default, docs.get(f.name, ""), group))
    return out


def format_settings(settings: list[Setting], overrides: dict | None = None) -> str:
    """A table: name, default (or the method's own default), meaning."""
    overrides = overrides or {}
    rows = [(s.name, repr(overrides.get(s.name, s.default)), s.help) for s in settings]
    w0 = max([len(r[0]) for r in rows] + [4])
    w1 = min(max([len(r[1]) for r in rows] + [7]), 24)
    lines = []
    group = None
    for s, (name, default, help_) in zip(settings, rows):
        if s.group != group:
            group = s.group
            lines.append(f"\n[{group}]" if lines else f"[{group}]")
        lines.append(f"  {name:<{w0}}  {default:<{w1}}  {help_}".rstrip())
    return "\n".join(lines)
