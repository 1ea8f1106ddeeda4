"""Fetch datasets that have a direct URL, and unpack archives safely.

- `download_file`: resumable (a `.part` file next to the target, continued with an HTTP Range
  request; a server that ignores Range restarts the transfer from zero), verified with sha256
  when the card knows the hash (otherwise the computed hash is printed and the file is reported
  as unverified), with a progress bar. The target appears only when complete and verified.
- `safe_extract`: zip and tar. Every member is checked before anything is written: absolute
  paths, `..` components, drive letters, links (symbolic and hard) and special files are refused.
  Extraction goes into a temporary sibling folder that is renamed onto the target at the end.
- `download_dataset`: for a card with a URL, download + extract + register; for data behind a
  browser or an account (Google Drive, the gated DL3DV set) print the exact steps instead.
"""

from __future__ import annotations

import lzma
import os
import shutil
import stat
import tarfile
import urllib.error
import urllib.request
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Callable

from tqdm import tqdm

from strings_bench.core.errors import DatasetError, StringsBenchError
from strings_bench.core.io import cache_root, sha256_file

CHUNK = 1 << 20
USER_AGENT = "strings-bench-downloader"


class DownloadError(StringsBenchError):
    """A transfer failed or its content does not match the expected hash."""


class UnsafeArchiveError(DatasetError):
    """An archive member would land outside the target folder, or is a link/special file."""


@dataclass
class DownloadResult:
    path: Path
    sha256: str
    verified: bool  # False when no expected hash was known
    resumed_from: int  # bytes already present in the .part file when this call started


