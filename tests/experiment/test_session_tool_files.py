"""Session CSVs, plans and observers.toml as a lab's tools re-save them (issue 29 item 6, issue 33
items 3b, 6, 7): read as the app's own, or refused naming the separator and the fix.

The files are the app's (``python -m experiment simulate`` and ``plan``), then re-saved byte for
byte as Excel, Notepad or R would (:mod:`tests.tool_files`); every check goes through the
command line an operator types.
"""

from __future__ import annotations

import codecs
import shutil

import pandas as pd
import pytest

from experiment import read_session
from experiment.__main__ import main
from experiment.datafile import SESSION_COLUMNS, SessionWriter, session_path
from labfiles import LabFileError
from tests.tool_files import (
    crlf,
    excel_csv_utf8,
    excel_semicolons,
    excel_unicode_text,
    notepad_unicode,
    quoted,
)

RESAVED = [excel_csv_utf8, crlf, quoted, notepad_unicode]
REFUSED = [(excel_semicolons, "separated by semicolons"), (excel_unicode_text, "separated by tabs")]


@pytest.fixture(scope="module")
def simulated(tmp_path_factory, small_design_path):
    """Two simulated participants' complete sessions (the app's writer), kept read-only."""
    data = tmp_path_factory.mktemp("simulated") / "data"
    assert main(["--design", str(small_design_path), "simulate", "--observer", "ideal",
                 "--participants", "S01", "S02", "--data", str(data), "--seed", "3"]) == 0
    return data


@pytest.fixture
def data(tmp_path, simulated):
    """A copy of the simulated data whose S01 session 1 stops after trial 2 (to resume)."""
    copy = tmp_path / "data"
    shutil.copytree(simulated, copy)
    path = session_path(copy, "S01", 1)
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    path.write_text("".join(lines[:3]), encoding="utf-8")
    return copy


def _status(design_path, data, capsys) -> tuple[int, str]:
    rc = main(["--design", str(design_path), "status", "--participant", "S01", "--data",
               str(data)])
    return rc, capsys.readouterr().out


@pytest.mark.parametrize("resave", RESAVED, ids=lambda f: f.__name__)
def test_status_reads_a_session_resaved_by_another_tool(resave, small_design_path, data, capsys):
    """Issue 33, 3(b): the Excel re-save was called DAMAGED ("missing [], unexpected []")."""
    before = read_session(session_path(data, "S01", 1))
    resave(session_path(data, "S01", 1))
    resave(session_path(data, "S01", 2))
    rc, out = _status(small_design_path, data, capsys)
    assert rc == 0, out
    assert "session 1: 2/6 trials, to resume" in out
    assert "session 2: 6/6 trials, complete" in out
    pd.testing.assert_frame_equal(read_session(session_path(data, "S01", 1)), before)


@pytest.mark.parametrize("resave, problem", REFUSED, ids=lambda v: getattr(v, "__name__", ""))
def test_status_names_the_separator_of_a_session_and_the_fix(resave, problem, small_design_path,
                                                             data, capsys):
    """Issue 33, 7: a ';' file got "missing [], unexpected []" with "move it aside"."""
    resave(session_path(data, "S01", 1))
    rc, out = _status(small_design_path, data, capsys)
    assert rc == 1
    line = next(x for x in out.splitlines() if "session 1:" in x)
    assert problem in line and "save it as 'CSV UTF-8 (Comma delimited) (*.csv)'" in line
    assert "missing" not in line


def test_a_resumed_session_appends_in_the_files_own_line_ends(simulated, data):
    """The rows the app appends to an Excel re-save (BOM, CRLF) end in CRLF like the rest, the
    BOM stays, and every trial reads back once."""
    full = read_session(session_path(simulated, "S01", 1))
    path = excel_csv_utf8(session_path(data, "S01", 1))
    with SessionWriter(data, "S01", 1, sliders=False) as writer:
        writer.extend(full.iloc[2:][list(SESSION_COLUMNS)].to_dict("records"))
    raw = path.read_bytes()
    assert raw.startswith(codecs.BOM_UTF8)
    assert raw.count(b"\r\n") == raw.count(b"\n") == 7
    pd.testing.assert_frame_equal(read_session(path), full)


def test_a_utf16_session_is_refused_for_appending_with_the_fix(data):
    """Read (status, analysis) but never appended to in another encoding."""
    path = notepad_unicode(session_path(data, "S01", 1))
    before = path.read_bytes()
    with pytest.raises(LabFileError, match=r"UTF-16 text.*save it as UTF-8"):
        SessionWriter(data, "S01", 1, sliders=False).__enter__()
    assert path.read_bytes() == before
    assert not list(path.parent.glob("*.torn-*"))


