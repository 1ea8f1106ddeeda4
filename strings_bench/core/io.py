"""Atomic file writes and content hashing: finished results are never half-written."""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import re
import shutil
import socket
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable

log = logging.getLogger(__name__)


def writer_tag() -> str:
    """`<host hash>-<pid>`: names the process that owns a temporary file or folder, so that a later
    run can tell the leftovers of a killed process (`sweep_stale_temps`) from those of a live one."""
    host = hashlib.sha256(socket.gethostname().encode()).hexdigest()[:6]
    return f"{host}-{os.getpid()}"


# A temporary file of atomic_write: .<name>.~<host>-<pid>.<random>.tmp
_TEMP_FILE = re.compile(r"^\..+\.~(?P<host>[0-9a-f]{6})-(?P<pid>\d+)\.[^.]+\.tmp$")
# A temporary folder of a scene build (datasets/synthetic): .build-<scene>-~<host>-<pid>-<random>
_TEMP_DIR = re.compile(r"^\.build-.+-~(?P<host>[0-9a-f]{6})-(?P<pid>\d+)-[0-9a-f]+$")


def _owner_is_gone(host: str, pid: int) -> bool:
    """True when the process that made a temporary entry ran on this host and is no longer alive. An entry
    of another host is never judged (its process may be alive there: a shared run folder)."""
    if host != writer_tag().split("-")[0]:
        return False
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False  # alive, another user's
    return False


def sweep_stale_temps(folder: str | os.PathLike, skip: Iterable[str] = ()) -> list[Path]:
    """Remove the temporary files (atomic_write) and build folders that killed processes of this host left
    under `folder` (kill -9, power loss of the process, OOM killer); returns what was removed. Entries of live
    processes and of other hosts are left alone. `skip` names top-level subfolders not to walk."""
    folder = Path(folder)
    removed: list[Path] = []
    if not folder.is_dir():
        return removed
    skip = set(skip)
    for root, dirs, files in os.walk(folder):
        if Path(root) == folder:
            dirs[:] = [d for d in dirs if d not in skip]
        for d in list(dirs):
            m = _TEMP_DIR.match(d)
            if m and _owner_is_gone(m["host"], int(m["pid"])):
                shutil.rmtree(Path(root) / d, ignore_errors=True)
                removed.append(Path(root) / d)
                dirs.remove(d)
        for f in files:
            m = _TEMP_FILE.match(f)
            if m and _owner_is_gone(m["host"], int(m["pid"])):
                (Path(root) / f).unlink(missing_ok=True)
                removed.append(Path(root) / f)
    if removed:
        log.info("removed %d temporary file(s) left by killed runs under %s", len(removed), folder)
    return removed

# mkstemp makes 0600 files; results are shared with co-authors, so finished files get the mode a
# plain open() would give (0666 less the umask). Read once: os.umask can only be read by setting it.
_UMASK = os.umask(0)
os.umask(_UMASK)


def atomic_write(path: str | os.PathLike, write: Callable[[Path], None]) -> Path:
    """Call `write(tmp_path)` then rename the temporary file onto `path`.

    The rename is atomic on POSIX, so readers see either the old file or the complete new one. The
    temporary file's name carries the writer's host and pid: a process killed between the two leaves it
    behind, and `sweep_stale_temps` removes it later. The data is flushed to disk (fsync) before the
    rename and the folder after it, so that a machine that crashes or loses power does not keep the
    new name with empty contents (ext4 and XFS may otherwise; ~0.4 ms a write, measured on ext4).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.~{writer_tag()}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        write(tmp_path)
        os.chmod(tmp_path, 0o666 & ~_UMASK)
        _fsync_path(tmp_path, os.O_RDONLY)
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    _fsync_path(path.parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    return path


def _fsync_path(path: Path, flags: int) -> None:
    """fsync a file or folder by path; filesystems that cannot sync folders (some network ones) are let be."""
    try:
        fd = os.open(path, flags)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    return atomic_write(path, lambda p: p.write_bytes(data))


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def _nan_to_none(x):
    if isinstance(x, float) and (math.isnan(x) or math.isinf(x)):
        return None if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def jsonable(obj):
    """`obj` in the form result.json and run.json store: numpy values as Python numbers, tuples as lists, NaN as
    null and the infinities as "inf" / "-inf" (JSON has neither)."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.floating,)):
        return _nan_to_none(float(obj))
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, float):
        return _nan_to_none(obj)
    return obj


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def cache_root() -> Path:
    """Folder for every cache the suite writes (scenes, masks, OCR results, compiled kernels).

    Set STRINGS_BENCH_CACHE to move it; the default is ~/.cache/strings-bench.
    """
    env = os.environ.get("STRINGS_BENCH_CACHE")
    if env:
        root = Path(env)
    else:
        root = Path.home() / ".cache" / "strings-bench"
    root.mkdir(parents=True, exist_ok=True)
    return root
