"""The analysis's inputs as a lab's tools re-save them (issue 29 item 6, issue 33 items 6 and 7):
session folders, any CSV given to ``analysis fit`` or ``analysis units``, and the display layer's
readings give the numbers the files as written give; a ';' file is refused naming the
separator and the fix (it said "not a column").
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from analysis.__main__ import main
from analysis.gap import GapError
from analysis.lmm import LmmFit, fit
from analysis.load import load_sessions
from tests.tool_files import (
    crlf,
    excel_csv_utf8,
    excel_semicolons,
    notepad_unicode,
    quoted,
    windows_code_page,
)

from .sessions import write_sessions
from .test_fit_command import REF

FORMULA = "y ~ gloss * depth + (1 + gloss + depth | participant)"


@pytest.mark.parametrize("resave", [excel_csv_utf8, notepad_unicode], ids=lambda f: f.__name__)
def test_fit_of_a_csv_resaved_by_another_tool_is_the_same_fit(resave, tmp_path, capsys):
    src = resave(shutil.copy(REF / "unbalanced_5_data.csv", tmp_path / "data.csv"))
    assert main(["fit", str(src), "--formula", FORMULA, "--out", str(tmp_path / "f"),
                 "--quiet"]) == 0, capsys.readouterr().err
    record = json.loads((tmp_path / "f" / "fit.json").read_text())
    data = pd.read_csv(REF / "unbalanced_5_data.csv", dtype={"participant": str})
    assert LmmFit(**record["fit"]) == fit(FORMULA, data)


def test_fit_of_a_semicolon_csv_names_the_separator(tmp_path, capsys):
    src = excel_semicolons(shutil.copy(REF / "unbalanced_5_data.csv", tmp_path / "data.csv"))
    assert main(["fit", str(src), "--formula", FORMULA, "--out", str(tmp_path / "f")]) == 1
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "separated by semicolons" in last and "CSV UTF-8" in last, last
    assert "not a column" not in last
    assert not (tmp_path / "f" / "fit.json").exists()
    assert main(["units", str(src)]) == 1
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "separated by semicolons" in last and last.count(str(src)) == 1, last


def test_a_session_folder_resaved_by_other_tools_loads_as_written(tmp_path, design, capsys):
    """Each participant's files re-saved by another tool (Excel, R, Notepad): the same trials
    for the report and fit (load_sessions) and the gap's observer layer, and `analysis units`
    gives the same table."""
    from analysis.gap.observer.data import read_session_csvs

    paths = write_sessions(tmp_path / "data", design, np.random.default_rng(11),
                           n_participants=3)
    before = load_sessions(tmp_path / "data", design)
    gap_before = read_session_csvs(tmp_path / "data")
    assert main(["units", str(paths[0])]) == 0
    units = capsys.readouterr().out
    for path, resave in zip(paths, [excel_csv_utf8, crlf, quoted, notepad_unicode] * 3):
        resave(path)
    after = load_sessions(tmp_path / "data", design)
    pd.testing.assert_frame_equal(after.frame, before.frame)
    assert after.warnings == before.warnings
    pd.testing.assert_frame_equal(read_session_csvs(tmp_path / "data"), gap_before)
    assert main(["units", str(paths[0])]) == 0
    assert capsys.readouterr().out == units


@pytest.mark.filterwarnings("ignore:.*readings file .* is missing")
def test_display_readings_resaved_by_excel_are_read_as_written(tmp_path):
    """The display layer's reader (readings.csv beside a calibration)."""
    from analysis.gap.display.data import load_display
    from analysis.gapbench import inject

    rng = np.random.default_rng(5)
    inject.write_calibration(rng, tmp_path / "cal")
    path = inject.write_readings(inject.simulate_readings(rng), tmp_path / "real")
    before, _ = load_display(path, tmp_path / "cal")
    for resave in (excel_csv_utf8, notepad_unicode):
        shutil.copy(path, tmp_path / "copy.csv")
        after, _ = load_display(resave(tmp_path / "copy.csv"), tmp_path / "cal")
        pd.testing.assert_frame_equal(after, before)
    # A Windows code page: the layer's error (gap diagnose prints it), not a traceback.
    shutil.copy(path, tmp_path / "copy.csv")
    windows_code_page(tmp_path / "copy.csv", column="device", value="PR-650 µ")
    with pytest.raises(GapError, match=r"not UTF-8 text \(byte 0xb5 on line 2.*save it as UTF-8"):
        load_display(tmp_path / "copy.csv", tmp_path / "cal")
