"""Output folders checked before work, and atomic writes that fail on a read-only disk
(issue 33, item 6: labfiles' cleanup of its temporary file raised a second error that hid the
first, and the error named the hidden temporary file instead of the file asked for)."""

from __future__ import annotations

import errno

import pytest

from labfiles import atomic_write_text, write_new_file
from labfiles.outdir import OutDirError, prepare_out_dir, write_error_line
from tests.readonly import read_only_folder


def test_a_failed_write_on_a_read_only_disk_names_the_target(tmp_path):
    with read_only_folder(tmp_path) as ro:
        for write in (atomic_write_text, write_new_file):
            with pytest.raises(OSError) as caught:
                write(ro / "observers.toml", "x = 1\n")
            assert caught.value.errno == errno.EROFS
            assert caught.value.filename == str(ro / "observers.toml")
            assert caught.value.__context__ is None or ".tmp-" not in str(caught.value)
        with pytest.raises(OutDirError, match=r"cannot write .*read-only/report \(Read-only file "
                                              r"system\).*give --out a place on a writable disk"):
            prepare_out_dir(ro / "report")


def test_out_naming_a_file_is_refused_and_the_file_kept(tmp_path):
    afile = tmp_path / "results"
    afile.write_text("mine")
    with pytest.raises(OutDirError, match="--out .*results is a file, not a folder"):
        prepare_out_dir(afile)
    assert afile.read_text() == "mine"
    assert prepare_out_dir(tmp_path / "a" / "b").is_dir()  # parents are made
    assert not list((tmp_path / "a" / "b").iterdir())  # the probe is gone


def test_write_error_line_says_what_to_do():
    full = OSError(errno.ENOSPC, "No space left on device", "/data/x.csv")
    assert "the disk is full: could not write /data/x.csv; free space" in write_error_line(full)
