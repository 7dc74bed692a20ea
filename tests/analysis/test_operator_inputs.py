"""Operator faults at the analysis command lines (issue 33, items 5-7), run as an operator
would: ``python -m analysis`` main() on real files. Each fault gets one line on stderr naming
the problem and what to type next, never a traceback, and mixed inputs are refused."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.__main__ import main
from tests.readonly import read_only_folder

DEMO = Path(__file__).resolve().parents[1] / "data" / "demo_sessions"


def _run(capsys, *argv) -> tuple[int, str]:
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return rc, err


def _last_line(err: str) -> str:
    return err.strip().splitlines()[-1]


@pytest.mark.parametrize("command", ["report", "fit", "gap"])
def test_read_only_out_is_one_line_before_any_work(command, tmp_path, capsys):
    """A read-only --out was a traceback (after the fit, for fit); now refused at once."""
    with read_only_folder(tmp_path) as ro:
        out = ro / "result"
        argv = {"report": ["report", DEMO / "humanlike", "--out", out, "--bootstrap", "0"],
                "fit": ["fit", DEMO / "humanlike", "--formula",
                        "gloss_match_pct ~ gloss + (1 | participant)", "--out", out],
                "gap": ["gap", "diagnose", "--layer", "observer", "--real", DEMO / "humanlike",
                        "--sim", DEMO / "ideal", "--out", out]}[command]
        rc, err = _run(capsys, *argv)
    assert rc != 0
    line = _last_line(err)
    assert "Read-only file system" in line and str(out) in line and "--out" in line


def test_out_naming_an_existing_file_is_one_line(tmp_path, capsys):
    afile = tmp_path / "notes.txt"
    afile.write_text("keep me")
    rc, err = _run(capsys, "report", DEMO / "humanlike", "--out", afile, "--bootstrap", "0")
    assert rc == 1 and "is a file, not a folder" in err and "--out" in _last_line(err)
    assert afile.read_text() == "keep me"


def test_jobs_zero_names_the_option(tmp_path, capsys):
    rc, err = _run(capsys, "report", DEMO / "humanlike", "--out", tmp_path / "r", "--jobs", "0")
    assert rc == 2 and "--jobs 0: use 1 or more" in err


def test_a_layer_named_twice_is_refused(tmp_path, capsys):
    """--layer all with observer=A,observer=B kept B silently."""
    rc, err = _run(capsys, "gap", "diagnose", "--layer", "all",
                   "--real", f"observer={DEMO / 'humanlike'},observer={DEMO / 'ideal'}",
                   "--sim", f"observer={DEMO / 'ideal'}", "--out", tmp_path / "g")
    assert rc == 2 and "observer is named twice" in err
    assert not (tmp_path / "g" / "index.html").exists()


def test_display_real_and_sim_swapped_says_so(tmp_path, design, capsys):
    """A calibration as --real and readings as --sim printed 'not valid JSON'."""
    from calibration import default_calibration, save_calibration

    cal = save_calibration(default_calibration(design), tmp_path / "cal" / "calibration.json")
    readings = Path(__file__).resolve().parents[1] / "data" / "calibration" / \
        "ptb_apple17_crt_2000" / "readings.csv"
    rc, err = _run(capsys, "gap", "diagnose", "--layer", "display", "--real", cal,
                   "--sim", readings, "--out", tmp_path / "g")
    assert rc == 2 and "swapped?" in err and "--sim the calibration" in err


def test_a_participant_copied_under_another_id_is_refused(tmp_path, capsys):
    """Identical answers, times and timestamps under two ids were analysed as two people."""
    sessions = tmp_path / "data" / "sessions"
    shutil.copytree(DEMO / "humanlike", sessions)
    text = (sessions / "D02_s1.csv").read_text()
    (sessions / "D09_s1.csv").write_text(text.replace("\nD02,", "\nD09,"))
    rc, err = _run(capsys, "report", tmp_path / "data", "--out", tmp_path / "r",
                   "--bootstrap", "0", "--quiet")
    assert rc == 1
    assert "['D02', 'D09'] share 81 trials" in err and "Move the copy's file out" in err
    assert not (tmp_path / "r" / "index.html").exists()


@pytest.fixture
def small_csv(tmp_path) -> Path:
    rng = np.random.default_rng(3)
    g = np.repeat([f"p{i}" for i in range(6)], 8)
    x = np.tile(np.arange(8.0), 6)
    frame = pd.DataFrame({"y": 2 + 0.5 * x + rng.normal(0, 1, g.size), "x": x, "g": g})
    path = tmp_path / "data.csv"
    frame.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("formula, said", [
    ("y ~ x + offset(x) + (1 | g)", "offset() is unsupported: subtract the offset"),
    ("log(y) ~ x + (1 | g)", "is a transformed column, which is unsupported"),
    ("y ~ s(x) + (1 | g)", "s() is unsupported: smooth terms"),
    ("cbind(y, x) ~ x + (1 | g)", "cbind() is unsupported"),
    ("y ~ x + (1 | g) junk", "is not one random-effect term"),
])
def test_unsupported_formula_terms_are_named(formula, said, small_csv, tmp_path, capsys):
    """These said 'not a column' (or 'no random-effect term' for trailing junk)."""
    rc, err = _run(capsys, "fit", small_csv, "--formula", formula, "--out", tmp_path / "f")
    assert rc == 1 and said in err
    assert "not a column" not in err and "no random-effect term" not in err


def test_non_numeric_response_names_row_and_value(small_csv, tmp_path, capsys):
    frame = pd.read_csv(small_csv)
    frame["y"] = frame["y"].astype(object)
    frame.loc[4, "y"] = "n/a?"
    frame.to_csv(small_csv, index=False)
    rc, err = _run(capsys, "fit", small_csv, "--formula", "y ~ x + (1 | g)", "--out",
                   tmp_path / "f")
    assert rc == 1 and "data row 5 (line 6" in err and "'n/a?'" in err


def test_semicolon_csv_names_the_separator(small_csv, tmp_path, capsys):
    semi = tmp_path / "excel.csv"
    pd.read_csv(small_csv).to_csv(semi, index=False, sep=";", decimal=",")
    rc, err = _run(capsys, "fit", semi, "--formula", "y ~ x + (1 | g)", "--out", tmp_path / "f")
    assert rc == 1 and "separated by semicolons" in err and "CSV UTF-8" in err


def test_a_simulation_covering_half_the_stimuli_is_named_a_mismatch(tmp_path, design):
    """The simulated sessions (real files, cut to gloss levels 1-5) cover 36 of the 81 gloss x
    depth levels of the real ones: the warning the report shows (stderr, index.html,
    diagnosis.json) says how much is covered, not only that the designs differ."""
    from analysis.gap.observer.data import check_sim, load_sim, read_session_csvs

    half = tmp_path / "half"
    half.mkdir()
    for path in sorted((DEMO / "ideal").glob("*.csv")):
        frame = pd.read_csv(path)
        frame[frame["gloss_level"] <= 5].to_csv(half / path.name, index=False)
    notes = check_sim(read_session_csvs(DEMO / "humanlike"), load_sim(half, design))
    assert any(n.startswith("mismatch: the simulation covers 36 of the 81 gloss x depth levels")
               for n in notes), notes


def test_second_round_refusals(small_csv, tmp_path, capsys, monkeypatch):
    """An empty --out wrote the report into the current folder; a random term given twice was
    fitted; R's '.' was 'not a column'; an observers TOML as --real got a list of columns."""
    monkeypatch.chdir(tmp_path)
    rc, err = _run(capsys, "report", DEMO / "humanlike", "--out", "", "--bootstrap", "0")
    assert rc == 1 and "--out is empty" in err and not (tmp_path / "index.html").exists()
    rc, err = _run(capsys, "fit", small_csv, "--formula", "y ~ x + (1 | g) + (1 | g)",
                   "--out", tmp_path / "f")
    assert rc == 1 and "random term (1 | g) is given twice" in err
    rc, err = _run(capsys, "fit", small_csv, "--formula", "y ~ . + (1 | g)", "--out",
                   tmp_path / "f")
    assert rc == 1 and "'.' (every other column) is unsupported" in err
    toml = tmp_path / "observers.toml"
    toml.write_text("[humanlike]\n")
    rc, err = _run(capsys, "gap", "diagnose", "--layer", "observer", "--real", toml, "--sim",
                   DEMO / "ideal", "--out", tmp_path / "g")
    assert rc == 2 and "is not a session CSV (an observers TOML is a simulation" in err
