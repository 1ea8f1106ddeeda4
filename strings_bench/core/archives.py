"""Unpacking zip and tar archives safely: the one reader for every archive the suite opens (dataset
downloads, datasets/download.py; `strings-bench evaluate` on a .zip or .tar.gz, bench/predictions.py).

- Every member is checked before anything is written: absolute paths, drive letters, `..` components,
  links (symbolic and hard), device files and fifos are refused.
- Size: at most `extract_limit` bytes are written. An archive whose headers already declare more is
  refused before anything is written; the bytes are also counted as they are written (headers can lie),
  and the write that would pass the limit is not made.
- Extraction goes into a temporary folder beside the target that is renamed onto it at the end; on any
  error everything written is removed and the target does not appear.
"""

from __future__ import annotations

import errno
import lzma
import os
import shutil
import stat
import tarfile
import tempfile
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Callable

from tqdm import tqdm

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import writer_tag

CHUNK = 1 << 20
EXTRACT_LIMIT_ENV = "STRINGS_BENCH_MAX_EXTRACT_BYTES"
MIN_EXTRACT_LIMIT = 1 << 30  # 1 GiB
EXTRACT_RATIO_LIMIT = 100  # photos, renders and COLMAP models compress far less than 100:1; a zip bomb far more


class ArchiveError(StringsBenchError):
    """An archive cannot be extracted: it is damaged, not a zip or tar, or larger than the limit."""


class UnsafeArchiveError(ArchiveError):
    """An archive member would land outside the target folder, is a link or special file, or the archive
    expands past the extraction limit."""


@dataclass(frozen=True)
class ExtractLimit:
    bytes: int
    source: str  # "caller" (e.g. a dataset card's download.max_bytes), "env", or "default"

    def hint(self) -> str:
        if self.source == "caller":
            return (f"the limit of {self.bytes} bytes is set for this archive (a dataset card's download.max_bytes); "
                    f"if the archive is genuine, the card needs a larger value")
        return (f"if the archive is genuine, raise the limit with the environment variable {EXTRACT_LIMIT_ENV}=BYTES "
                f"(e.g. {EXTRACT_LIMIT_ENV}=20e9)")


def extract_limit(archive: str | Path, max_bytes: int | None = None) -> ExtractLimit:
    """Bytes an archive may expand to: `max_bytes` (a card's `download.max_bytes`), else the environment's
    STRINGS_BENCH_MAX_EXTRACT_BYTES, else 100 x the archive's size (at least 1 GiB)."""
    if max_bytes is not None:
        return ExtractLimit(int(max_bytes), "caller")
    env = os.environ.get(EXTRACT_LIMIT_ENV, "").strip()
    if env:
        try:
            value = int(float(env))
        except ValueError:
            value = -1
        if value < 0:
            raise ArchiveError(f"{EXTRACT_LIMIT_ENV}={env!r} is not a number of bytes", hint="e.g. 200e9") from None
        return ExtractLimit(value, "env")
    return ExtractLimit(max(MIN_EXTRACT_LIMIT, EXTRACT_RATIO_LIMIT * Path(archive).stat().st_size), "default")


def _gib(n: int) -> str:
    return f"{n / (1 << 30):.3g} GiB" if n >= 1 << 30 else f"{n / (1 << 20):.3g} MiB"


@dataclass
class _Member:
    """An archive member as extraction sees it, zip or tar alike."""

    name: str
    is_dir: bool
    size: int  # declared bytes (0 for a folder)
    open: Callable  # () -> a readable file object of its bytes
    refused: str = ""  # why it is not extracted (a link, a special file); "" when it is


def _member_parts(name: str, archive: Path) -> tuple[str, ...]:
    """The member's path inside the target as parts; refuses one that would land outside it."""
    norm = name.replace("\\", "/")
    why = ("an absolute path" if norm.startswith("/") else
           "a drive letter" if len(norm) > 1 and norm[1] == ":" else
           "'..' climbs out of the folder" if ".." in PurePosixPath(norm).parts else "")
    if why:
        raise UnsafeArchiveError(f"archive {archive} holds {name!r}, a path outside the archive ({why})",
                                 hint="refused: extracting it would write outside the folder; get the archive from "
                                      "its source again, or repack it with relative paths")
    return PurePosixPath(norm).parts


def _zip_members(zf: zipfile.ZipFile) -> list[_Member]:
    out = []
    for info in zf.infolist():
        # Unix zips keep st_mode in the high 16 bits; many writers leave the file-type bits at 0.
        file_type = stat.S_IFMT(info.external_attr >> 16)
        refused = ("a symbolic link" if file_type == stat.S_IFLNK else
                   "a special file" if file_type not in (0, stat.S_IFREG, stat.S_IFDIR) else "")
        out.append(_Member(info.filename, info.is_dir(), 0 if info.is_dir() else info.file_size,
                           lambda info=info: zf.open(info), refused))
    return out


