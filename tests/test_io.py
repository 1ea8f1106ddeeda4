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
