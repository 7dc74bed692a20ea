"""Readings files and display TOMLs as a lab's tools re-save them (issue 29 item 6, issue 33
item 6), through ``python -m calibration fit``.

The readings are a real display's (Psychtoolbox's Apple 17" CRT, 2000, in the procedure's columns:
tests/data/calibration, MIT), re-saved byte for byte as Excel, Notepad or R would
(:mod:`tests.tool_files`): each gives the calibration the file as written gives.
"""

from __future__ import annotations

import codecs
import shutil
from pathlib import Path

import pytest

from calibration import load_calibration
from calibration.readings import read_readings
from tests.tool_files import (
    excel_csv_utf8,
    excel_unicode_text,
    notepad_unicode,
    quoted,
    windows_code_page,
)

READINGS = Path(__file__).parents[1] / "data" / "calibration" / "ptb_apple17_crt_2000" / "readings.csv"
T0 = "2026-08-01T10:00:00Z"


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The calibration fitted from the file as written, and its readings."""
    from calibration.__main__ import main

    out = tmp_path_factory.mktemp("ref") / "cal"
    assert main(["fit", str(READINGS), "--out", str(out)]) == 0
    return load_calibration(out), read_readings(READINGS).frame, out


def _display_toml(path: Path, bom: bytes) -> Path:
    """A display description as Notepad saves it: ``bom``, CRLF."""
    text = ("[display]\r\nwidth_cm = 33.1\r\nresolution_px = [1024, 768]\r\ndistance_cm = 57.0"
            "\r\nrefresh_hz = 100.0\r\nmonitor_name = 'lab-crt'\r\n")
    path.write_bytes(bom + text.encode("utf-8" if bom == codecs.BOM_UTF8 else "utf-16-le"))
    return path


@pytest.mark.parametrize("resave, bom", [(excel_csv_utf8, codecs.BOM_UTF8),
                                         (notepad_unicode, codecs.BOM_UTF16_LE)],
                         ids=["excel_csv_utf8", "notepad_unicode"])
def test_readings_and_display_resaved_by_another_tool_give_the_same_calibration(
        resave, bom, reference, tmp_path, cli):
    """The BOM of Excel's 'CSV UTF-8' hid the first column (calibration_id read as empty),
    Notepad's UTF-16 gave a UnicodeDecodeError, and a display TOML with a BOM 'Invalid
    statement (at line 1, column 1)'."""
    cal, readings, _ = reference
    src = resave(Path(shutil.copy(READINGS, tmp_path / "readings.csv")))
    table = read_readings(src)
    assert table.frame.equals(readings)
    assert not table.notes
    display = _display_toml(tmp_path / "display.toml", bom)
    res = cli(["fit", src, "--out", tmp_path / "cal", "--display", display])
    assert res.returncode == 0, res.stderr
    again = load_calibration(tmp_path / "cal")
    assert (again.calibration_id, again.gamma_params) == (cal.calibration_id, cal.gamma_params)
    assert (again.width_cm, again.distance_cm, again.refresh_hz) == (33.1, 57.0, 100.0)


def test_readings_with_every_field_quoted_read_as_written(reference, tmp_path):
    """R's write.csv and MATLAB's writetable quote every field (RFC 4180)."""
    src = quoted(Path(shutil.copy(READINGS, tmp_path / "readings.csv")))
    table = read_readings(src)
    assert table.frame.equals(reference[1]) and not table.notes


@pytest.mark.parametrize("resave, problem", [
    (excel_unicode_text, "separated by tabs"),
    (lambda p: windows_code_page(p, column="device", value="Photo Research PR-650 µ"),
     "not UTF-8 text (byte 0xb5 on line 2"),
], ids=["excel_unicode_text", "windows_code_page"])
def test_readings_in_another_form_are_refused_with_the_fix(resave, problem, tmp_path, cli):
    src = resave(Path(shutil.copy(READINGS, tmp_path / "readings.csv")))
    res = cli(["fit", src, "--out", tmp_path / "cal"])
    assert res.returncode != 0
    last = res.stderr.strip().splitlines()[-1]
    assert problem in last and ("CSV with commas" in last or "save it as UTF-8" in last), last
    assert "Traceback" not in res.stderr


def test_a_calibrations_own_readings_resaved_as_utf16_are_refused_untouched(reference, tmp_path,
                                                                            cli):
    """The procedure appends to (and refits from) its readings.csv: in UTF-16 it cannot."""
    folder = Path(shutil.copytree(reference[2], tmp_path / "cal"))
    path = folder / "readings.csv"
    data = notepad_unicode(path).read_bytes()
    res = cli(["fit", "--out", folder])
    assert res.returncode != 0
    last = res.stderr.strip().splitlines()[-1]
    assert "UTF-16 text" in last and "save it as UTF-8" in last, last
    assert path.read_bytes() == data and not list(folder.glob("readings.csv.torn-*"))
