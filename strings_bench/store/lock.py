"""One run at a time in a run folder.

A run trains each unfinished cell and saves its training state in the folder; two runs given the same `--out`
at once would train the same cells twice and overwrite each other's states. `run_folder_lock` holds an exclusive
lock on RUN_DIR/.run.lock while a run writes there, so the second run stops at once with an error that names the
first; `run_folder_busy` tells another process (e.g. tools/captures_cells.py) whether a run holds it.

The lock is the operating system's (flock): it ends with the process that holds it, however that process ends
(kill -9 included), so a killed run never leaves a folder locked. The file itself stays (removing it would race
with a run opening it); it records which process last held the lock, for the error message. Where flock is not
available (Windows, or a file system that refuses it, with a warning) runs are not locked.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from strings_bench.core.errors import StringsBenchError

try:
    import fcntl
except ImportError:  # Windows: no flock; runs are not locked there
    fcntl = None

LOCK_FILE = ".run.lock"
log = logging.getLogger(__name__)


def _holder(path: Path) -> str:
    """What the lock file says of the process that holds it ("" when it says nothing readable)."""
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
        return f" (process {int(info['pid'])} on {info['host']}, since {info['since']})"
    except Exception:  # noqa: BLE001 - written by a run that has not finished writing it, or by hand
        return ""


@contextmanager
def run_folder_lock(run_dir: str | os.PathLike) -> Iterator[Path]:
    """Hold RUN_DIR's lock for the `with` block; a `StringsBenchError` naming the holder if another run holds it."""
    run_dir = Path(run_dir)
    path = run_dir / LOCK_FILE
    if fcntl is None:
        yield path
        return
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise StringsBenchError(
                f"run folder {run_dir} is in use by another run{_holder(path)}",
                hint="wait until that run ends (then run again: it resumes where the folder stands), or give "
                     "another --out") from None
        except OSError as exc:  # a file system without flock (some cluster mounts): run, unlocked
            log.warning("run folder %s cannot be locked (%s): nothing stops a second run in it at the same time",
                        run_dir, exc)
            yield path
            return
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                 "since": time.strftime("%Y-%m-%dT%H:%M:%S")}).encode())
        yield path
    finally:
        os.close(fd)  # closing the descriptor releases the lock


def run_folder_busy(run_dir: str | os.PathLike) -> bool:
    """Whether a run holds RUN_DIR's lock now (False where runs are not locked)."""
    path = Path(run_dir) / LOCK_FILE
    if fcntl is None or not path.is_file():
        return False
    fd = os.open(path, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        except OSError:  # a file system without flock: runs there are not locked
            return False
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    finally:
        os.close(fd)
