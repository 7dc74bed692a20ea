"""Atomic writes: a failed write leaves the target as it was and no temporary file behind."""

from __future__ import annotations

import os
import stat

import pytest

from labfiles import (
    TEMPORARY_GLOB,
    atomic_open,
    atomic_path,
    atomic_write_text,
    temporary_path,
    write_new_file,
)


def test_successful_write_replaces_the_target(tmp_path):
    target = tmp_path / "table.csv"
    target.write_text("old\n")
    with atomic_open(target, "w", encoding="utf-8") as fh:
        fh.write("new\n")
    assert target.read_text() == "new\n"
    assert not list(tmp_path.glob(TEMPORARY_GLOB))


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "image.png"
    target.write_bytes(b"recorded")
    with pytest.raises(RuntimeError), atomic_open(target) as fh:
        fh.write(b"half")
        raise RuntimeError("disk full")
    assert target.read_bytes() == b"recorded"
    assert not list(tmp_path.glob(TEMPORARY_GLOB))


def test_writers_by_name_get_a_hidden_temporary_with_the_same_suffix(tmp_path):
    target = tmp_path / "photo.exr"
    with atomic_path(target) as tmp:
        assert tmp.parent == temporary_path(target).parent
        assert tmp.name.startswith(".") and tmp.suffix == ".exr"
        assert tmp.match(TEMPORARY_GLOB)
        assert not target.exists()
        tmp.write_bytes(b"exr")
    assert target.read_bytes() == b"exr"


def test_files_get_the_umask_permissions_not_0600(tmp_path):
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "calibration.json", "{}")
        write_new_file(tmp_path / "report.txt", "ok")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "calibration.json").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "report.txt").stat().st_mode) == 0o644


def test_a_new_file_is_never_written_over(tmp_path):
    target = tmp_path / "run1.json"
    write_new_file(target, "first")
    with pytest.raises(FileExistsError, match="never overwritten"):
        write_new_file(target, "second")
    assert target.read_text() == "first"
    assert not list(tmp_path.glob(TEMPORARY_GLOB))
