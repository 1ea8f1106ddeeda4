"""The one archive reader (core/archives.py) for dataset downloads and `evaluate`: zip and tar bombs refused
before the limit is passed, headers that lie stopped by the count of bytes written, paths outside the
archive, links and special files refused, nothing left behind, good archives extracted byte for byte."""

from __future__ import annotations

import os
import tarfile
import tempfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import strings_bench.core.archives as archives
from strings_bench.core.archives import (EXTRACT_LIMIT_ENV, ArchiveError, UnsafeArchiveError, extract_limit,
                                         safe_extract)

from _archives import MIB, tar_bomb, tar_of, zip_bomb, zip_of


@pytest.fixture
def written(monkeypatch) -> list[int]:
    """Bytes found on disk in each partial extraction at the moment it is discarded (measured by walking the
    folder, not by the reader's own count)."""
    seen: list[int] = []
    discard = archives._discard

    def measured(folder: Path) -> None:
        seen.append(sum(p.stat().st_size for p in Path(folder).rglob("*") if p.is_file()))
        discard(folder)

    monkeypatch.setattr(archives, "_discard", measured)
    return seen


def everything_under(folder: Path) -> list[Path]:
    return sorted(folder.rglob("*")) if folder.exists() else []


# ---- bombs ------------------------------------------------------------------------------------
def test_zip_bomb_is_refused_from_its_directory_before_anything_is_written(tmp_path, written):
    bomb = zip_bomb(tmp_path / "bomb.zip", 64 * MIB)
    assert bomb.stat().st_size < 200_000  # a bomb indeed: > 300:1
    target = tmp_path / "work" / "data"
    with pytest.raises(UnsafeArchiveError) as exc:
        safe_extract(bomb, target, progress=False, max_bytes=4 * MIB)
    msg = str(exc.value)
    assert str(bomb) in msg and "over the extraction limit of 4194304 bytes" in msg and "67108864 bytes" in msg
    assert "download.max_bytes" in exc.value.hint  # the limit came from the caller (a card): says where
    assert written == [0]
    assert everything_under(tmp_path / "work") == []


def test_tar_bomb_is_refused_from_its_headers_with_the_env_limit_named(tmp_path, written, monkeypatch):
    monkeypatch.setenv(EXTRACT_LIMIT_ENV, str(1 * MIB))
    bomb = tar_bomb(tmp_path / "bomb.tar.gz", 16 * MIB)
    target = tmp_path / "work" / "data"
    with pytest.raises(UnsafeArchiveError,
                       match=r"expands to 16777216 bytes .*over the extraction limit of 1048576 bytes") as exc:
        safe_extract(bomb, target, progress=False)
    assert f"{EXTRACT_LIMIT_ENV}=BYTES" in exc.value.hint
    assert written == [0]
    assert everything_under(tmp_path / "work") == []
    # raised above the archive's size, the same archive extracts
    monkeypatch.setenv(EXTRACT_LIMIT_ENV, str(16 * MIB))
    assert (safe_extract(bomb, target, progress=False) / "predictions/color/zeros.png").stat().st_size == 16 * MIB


@pytest.mark.parametrize("fmt", ["zip", "tar.gz"])
def test_headers_that_lie_are_stopped_by_the_count_of_bytes_written(tmp_path, written, monkeypatch, fmt):
    """The members declare 1 byte each (as a forged header would); the data streams on: the count of bytes
    written stops it, and never past the limit."""
    limit = 3 * MIB + 12345
    make = zip_bomb if fmt == "zip" else tar_bomb
    bomb = make(tmp_path / f"bomb.{fmt}", 16 * MIB)
    real = archives._zip_members if fmt == "zip" else archives._tar_members

    def lying(handle):
        members = real(handle)
        for m in members:
            m.size = 1
        return members

    monkeypatch.setattr(archives, "_zip_members" if fmt == "zip" else "_tar_members", lying)
    with pytest.raises(UnsafeArchiveError, match=f"more than {limit} bytes"):
        safe_extract(bomb, tmp_path / "work" / "data", progress=False, max_bytes=limit)
    (on_disk,) = written
    assert 2 * MIB < on_disk <= limit  # it wrote, and stopped at the limit (1 MiB pieces: the last one refused)
    assert everything_under(tmp_path / "work") == []


def test_a_bad_limit_in_the_environment_is_a_clear_error(tmp_path, monkeypatch):
    arc = zip_of(tmp_path / "a.zip", {"x": b"1"})
    for bad in ("lots", "-5"):
        monkeypatch.setenv(EXTRACT_LIMIT_ENV, bad)
        with pytest.raises(ArchiveError, match=f"{EXTRACT_LIMIT_ENV}='{bad}' is not a number of bytes"):
            safe_extract(arc, tmp_path / "t", progress=False)
    monkeypatch.setenv(EXTRACT_LIMIT_ENV, "2e9")
    assert extract_limit(arc).bytes == 2_000_000_000
    monkeypatch.delenv(EXTRACT_LIMIT_ENV)
    assert extract_limit(arc).bytes == 1 << 30  # a small archive: the 1 GiB floor
    big = tmp_path / "big.bin"
    with open(big, "wb") as f:
        f.truncate(20 * MIB)  # sparse: no 20 MiB written
    assert extract_limit(big).bytes == 100 * 20 * MIB


