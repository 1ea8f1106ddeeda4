"""core.io: atomic writes leave no temporary file and give finished files the umask's mode."""

import os
import stat

import pytest

from strings_bench.core.io import atomic_write, atomic_write_text


def test_atomic_write_mode_is_that_of_a_plain_open(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")  # open() applies the process umask to 0666: the reference
    p = atomic_write_text(tmp_path / "a.txt", "x")
    assert stat.S_IMODE(p.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)


def test_atomic_write_failure_leaves_old_file_and_no_temp(tmp_path):
    target = atomic_write_text(tmp_path / "r.json", "old")

    def boom(tmp):
        tmp.write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(target, boom)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_atomic_write_syncs_the_data_before_the_rename_and_the_folder_after(tmp_path, monkeypatch):
    """Durable against a crash of the machine: the new contents reach the disk before the name does."""
    import strings_bench.core.io as io

    events = []
    real_open, real_fsync, real_replace = os.open, os.fsync, os.replace
    fds = {}

    def spy_open(path, flags, *a, **k):
        fd = real_open(path, flags, *a, **k)
        fds[fd] = str(path)
        return fd

    def spy_fsync(fd):
        p = fds.get(fd, "?")
        events.append(("fsync", "folder" if os.path.isdir(p) else open(p).read()))
        real_fsync(fd)

    def spy_replace(a, b):
        events.append(("replace", os.path.basename(b)))
        real_replace(a, b)

    monkeypatch.setattr(io.os, "open", spy_open)
    monkeypatch.setattr(io.os, "fsync", spy_fsync)
    monkeypatch.setattr(io.os, "replace", spy_replace)
    atomic_write_text(tmp_path / "d.json", "new contents")
    assert events == [("fsync", "new contents"), ("replace", "d.json"), ("fsync", "folder")]