def test_fit_observer_reads_pilot_sessions_resaved_by_excel(tmp_path):
    """A pilot's session files re-saved by Excel (BOM, CRLF) and Notepad (UTF-16) fit the same
    observers.toml as the files the app wrote (the shipped design: enough trials to fit)."""
    pilot = tmp_path / "pilot"
    assert main(["simulate", "--observer", "ideal", "--participants", "S01", "S02",
                 "--data", str(pilot), "--seed", "5"]) == 0
    ref = tmp_path / "ref.toml"
    assert main(["fit-observer", str(pilot), "--kind", "ideal", "--out", str(ref)]) == 0
    for path, resave in zip(sorted((pilot / "sessions").glob("*.csv")),
                            [excel_csv_utf8, notepad_unicode] * 9):
        resave(path)
    out = tmp_path / "observers.toml"
    assert main(["fit-observer", str(pilot), "--kind", "ideal", "--out", str(out)]) == 0

    def fitted(path):
        return [x for x in path.read_text().splitlines() if "utc" not in x]

    assert fitted(out) == fitted(ref)


@pytest.mark.parametrize("resave", [excel_csv_utf8, quoted, notepad_unicode],
                         ids=lambda f: f.__name__)
def test_a_plan_resaved_by_another_tool_is_the_same_plan(resave, small_design_path, tmp_path,
                                                         capsys):
    data = tmp_path / "data"
    args = ["--design", str(small_design_path), "plan", "--participant", "P01", "--data",
            str(data)]
    assert main(args) == 0
    first = capsys.readouterr().out
    resave(data / "plans" / "P01_plan.csv")
    assert main(args) == 0
    assert capsys.readouterr().out == first


def test_a_semicolon_plan_is_refused_naming_the_separator(small_design_path, tmp_path, capsys):
    data = tmp_path / "data"
    args = ["--design", str(small_design_path), "plan", "--participant", "P01", "--data",
            str(data)]
    assert main(args) == 0
    excel_semicolons(data / "plans" / "P01_plan.csv")
    assert main(args) != 0
    err = capsys.readouterr().err
    assert "separated by semicolons" in err and "CSV UTF-8" in err


@pytest.mark.parametrize("bom", [codecs.BOM_UTF8, codecs.BOM_UTF16_LE], ids=["utf8", "utf16"])
def test_observers_toml_with_a_bom_is_read(bom, small_design_path, tmp_path):
    """Notepad's BOM (UTF-8 or "Unicode") on an observers.toml gave "Invalid statement"."""
    from experiment.observers import default_observers_path

    text = default_observers_path().read_text(encoding="utf-8").replace("\n", "\r\n")
    params = tmp_path / "observers.toml"
    params.write_bytes(bom + text.encode("utf-8" if bom == codecs.BOM_UTF8 else "utf-16-le"))
    assert main(["--design", str(small_design_path), "simulate", "--observer", "humanlike",
                 "--participants", "S09", "--data", str(tmp_path / "d"),
                 "--observer-params", str(params)]) == 0
    assert session_path(tmp_path / "d", "S09", 1).is_file()


@pytest.mark.slow
@pytest.mark.xvfb
def test_a_session_resaved_by_excel_resumes_where_it_stopped(small_design, small_design_path,
                                                             session_files, capsys):
    """Issue 33, 3(b), as the operator meets it: the app quits at trial 3, the file is opened
    and saved in Excel ("CSV UTF-8": a BOM, CRLF), and the same command continues at trial 3:
    every stimulus shown once, every line CRLF (it was called DAMAGED, with "move it aside",
    which restarted the session at trial 1)."""
    import subprocess
    import sys

    from .conftest import REPO, app_env

    f = session_files
    cmd = [sys.executable, "-m", "experiment", "--design", str(small_design_path), "run",
           "--participant", "Q1", "--session", "1", "--stimuli", str(f["manifest"]),
           "--calibration", str(f["calibration"]), "--data", str(f["data"]),
           "--simulate", "humanlike", "--fast"]

    def run(*extra):
        return subprocess.run([*cmd, *extra], cwd=REPO, env=app_env(), capture_output=True,
                              text=True, timeout=300, check=False)

    assert run("--simulate-quit-at", "3").returncode == 3
    path = session_path(f["data"], "Q1", 1)
    written = path.read_bytes()
    # Saved as Notepad's "Unicode": refused before any window opens, the file untouched.
    notepad_unicode(path)
    utf16 = path.read_bytes()
    res = run()
    assert res.returncode == 2, res.stderr
    assert "UTF-16 text" in res.stderr and "save it as UTF-8" in res.stderr
    assert "Traceback" not in res.stderr and path.read_bytes() == utf16
    path.write_bytes(written)
    excel_csv_utf8(path)
    assert main(["--design", str(small_design_path), "status", "--participant", "Q1",
                 "--data", str(f["data"])]) == 0
    assert "session 1: 2/6 trials, to resume" in capsys.readouterr().out
    res = run()
    assert res.returncode == 0, res.stderr
    done = read_session(path)
    assert done["trial"].tolist() == list(range(1, 7))
    assert not done["stimulus_id"].duplicated().any()
    raw = path.read_bytes()
    assert raw.startswith(codecs.BOM_UTF8) and raw.count(b"\r\n") == raw.count(b"\n") == 7
