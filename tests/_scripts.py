"""Test-local helpers: a tool of tools/ (a package at the repository's root) or a study's script of studies/NAME/
(a script, not a package) loaded as a module."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def load_tool(name: str):
    """tools/NAME.py as `tools.NAME`, imported as `python -m tools.NAME` imports it (the repository's root on the
    path: a tool may import another as `tools.OTHER`)."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    return importlib.import_module(f"tools.{name}")


def load_study(name: str):
    """studies/NAME/NAME.py as a module of its own (`_study_NAME`)."""
    spec = importlib.util.spec_from_file_location(f"_study_{name}", REPO / "studies" / name / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # as an import would: dataclasses look their module up there
    spec.loader.exec_module(module)
    return module
