"""sanav_mj.outputs: files written whole or not at all."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from sanav_mj import outputs
from sanav_mj.outputs import atomic_path, write_text


def test_write_creates_the_folder_and_replaces_an_old_file(tmp_path):
    path = tmp_path / "a" / "b.json"
    write_text(path, "old")
    write_text(path, "new")
    assert path.read_text() == "new"
    assert [p.name for p in path.parent.iterdir()] == ["b.json"]


@pytest.mark.parametrize("exc", [KeyboardInterrupt, RuntimeError])
def test_an_interrupted_write_keeps_the_old_file_and_leaves_no_part(tmp_path, exc):
    path = tmp_path / "r.csv"
    path.write_text("complete")
    with pytest.raises(exc), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise exc
    assert path.read_text() == "complete"
    assert [p.name for p in tmp_path.iterdir()] == ["r.csv"]


def test_a_new_file_interrupted_does_not_exist(tmp_path):
    path = tmp_path / "r.csv"
    with pytest.raises(KeyboardInterrupt), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_a_write_error_names_the_destination_not_the_temporary_file(tmp_path, monkeypatch):
    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", "/somewhere/.x.json.abc.part")

    monkeypatch.setattr(outputs.os, "fsync", full)
    path = tmp_path / "x.json"
    with pytest.raises(OSError) as err:
        write_text(path, "{}")
    assert (err.value.errno, err.value.filename) == (errno.ENOSPC, str(path))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_device_is_written_in_place_and_its_error_raised():
    with pytest.raises(OSError) as err:
        write_text("/dev/full", "x" * 10)
    assert (err.value.errno, err.value.filename) == (errno.ENOSPC, "/dev/full")


def test_a_folder_that_cannot_be_created_names_the_file(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OSError) as err:
        write_text(tmp_path / "f" / "sub" / "a.json", "{}")
    assert err.value.filename == str(tmp_path / "f" / "sub" / "a.json")


def test_the_file_mode_is_that_of_a_plain_write(tmp_path):
    import os
    import stat

    plain = tmp_path / "plain"
    plain.write_text("x")
    path = write_text(tmp_path / "atomic", "x")
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)  # umask applies, not 0o600
    os.chmod(path, 0o640)
    write_text(path, "y")
    assert stat.S_IMODE(path.stat().st_mode) == 0o640  # an existing file keeps its mode