# ---- refused members --------------------------------------------------------------------------
def _malicious(kind: str, tmp_path: Path) -> Path:
    outside = str(tmp_path / "evil")
    if kind.startswith("zip"):
        members, modes = {"data/ok.txt": b"fine"}, {}
        if kind == "zip_slip":
            members["data/../../evil"] = b"pwned"
        elif kind == "zip_absolute":
            members[outside] = b"pwned"
        elif kind == "zip_drive":
            members["C:/evil"] = b"pwned"
        elif kind == "zip_symlink":
            members["data/link"], modes["data/link"] = b"/etc/passwd", 0o120777
        elif kind == "zip_device":
            members["data/dev"], modes["data/dev"] = b"", 0o020644
        return zip_of(tmp_path / "in" / "a.zip", members, modes)
    members: list = [("data/ok.txt", b"fine")]
    if kind == "tar_slip":
        members.append(("data/../../evil", b"pwned"))
    elif kind == "tar_absolute":
        members.append((outside, b"pwned"))
    else:
        info = tarfile.TarInfo("data/link")
        info.type, info.linkname = {"tar_symlink": (tarfile.SYMTYPE, "/etc/passwd"),
                                    "tar_hardlink": (tarfile.LNKTYPE, "data/ok.txt"),
                                    "tar_device": (tarfile.CHRTYPE, ""),
                                    "tar_fifo": (tarfile.FIFOTYPE, "")}[kind]
        members.append(info)
    return tar_of(tmp_path / "in" / "a.tar.gz", members)


REFUSED = {"zip_slip": "a path outside the archive ('..' climbs out of the folder)",
           "zip_absolute": "a path outside the archive (an absolute path)",
           "zip_drive": "a path outside the archive (a drive letter)",
           "zip_symlink": "holds links or special files: 'data/link' (a symbolic link)",
           "zip_device": "holds links or special files: 'data/dev' (a special file)",
           "tar_slip": "a path outside the archive ('..' climbs out of the folder)",
           "tar_absolute": "a path outside the archive (an absolute path)",
           "tar_symlink": "holds links or special files: 'data/link' (a symbolic link to '/etc/passwd')",
           "tar_hardlink": "holds links or special files: 'data/link' (a hard link to 'data/ok.txt')",
           "tar_device": "holds links or special files: 'data/link' (a special file (device or fifo))",
           "tar_fifo": "holds links or special files: 'data/link' (a special file (device or fifo))"}


@pytest.mark.parametrize("kind", sorted(REFUSED))
def test_paths_out_links_and_special_files_are_refused_before_writing(tmp_path, written, kind):
    (tmp_path / "in").mkdir()
    arc = _malicious(kind, tmp_path)
    with pytest.raises(UnsafeArchiveError) as exc:
        safe_extract(arc, tmp_path / "work" / "data", progress=False)
    assert str(arc) in str(exc.value) and REFUSED[kind] in str(exc.value)
    assert written == [0]  # not even data/ok.txt
    assert everything_under(tmp_path / "work") == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in", "work"]  # no evil anywhere


@pytest.mark.parametrize("content", [b"PK\x03\x04 cut off", b"<html>login page</html>", b""])
def test_damaged_or_non_archives_are_a_clear_error_leaving_nothing(tmp_path, content):
    arc = tmp_path / "a.zip"
    arc.write_bytes(content)
    with pytest.raises(ArchiveError, match=rf"cannot read archive {arc}"):
        safe_extract(arc, tmp_path / "work" / "data", progress=False)
    assert everything_under(tmp_path / "work") == []


def test_a_corrupt_member_removes_what_was_already_written(tmp_path, written):
    arc = zip_of(tmp_path / "a.zip", {"data/a.bin": os.urandom(300_000), "data/b.bin": os.urandom(300_000)})
    data = bytearray(arc.read_bytes())
    second = data.find(b"PK\x03\x04", 10)
    data[second + 5000] ^= 0xFF  # inside b.bin's deflated data, after a.bin is written
    arc.write_bytes(bytes(data))
    with pytest.raises(ArchiveError, match="damaged or unsupported"):
        safe_extract(arc, tmp_path / "work" / "data", progress=False)
    assert written and written[0] >= 300_000  # a.bin was on disk, and is gone
    assert everything_under(tmp_path / "work") == []


