"""Archive builders shared by tests/core/test_archives.py and tests/datasets/test_download.py: bombs of zeros and
small zip / tar.gz files of given members (links and special files as tarfile.TarInfo, zip modes as Unix modes)."""

from __future__ import annotations

import io
import tarfile
import zipfile
from pathlib import Path

MIB = 1 << 20


def zip_bomb(path: Path, n_bytes: int, name: str = "predictions/color/zeros.png") -> Path:
    """One member of `n_bytes` zeros, deflated (about 1000:1), written in 1 MiB pieces."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        info = zipfile.ZipInfo(name)
        info.compress_type = zipfile.ZIP_DEFLATED
        with zf.open(info, "w", force_zip64=n_bytes >= 1 << 31) as f:
            block = bytes(MIB)
            for start in range(0, n_bytes, MIB):
                f.write(block[: min(MIB, n_bytes - start)])
    return path


def tar_bomb(path: Path, n_bytes: int, name: str = "predictions/color/zeros.png") -> Path:
    with tarfile.open(path, "w:gz", compresslevel=9) as tf:
        info = tarfile.TarInfo(name)
        info.size = n_bytes
        tf.addfile(info, io.BytesIO(bytes(n_bytes)))
    return path


def tar_of(path: Path, members: list[tarfile.TarInfo | tuple[str, bytes]]) -> Path:
    with tarfile.open(path, "w:gz") as tf:
        for m in members:
            if isinstance(m, tarfile.TarInfo):
                tf.addfile(m)
            else:
                info = tarfile.TarInfo(m[0])
                info.size = len(m[1])
                tf.addfile(info, io.BytesIO(m[1]))
    return path


def zip_of(path: Path, members: dict[str, bytes], modes: dict[str, int] | None = None) -> Path:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            info = zipfile.ZipInfo(name)
            info.compress_type = zipfile.ZIP_DEFLATED
            if modes and name in modes:
                info.external_attr = modes[name] << 16
            zf.writestr(info, data)
    return path