def download_file(url: str, dest: str | Path, sha256: str | None = None, progress: bool = True,
                  timeout: float = 60.0, echo: Callable[[str], None] = print) -> DownloadResult:
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    if dest.exists():
        digest = sha256_file(dest)
        if sha256 and digest != sha256.lower():
            raise DownloadError(f"{dest} exists but its sha256 is {digest}, expected {sha256}",
                                hint=f"delete {dest} and download again")
        return DownloadResult(dest, digest, bool(sha256), dest.stat().st_size)

    part = dest.with_name(dest.name + ".part")
    have = part.stat().st_size if part.exists() else 0
    headers = {"User-Agent": USER_AGENT}
    if have:
        headers["Range"] = f"bytes={have}-"
    req = urllib.request.Request(url, headers=headers)
    try:
        resp = urllib.request.urlopen(req, timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:
            # Range not satisfiable: the .part already holds the whole file; verify it below.
            resp = None
        else:
            raise DownloadError(f"download of {url} failed: HTTP {exc.code} {exc.reason}",
                                hint="check the URL or your network; re-run to resume") from exc
    except (urllib.error.URLError, OSError) as exc:
        raise DownloadError(f"cannot reach {url}: {exc}", hint="check your network; re-run to resume") from exc

    resumed_from = have
    if resp is not None:
        with resp:
            status = getattr(resp, "status", 200)
            if have and status != 206:
                # The server ignored Range: start over rather than append a second copy.
                echo(f"server does not support resuming; restarting {dest.name} from the beginning")
                have = resumed_from = 0
            length = resp.headers.get("Content-Length")
            total = have + int(length) if length is not None else None
            mode = "ab" if have else "wb"
            with open(part, mode) as f, tqdm(total=total, initial=have, unit="B", unit_scale=True,
                                             desc=dest.name, disable=not progress) as bar:
                try:
                    while block := resp.read(CHUNK):
                        f.write(block)
                        bar.update(len(block))
                except (OSError, urllib.error.URLError) as exc:
                    raise DownloadError(f"the transfer of {url} broke off after {part.stat().st_size} bytes: {exc}",
                                        hint="re-run the same command: it resumes from the .part file") from exc
            if total is not None and part.stat().st_size < total:
                raise DownloadError(f"the transfer of {url} ended early ({part.stat().st_size} of {total} bytes)",
                                    hint="re-run the same command: it resumes from the .part file")

    digest = sha256_file(part)
    if sha256:
        if digest != sha256.lower():
            bad = part.with_name(part.name + ".bad")
            os.replace(part, bad)
            raise DownloadError(
                f"sha256 mismatch for {url}: got {digest}, expected {sha256.lower()} (kept as {bad})",
                hint="the file is damaged or changed upstream; delete it and download again, or check the card's hash",
            )
    else:
        echo(f"sha256 of {dest.name}: {digest} (no published hash: the download could not be verified)")
    os.replace(part, dest)
    return DownloadResult(dest, digest, bool(sha256), resumed_from)


# ---- safe extraction --------------------------------------------------------------------------
def _checked_member_path(name: str, archive: Path) -> PurePosixPath:
    norm = name.replace("\\", "/")
    p = PurePosixPath(norm)
    if norm.startswith("/") or p.is_absolute() or (len(norm) > 1 and norm[1] == ":"):
        raise UnsafeArchiveError(f"{archive} holds a member with an absolute path: {name!r}",
                                 hint="refusing to extract an archive that writes outside its folder; get it from the official source")
    if ".." in p.parts:
        raise UnsafeArchiveError(f"{archive} holds a member that escapes the target folder: {name!r}",
                                 hint="refusing to extract an archive with '..' paths; get it from the official source")
    return p


def _zip_is_link_or_special(info: zipfile.ZipInfo) -> bool:
    # Unix zips keep st_mode in the high 16 bits; many writers leave the file-type bits at 0.
    file_type = stat.S_IFMT(info.external_attr >> 16)
    return file_type not in (0, stat.S_IFREG, stat.S_IFDIR)


EXTRACT_LIMIT_ENV = "STRINGS_BENCH_MAX_EXTRACT_BYTES"
MIN_EXTRACT_LIMIT = 1 << 30  # 1 GiB
EXTRACT_RATIO_LIMIT = 100  # photos and COLMAP models compress far less than 100:1; a zip bomb far more


def extract_limit(archive: Path, max_bytes: int | None = None) -> int:
    """Bytes an archive may expand to: `max_bytes` (a card's `download.max_bytes`), else the environment's
    STRINGS_BENCH_MAX_EXTRACT_BYTES, else 100 x the archive's size (at least 1 GiB)."""
    if max_bytes is not None:
        return int(max_bytes)
    env = os.environ.get(EXTRACT_LIMIT_ENV, "").strip()
    if env:
        try:
            return int(float(env))
        except ValueError:
            raise DatasetError(f"{EXTRACT_LIMIT_ENV}={env!r} is not a number of bytes", hint="e.g. 200e9") from None
    return max(MIN_EXTRACT_LIMIT, EXTRACT_RATIO_LIMIT * Path(archive).stat().st_size)


class _Budget:
    """Counts the bytes actually written (headers can lie about sizes) and stops at the limit."""

    def __init__(self, archive: Path, limit: int):
        self.archive, self.limit, self.used = archive, limit, 0

    def refuse(self, amount: str) -> UnsafeArchiveError:
        return UnsafeArchiveError(
            f"{self.archive} expands to {amount}, over the extraction limit of {self.limit} bytes (a zip bomb, or a "
            f"larger dataset than expected); extraction stopped and nothing was kept",
            hint=f"if the archive is genuine, raise the limit with {EXTRACT_LIMIT_ENV}=BYTES")

    def copy(self, src, dst) -> None:
        while block := src.read(CHUNK):
            self.used += len(block)
            if self.used > self.limit:
                raise self.refuse(f"more than {self.limit} bytes")
            dst.write(block)


@dataclass
class _Member:
    """An archive member as extraction sees it, zip or tar alike."""

    name: str
    is_dir: bool
    size: int  # declared bytes (0 for a folder)
    open: Callable  # () -> a readable file object of its bytes
    refused: str = ""  # why it is not extracted (a link, a special file); "" when it is


def _zip_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, archive: Path) -> _Member:
    refused = f"{archive} holds a link or special file: {info.filename!r}" if _zip_is_link_or_special(info) else ""
    return _Member(info.filename, info.is_dir(), 0 if info.is_dir() else info.file_size, lambda: zf.open(info), refused)


def _tar_member(tf: tarfile.TarFile, m: tarfile.TarInfo, archive: Path) -> _Member:
    refused = (f"{archive} holds a link: {m.name!r} -> {m.linkname!r}" if m.issym() or m.islnk() else
               f"{archive} holds a special file (device/fifo): {m.name!r}" if not (m.isfile() or m.isdir()) else "")
    return _Member(m.name, m.isdir(), m.size if m.isfile() else 0, lambda: tf.extractfile(m), refused)


