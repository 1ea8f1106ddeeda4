"""Whether progress bars are shown, as one switch for a whole command.

`strings-bench run --no-progress` turns the bars off; some are drawn far below the command, where a scene is built
on first use behind a dataset card's `locate(scene)` (whose signature users' own cards share). The command sets the
switch around that work (`progress_bars(False)`), and the builders read it (`progress_shown()`).
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator

_SHOWN: contextvars.ContextVar[bool] = contextvars.ContextVar("strings_bench_progress_shown", default=True)


def progress_shown() -> bool:
    """True unless the command running now turned progress bars off."""
    return _SHOWN.get()


@contextlib.contextmanager
def progress_bars(shown: bool) -> Iterator[None]:
    """Show (True) or hide (False) progress bars inside the block; the setting before it comes back after."""
    token = _SHOWN.set(bool(shown))
    try:
        yield
    finally:
        _SHOWN.reset(token)
