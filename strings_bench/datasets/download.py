"""Fetch datasets that have a direct URL, and unpack archives safely.

- `download_file`: resumable (a `.part` file next to the target, continued with an HTTP Range
  request; a server that ignores Range restarts the transfer from zero), verified with sha256
  when the card knows the hash (otherwise the computed hash is printed and the file is reported
  as unverified), with a progress bar. The target appears only when complete and verified.
- `safe_extract` (core/archives.py, the suite's one archive reader): zip and tar, members with
  absolute or `..` paths, links and special files refused, at most `extract_limit` bytes written,
  into a temporary sibling folder renamed onto the target at the end.
- `download_dataset`: for a card with a URL, download + extract + register; for data behind a
  browser or an account (Google Drive, the gated DL3DV set) print the exact steps instead.
"""

from __future__ import annotations

import os
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from tqdm import tqdm

# UnsafeArchiveError: what callers of safe_extract catch, importable from here as before
from strings_bench.core.archives import UnsafeArchiveError, safe_extract  # noqa: F401
from strings_bench.core.errors import DatasetError, StringsBenchError
from strings_bench.core.io import cache_root, sha256_file

CHUNK = 1 << 20
USER_AGENT = "strings-bench-downloader"


class DownloadError(StringsBenchError):
    """A transfer failed or its content does not match the expected hash."""


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