def _extract_members(members: list[_Member], declared_by: str, archive: Path, tmp: Path, budget: _Budget,
                     progress: bool) -> None:
    """Check every member (a path inside the folder, no link, no special file, the declared total within the
    budget) before writing anything, then write them under `tmp`, counting the bytes actually written."""
    for m in members:
        _checked_member_path(m.name, archive)
        if m.refused:
            raise UnsafeArchiveError(m.refused, hint="refusing to extract links and special files; get the archive from "
                                                     "the official source")
    declared = sum(m.size for m in members)
    if declared > budget.limit:
        raise budget.refuse(f"{declared} bytes ({declared_by})")
    for m in tqdm(members, desc=f"extract {archive.name}", unit="file", disable=not progress):
        out = tmp.joinpath(*_checked_member_path(m.name, archive).parts)
        if m.is_dir:
            out.mkdir(parents=True, exist_ok=True)
            continue
        out.parent.mkdir(parents=True, exist_ok=True)
        with m.open() as src, open(out, "wb") as dst:
            budget.copy(src, dst)


def safe_extract(archive: str | Path, target: str | Path, progress: bool = True, max_bytes: int | None = None) -> Path:
    """Extract a .zip or .tar(.gz/.bz2/.xz) into `target` (which must not exist yet), writing at most
    `extract_limit(archive, max_bytes)` bytes."""
    archive, target = Path(archive), Path(target)
    if target.exists():
        raise DatasetError(f"{target} already exists", hint="delete it or choose another folder")
    budget = _Budget(archive, extract_limit(archive, max_bytes))
    tmp = target.with_name(f".{target.name}.extract-tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        if zipfile.is_zipfile(archive):
            with zipfile.ZipFile(archive) as zf:
                _extract_members([_zip_member(zf, info, archive) for info in zf.infolist()], "as its directory says",
                                 archive, tmp, budget, progress)
        elif tarfile.is_tarfile(archive):
            with tarfile.open(archive) as tf:
                _extract_members([_tar_member(tf, m, archive) for m in tf.getmembers()], "as its headers say",
                                 archive, tmp, budget, progress)
        else:
            raise DatasetError(f"{archive} is neither a zip nor a tar archive", hint="the download may be damaged; delete it and retry")
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, target)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, tarfile.TarError, EOFError, zlib.error, lzma.LZMAError,
            NotImplementedError, RuntimeError, OSError) as exc:
        # A damaged archive: a bad CRC, cut-off compressed data, an unsupported or encrypted member.
        shutil.rmtree(tmp, ignore_errors=True)
        raise DatasetError(f"{archive} is damaged or unsupported and cannot be extracted: {type(exc).__name__}: {exc}",
                           hint="delete it and download again; your other files were not touched") from exc
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


# ---- datasets ---------------------------------------------------------------------------------
def download_steps(card) -> list[str]:
    info = card.download or {}
    return list(info.get("steps", []))


def download_dataset(dataset_id: str, dest: str | Path | None = None, progress: bool = True,
                     register: bool = True, echo: Callable[[str], None] = print) -> Path | None:
    """Download and register a dataset with a direct URL; print the steps for the others.

    Returns the registered root, or None when the data needs manual steps.
    """
    from strings_bench.datasets.registry import get_dataset, read_index, write_index

    card = get_dataset(dataset_id)
    info = card.download or {}
    if not info.get("url"):
        steps = download_steps(card)
        echo(f"{card.title}\n  source: {card.source}\n  licence: {card.licence}")
        if not steps:
            echo("  no download is known for this dataset; see its source above")
            return None
        echo("  This dataset cannot be fetched automatically (it needs a browser or an account). Steps:")
        for i, step in enumerate(steps, 1):
            echo(f"  {i}. {step}")
        return None

    echo(f"{card.title}\n  source: {card.source}\n  licence: {card.licence} -- by downloading you accept it")
    downloads = cache_root() / "downloads"
    archive = downloads / info.get("filename", Path(info["url"]).name)
    download_file(info["url"], archive, sha256=info.get("sha256"), progress=progress, echo=echo)
    dest = Path(dest) if dest is not None else cache_root() / "datasets" / card.id
    extracted = dest  # the archive's content; the dataset root may be a subfolder of it
    if not extracted.exists():
        safe_extract(archive, extracted, progress=progress, max_bytes=info.get("max_bytes"))
    root = extracted
    if info.get("archive_subdir"):
        sub = extracted / info["archive_subdir"]
        if not sub.is_dir():
            raise DatasetError(f"{archive} did not contain the folder {info['archive_subdir']}/",
                               hint="the upstream archive changed; report it")
        root = sub
    if register:
        from strings_bench.datasets.check import check_card_copy, format_reports

        reports = check_card_copy(card.id, root)
        echo(format_reports(reports))
        index = read_index()
        index[card.id] = str(root.resolve())
        write_index(index)
        echo(f"registered {card.id} -> {root}")
    return root
