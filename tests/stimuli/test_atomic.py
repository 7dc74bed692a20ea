"""Atomic writes: a failed write leaves the target as it was and no temporary file behind."""

from __future__ import annotations

import pytest

from stimuli.atomic import TEMPORARY_GLOB, atomic_open, atomic_path, temporary_path


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
        assert tmp == temporary_path(target)
        assert tmp.name.startswith(".") and tmp.suffix == ".exr"
        assert tmp.match(TEMPORARY_GLOB)
        assert not target.exists()
        tmp.write_bytes(b"exr")
    assert target.read_bytes() == b"exr"
