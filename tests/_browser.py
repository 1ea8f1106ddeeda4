"""The Chromium the browser tests drive (the docs site, the report page): STRINGS_BENCH_CHROMIUM, else Debian's."""

from __future__ import annotations

import os
import shutil
from pathlib import Path


def find_chromium() -> str | None:
    """The path of a Chromium executable, None when there is none (the browser tests then skip)."""
    for c in (os.environ.get("STRINGS_BENCH_CHROMIUM"), "/usr/bin/chromium", shutil.which("chromium"),
              shutil.which("chromium-browser")):
        if c and Path(c).is_file():
            return c
    return None