# ---- good archives ----------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["zip", "tar.gz"])
def test_good_archives_extract_byte_for_byte(tmp_path, fmt):
    files = {"tandt/truck/images/a.jpg": os.urandom(5000), "tandt/truck/sparse/0/cameras.bin": os.urandom(77),
             "tandt/README": b"hello\n", "tandt/empty.txt": b""}
    arc = (zip_of(tmp_path / "a.zip", files) if fmt == "zip" else
           tar_of(tmp_path / "a.tar.gz", list(files.items())))
    out = safe_extract(arc, tmp_path / "x" / "data", progress=False)
    got = {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert got == files
    assert [p.name for p in (tmp_path / "x").iterdir()] == ["data"]  # no temporary folder left
    with pytest.raises(ArchiveError, match="already exists"):
        safe_extract(arc, out, progress=False)


# ---- through `strings-bench evaluate` ---------------------------------------------------------
@pytest.fixture
def private_tmp(tmp_path, monkeypatch) -> Path:
    """TMPDIR pointed at an empty folder, so that anything left in the temporary folder is seen."""
    tmp = tmp_path / "TMPDIR"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", None)  # re-read TMPDIR
    return tmp


@pytest.mark.parametrize("fmt", ["zip", "tar.gz"])
def test_evaluate_refuses_a_bomb_and_leaves_nothing(tmp_path, private_tmp, written, monkeypatch, capsys, fmt):
    import runner_fakes as rf
    import strings_bench.eval.ocr as ocr
    from strings_bench.cli import main

    # The OCR engine is built before the predictions are opened; a fake one spares loading RapidOCR's models.
    monkeypatch.setattr(ocr, "get_engines", lambda spec: [rf.FakeOCR()])
    monkeypatch.setenv(EXTRACT_LIMIT_ENV, str(2 * MIB))
    bomb = (zip_bomb if fmt == "zip" else tar_bomb)(tmp_path / f"preds.{fmt}", 32 * MIB)
    out = tmp_path / "out"
    rc = main(["evaluate", str(bomb), "--out", str(out), "--no-lpips", "--no-report"])
    err = capsys.readouterr().err
    assert rc == 1
    assert f"error: archive {bomb} expands to 33554432 bytes" in err and "over the extraction limit of 2097152" in err
    assert f"hint: if the archive is genuine, raise the limit with the environment variable {EXTRACT_LIMIT_ENV}" in err
    assert "Traceback" not in err
    assert written == [0]
    assert everything_under(private_tmp) == []
    assert everything_under(out) == []


def _nerfbaselines_archive(tmp_path: Path, fmt: str) -> Path:
    rng = np.random.default_rng(0)
    stage = tmp_path / "stage" / "predictions"
    for name in ("view_a", "view_b"):
        gt = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
        render = np.clip(gt.astype(int) + rng.integers(-9, 10, gt.shape), 0, 255).astype(np.uint8)
        for sub, img in (("gt-color", gt), ("color", render)):
            (stage / sub).mkdir(parents=True, exist_ok=True)
            Image.fromarray(img).save(stage / sub / f"{name}.png")
    files = {p.relative_to(stage.parent).as_posix(): p.read_bytes() for p in sorted(stage.rglob("*")) if p.is_file()}
    return (zip_of(tmp_path / "preds.zip", files) if fmt == "zip" else
            tar_of(tmp_path / "preds.tar.gz", list(files.items())))


@pytest.mark.parametrize("fmt", ["zip", "tar.gz"])
def test_evaluate_reads_a_good_archive_and_cleans_up(tmp_path, private_tmp, fmt):
    import runner_fakes as rf
    from strings_bench.bench.evaluate import EvaluateOptions, evaluate
    from strings_bench.bench.predictions import detect_layout, open_predictions

    arc = _nerfbaselines_archive(tmp_path, fmt)
    with open_predictions(arc) as root:
        preds = detect_layout(root)
        assert preds.layout == "nerfbaselines" and sorted(preds.checkpoints[0].renders) == ["view_a", "view_b"]
        staged = tmp_path / "stage" / "predictions" / "color" / "view_a.png"
        assert (root / "color" / "view_a.png").read_bytes() == staged.read_bytes()
    assert everything_under(private_tmp) == []
    said = []
    out = evaluate(arc, EvaluateOptions(out=tmp_path / "out", ocr=rf.FakeOCR(), with_lpips=False, report=False,
                                        progress=False), say=said.append)
    assert said[0].startswith("layout: nerfbaselines")
    assert (out / "results.csv").is_file()
    assert everything_under(private_tmp) == []


@pytest.mark.slow
def test_evaluate_refuses_the_reported_bomb_at_full_scale(tmp_path, private_tmp, written, monkeypatch):
    """A 2 MB zip holding 2 GiB of zeros under predictions/color/, at the default limit (1 GiB for an archive
    this small): refused from the zip's directory, nothing written."""
    import runner_fakes as rf
    from strings_bench.bench.evaluate import EvaluateOptions, evaluate

    monkeypatch.delenv(EXTRACT_LIMIT_ENV, raising=False)
    bomb = zip_bomb(tmp_path / "preds.zip", 2 << 30)
    assert bomb.stat().st_size < 3_000_000
    with pytest.raises(UnsafeArchiveError, match=r"expands to 2147483648 bytes .* limit of 1073741824 bytes"):
        evaluate(bomb, EvaluateOptions(out=tmp_path / "out", ocr=rf.FakeOCR(), with_lpips=False, report=False))
    assert written == [0]
    assert everything_under(private_tmp) == [] and everything_under(tmp_path / "out") == []