def _tar_members(tf: tarfile.TarFile) -> list[_Member]:
    out = []
    for m in tf.getmembers():
        refused = (f"a symbolic link to {m.linkname!r}" if m.issym() else
                   f"a hard link to {m.linkname!r}" if m.islnk() else
                   "a special file (device or fifo)" if not (m.isfile() or m.isdir()) else "")
        out.append(_Member(m.name, m.isdir(), m.size if m.isfile() else 0, lambda m=m: tf.extractfile(m), refused))
    return out


class _Budget:
    """Counts the bytes actually written and stops before the write that would pass the limit."""

    def __init__(self, archive: Path, limit: ExtractLimit):
        self.archive, self.limit, self.used = archive, limit, 0

    def refuse(self, amount: str) -> UnsafeArchiveError:
        return UnsafeArchiveError(
            f"archive {self.archive} expands to {amount}, over the extraction limit of {self.limit.bytes} bytes "
            f"({_gib(self.limit.bytes)}): a zip bomb, or more data than expected; extraction stopped and nothing "
            f"was kept", hint=self.limit.hint())

    def copy(self, src, dst) -> None:
        while block := src.read(CHUNK):
            if self.used + len(block) > self.limit.bytes:
                raise self.refuse(f"more than {self.limit.bytes} bytes")
            self.used += len(block)
            dst.write(block)


def _extract_members(members: list[_Member], declared_by: str, archive: Path, tmp: Path, budget: _Budget,
                     progress: bool) -> None:
    """Check every member (a path inside the folder, no link, no special file, the declared total within the
    budget) before writing anything, then write them under `tmp`, counting the bytes actually written."""
    refused = [m for m in members if m.refused]
    for m in members:
        _member_parts(m.name, archive)
    if refused:
        listed = ", ".join(f"{m.name!r} ({m.refused})" for m in refused[:3])
        raise UnsafeArchiveError(
            f"archive {archive} holds links or special files: {listed}"
            + (f" and {len(refused) - 3} more" if len(refused) > 3 else ""),
            hint="refused: only plain files and folders are extracted; repack the archive without links")
    declared = sum(m.size for m in members)
    if declared > budget.limit.bytes:
        raise budget.refuse(f"{declared} bytes ({_gib(declared)}, {declared_by})")
    for m in tqdm(members, desc=f"extract {archive.name}", unit="file", disable=not progress):
        out = tmp.joinpath(*_member_parts(m.name, archive))
        if m.is_dir:
            out.mkdir(parents=True, exist_ok=True)
            continue
        out.parent.mkdir(parents=True, exist_ok=True)
        with m.open() as src, open(out, "wb") as dst:
            budget.copy(src, dst)


def _discard(folder: Path) -> None:
    """Remove a partial extraction (a seam for tests that measure what was written before a refusal)."""
    shutil.rmtree(folder, ignore_errors=True)


def safe_extract(archive: str | Path, target: str | Path, progress: bool = True,
                 max_bytes: int | None = None) -> Path:
    """Extract a .zip or .tar(.gz/.bz2/.xz) into `target` (which must not exist yet), writing at most
    `extract_limit(archive, max_bytes)` bytes; returns `target`. Raises UnsafeArchiveError (unsafe member,
    over the limit) or ArchiveError (damaged, not an archive), having kept nothing."""
    archive, target = Path(archive), Path(target)
    if target.exists():
        raise ArchiveError(f"{target} already exists", hint="delete it or choose another folder")
    budget = _Budget(archive, extract_limit(archive, max_bytes))
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.~{writer_tag()}-", suffix=".extract-tmp",
                                dir=target.parent))
    try:
        if zipfile.is_zipfile(archive):
            with zipfile.ZipFile(archive) as zf:
                _extract_members(_zip_members(zf), "as its directory says", archive, tmp, budget, progress)
        elif tarfile.is_tarfile(archive):
            with tarfile.open(archive) as tf:
                _extract_members(_tar_members(tf), "as its headers say", archive, tmp, budget, progress)
        else:
            raise ArchiveError(f"cannot read archive {archive}: it is neither a zip nor a tar archive",
                               hint="the file may be damaged or cut off; get it again")
        os.replace(tmp, target)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, tarfile.TarError, EOFError, zlib.error, lzma.LZMAError,
            NotImplementedError, RuntimeError, OSError) as exc:
        _discard(tmp)
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EROFS):
            raise ArchiveError(f"cannot extract archive {archive} into {target.parent}: {exc}",
                               hint="free some space or choose another folder; nothing was kept") from exc
        # A damaged archive: a bad CRC, cut-off compressed data, an unsupported or encrypted member.
        raise ArchiveError(f"cannot read archive {archive}: it is damaged or unsupported ({type(exc).__name__}: "
                           f"{exc})", hint="get the archive again; nothing was extracted and your other files were "
                                           "not touched") from exc
    except BaseException:
        _discard(tmp)
        raise
    return target
