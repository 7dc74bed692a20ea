"""The report end to end: a folder of sessions in, index.html with the source study's numbers out."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from analysis.report import ReportExistsError, build_report, chi2_sentence, format_p
from analysis.typeii import WaldTest

from .sessions import write_sessions


def test_sentence_in_the_source_studys_style():
    t = WaldTest(term="depth", chi2=3716.0449, df=1, p=1e-300)
    assert chi2_sentence(t, 11) == "χ²(1, N = 11) = 3716.04, p < 0.001"
    assert format_p(0.0234) == "p = 0.023"
    assert format_p(1 / 101, floor=1 / 101) == "p ≤ 0.0099"


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory, design):
    folder = tmp_path_factory.mktemp("data")
    write_sessions(folder, design, np.random.default_rng(4), n_participants=4)
    # One incomplete session: a warning in the report, not an error.
    path = folder / "sessions" / "S02_s2.csv"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:31]))
    return folder


def test_report_has_figures_tables_and_warnings(tmp_path, data_dir, design):
    index = build_report(data_dir, tmp_path / "report", design, n_boot=30, progress=False)
    text = index.read_text(encoding="utf-8")
    assert "χ²(1, N = 4) = " in text
    assert "S02_s2.csv: incomplete session, 30 of" in text
    for png in ("depth_matches.png", "gloss_matches.png", "gloss_contours.png",
                "observers_gloss.png", "observers_depth.png"):
        assert f"src='{png}'" in text
        assert (tmp_path / "report" / png).stat().st_size > 10_000
    results = json.loads((tmp_path / "report" / "results.json").read_text(encoding="utf-8"))
    assert results["bootstrap"]["gloss"]["n_boot"] == 30
    assert set(results["models"]) == {"gloss", "depth", "gloss_crossed", "depth_crossed"}
    assert results["bootstrap"]["gloss_crossed"]["n_ok"] > 0
    crossed = results["models"]["gloss_crossed"]["fit"]
    assert [r["group"] for r in crossed["random"]] == ["stimulus_id", "participant"]
    # The source study's findings, checked under its models and under the crossed ones.
    patterns = results["source_study_pattern"]
    assert patterns["respecified"]["models"] == {"gloss": "gloss_crossed",
                                                 "depth": "depth_crossed"}
    assert set(patterns["respecified"]["findings"]) == set(patterns["source"]["findings"])
    assert "holds: gloss_crossed / depth_crossed" in text
    assert "(1 | stimulus_id)" in text
    assert results["n_trials"] == 4 * design.n_stimuli - design.sessions.trials_per_session + 30


def test_existing_report_is_never_overwritten(tmp_path, data_dir, design):
    out = tmp_path / "report"
    out.mkdir()
    (out / "index.html").write_text("keep me")
    with pytest.raises(ReportExistsError, match="never overwritten"):
        build_report(data_dir, out, design, n_boot=0, progress=False)
    assert (out / "index.html").read_text() == "keep me"


def test_command_line(tmp_path, data_dir):
    cmd = [sys.executable, "-m", "analysis", "report", str(data_dir), "--out",
           str(tmp_path / "r"), "--bootstrap", "0", "--quiet"]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert first.returncode == 0, first.stderr
    assert "report: " in first.stdout
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert again.returncode == 1
    assert "never overwritten" in again.stderr
    bad = subprocess.run([sys.executable, "-m", "analysis", "report", str(tmp_path / "none"),
                          "--out", str(tmp_path / "r2")], capture_output=True, text=True,
                         timeout=300, check=False)
    assert bad.returncode == 1 and "no session files" in bad.stderr


def test_gap_is_passed_through():
    out = subprocess.run([sys.executable, "-m", "analysis", "gap", "--help"],
                         capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0
    assert "benchmark" in out.stdout and "diagnose" in out.stdout


def test_no_metamers_for_observers_without_a_depth_effect(tmp_path, design):
    write_sessions(tmp_path / "data", design, np.random.default_rng(3), n_participants=11,
                   kind="ideal")
    build_report(tmp_path / "data", tmp_path / "r", design, n_boot=0, progress=False)
    results = json.loads((tmp_path / "r" / "results.json").read_text(encoding="utf-8"))
    assert results["metamers"] == []
    findings = results["source_study_pattern"]["source"]["findings"]
    assert not findings["depth effect on estimated gloss"]["holds"]


def test_imagestats_is_passed_through_or_named_as_missing():
    import importlib.util

    out = subprocess.run([sys.executable, "-m", "analysis", "imagestats", "--help"],
                         capture_output=True, text=True, timeout=120, check=False)
    if importlib.util.find_spec("analysis.imagestats") is None:
        assert out.returncode == 2 and "not built yet" in out.stderr
    else:
        assert out.returncode == 0, out.stderr


def test_command_line_lists_simulated_data_and_shares_the_report(tmp_path, design):
    """Simulated participants in the data folder are named on the command line and in the
    report, and the report's files get the umask's permissions (not 0600)."""
    import os

    import pandas as pd

    write_sessions(tmp_path / "data", design, np.random.default_rng(5), n_participants=3)
    path = tmp_path / "data" / "sessions" / "S03_s1.csv"
    frame = pd.read_csv(path, dtype=str)
    frame.assign(calibration_id="simulated").to_csv(path, index=False)
    res = subprocess.run([sys.executable, "-m", "analysis", "report", str(tmp_path / "data"),
                          "--out", str(tmp_path / "r"), "--bootstrap", "0", "--quiet"],
                         capture_output=True, text=True, timeout=300, check=False,
                         preexec_fn=lambda: os.umask(0o002))
    assert res.returncode == 0, res.stderr
    assert "warning: simulated data included: participants ['S03']" in res.stderr
    text = (tmp_path / "r" / "index.html").read_text(encoding="utf-8")
    assert "simulated data included" in text and "Calibrations in these data" in text
    for name in ("index.html", "results.json", "depth_matches.png"):
        assert (tmp_path / "r" / name).stat().st_mode & 0o777 == 0o664, name
