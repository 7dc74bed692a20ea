"""The torn-tail rule of append-only files, and appends that never leave half a record."""

from __future__ import annotations

import errno
import subprocess
import sys
import warnings

import pytest

from labfiles import (
    FolderLock,
    FolderLocked,
    LabFileError,
    RecordFile,
    TornTailWarning,
    csv_fields_check,
    csv_record,
    json_record_check,
    read_records,
    repair_torn_tail,
)

HEADER = "a,b,c"


def _side_files(path):
    return sorted(path.parent.glob(path.name + ".torn-*"))


@pytest.mark.parametrize("tail, reason", [
    (b'4,"cut', "no newline"),       # cut inside quotes (pandas: EOF inside string)
    (b"4,5", "no newline"),          # cut outside quotes (would merge with the next row)
    (b"\x00" * 37, "NUL bytes"),     # what a power cut can leave on some file systems
])
def test_torn_tail_is_kept_aside_and_cut_back_to_the_last_whole_record(tmp_path, tail, reason):
    path = tmp_path / "readings.csv"
    whole = b"a,b,c\n1,2,3\n"
    path.write_bytes(whole + tail)
    with pytest.warns(TornTailWarning, match=rf"readings.csv: line 3 is torn \(.*{reason}"):
        torn = repair_torn_tail(path, check=csv_fields_check(3))
    assert path.read_bytes() == whole
    assert torn.side_file.read_bytes() == tail
    assert _side_files(path) == [torn.side_file]


def test_a_last_line_that_is_not_a_whole_record_is_torn_too(tmp_path):
    path = tmp_path / "runs.jsonl"
    path.write_bytes(b'{"event": "start"}\n{"event": "en\n')
    with pytest.warns(TornTailWarning, match="line 2 is torn"):
        lines = read_records(path, check=json_record_check)
    assert lines == ['{"event": "start"}']
    assert _side_files(path)[0].read_bytes() == b'{"event": "en\n'


def test_whole_file_is_left_untouched_and_warns_nothing(tmp_path):
    path = tmp_path / "s.csv"
    path.write_bytes(b"a,b,c\n1,2,3\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_records(path, check=csv_fields_check(3)) == ["a,b,c", "1,2,3"]
    assert _side_files(path) == []


def test_appending_after_a_torn_tail_starts_on_a_fresh_line(tmp_path):
    path = tmp_path / "s.csv"
    path.write_bytes(b"a,b,c\n1,2,3\n4,5")
    with pytest.warns(TornTailWarning), RecordFile(path, header=HEADER,
                                                   check=csv_fields_check(3)) as rec:
        rec.append(csv_record([4, 5, 6]))
    assert path.read_text() == "a,b,c\n1,2,3\n4,5,6\n"


def test_read_only_file_is_read_up_to_its_last_whole_record(tmp_path):
    path = tmp_path / "s.csv"
    path.write_bytes(b"a,b,c\n1,2,3\n4,")
    with pytest.warns(TornTailWarning, match="left as it is"):
        lines = read_records(path, repair=False)
    assert lines == ["a,b,c", "1,2,3"]
    assert path.read_bytes().endswith(b"4,")


def test_a_file_with_another_header_is_refused(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("x,y\n1,2\n")
    with pytest.raises(LabFileError, match="not this file's header"), RecordFile(path,
                                                                                 header=HEADER):
        pass
    assert path.read_text() == "x,y\n1,2\n"


def test_a_record_with_a_line_break_is_refused():
    with pytest.raises(ValueError, match="line break"):
        csv_record(["ok", "two\nlines"])


def test_a_write_cut_short_by_the_file_size_limit_leaves_no_half_record(tmp_path):
    """A real short write: RLIMIT_FSIZE makes the kernel write only part of the record."""
    path = tmp_path / "s.csv"
    code = f"""
import resource, signal
from labfiles import RecordFile
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
with RecordFile({str(path)!r}, header="a,b,c") as rec:
    rec.append("1,2,3")
    resource.setrlimit(resource.RLIMIT_FSIZE, (20, 20))
    try:
        rec.append("4,5," + "6" * 40)
    except OSError as exc:
        print("errno", exc.errno, exc)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert f"errno {errno.ENOSPC}" in out and "s.csv" in out
    assert path.read_text() == "a,b,c\n1,2,3\n"


def test_second_holder_of_a_folder_lock_is_told_who_holds_it(tmp_path):
    code = f"""
import time
from labfiles import FolderLock
with FolderLock({str(tmp_path)!r}, what="calibration folder"):
    print("held", flush=True)
    time.sleep(30)
"""
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        with (pytest.raises(FolderLocked, match=rf"calibration folder .*pid {proc.pid}"),
              FolderLock(tmp_path, what="calibration folder")):
            pass
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()
    with FolderLock(tmp_path):  # released by the kernel when the holder died
        pass


def test_csv_records_read_around_a_torn_row_and_append_after_it(tmp_path):
    from labfiles import append_csv_record, read_csv_records

    path = tmp_path / "renders.csv"
    append_csv_record(path, ["a", "b"], [1, "x,y"])
    path.write_bytes(path.read_bytes() + b'2,"cut')
    with pytest.warns(TornTailWarning):
        frame = read_csv_records(path, repair=False)
    assert frame.to_dict("list") == {"a": [1], "b": ["x,y"]}
    with pytest.warns(TornTailWarning):
        append_csv_record(path, ["a", "b"], [2, "z"])
    assert read_csv_records(path).to_dict("list") == {"a": [1, 2], "b": ["x,y", "z"]}
