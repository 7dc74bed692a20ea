"""The smaller silences of issue 33 (finding 8), each run through the command line on real files.

A design value of nan or inf, a calibration named ``simulated`` (the id of simulated observers'
rows), a negative response time in a session file, renders corrected with an 84-day-old
calibration, and a umask that denies the owner reading the files it writes. (A print slab of
negative thickness: ``tests/test_no_overwrite.py``; a row cut from a session's middle:
``tests/experiment/test_session_identity.py``.)
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from calibration import SimulatedCRT
from calibration.__main__ import main as calibration_main
from studydesign import default_design_path
from studydesign.__main__ import main as studydesign_main
from tests.calibration.test_check import _readings

REPO = Path(__file__).resolve().parents[1]


def _run(module, *args, **kw):
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=REPO,
                          capture_output=True, text=True, check=False, timeout=300, **kw)


def test_non_finite_design_values_are_refused(tmp_path, capsys):
    text = default_design_path().read_text(encoding="utf-8")
    for key in ("depth_boxcox_lambda", "nominal_refresh_hz"):
        before = next(line for line in text.splitlines() if line.startswith(f"{key} ="))
        for bad in ("nan", "inf"):
            path = tmp_path / f"{key}-{bad}.toml"
            path.write_text(text.replace(before, f"{key} = {bad}"), encoding="utf-8")
            assert studydesign_main(["--design", str(path), "check"]) == 1
            err = capsys.readouterr().err
            assert f"{key} = {bad} is not a finite number" in err, err


def test_a_calibration_may_not_take_a_reserved_id(tmp_path, capsys):
    readings = tmp_path / "readings.csv"
    now = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    (_readings(SimulatedCRT(), np.random.default_rng(1), cal_id="simulated")
     .assign(timestamp_utc=now).to_csv(readings, index=False))
    assert calibration_main(["fit", str(readings), "--out", str(tmp_path / "a")]) == 1
    assert "'simulated' is reserved" in capsys.readouterr().err
    assert calibration_main(["fit", str(readings), "--out", str(tmp_path / "b"),
                             "--calibration-id", "Default"]) == 1
    assert "--calibration-id" in capsys.readouterr().err
    assert not (tmp_path / "a" / "calibration.json").exists()


def test_a_negative_response_time_stops_the_analysis(tmp_path):
    data = tmp_path / "data"
    shutil.copytree(REPO / "tests/data/demo_sessions/ideal", data / "sessions")
    path = data / "sessions" / "D01_s1.csv"
    frame = pd.read_csv(path, dtype=str, keep_default_na=False)
    frame.loc[4, "rt_s"] = "-1.25"
    frame.to_csv(path, index=False)
    res = _run("analysis", "report", data, "--out", tmp_path / "report", "--bootstrap", "10")
    assert res.returncode != 0 and "Traceback" not in res.stderr
    assert "trial 5 has rt_s = -1.25" in res.stderr
    assert not (tmp_path / "report" / "index.html").exists()


@pytest.mark.slow
def test_renders_with_an_old_calibration_are_named(tmp_path):
    readings = tmp_path / "readings.csv"
    old = (datetime.now(UTC) - timedelta(days=84)).strftime("%Y-%m-%dT%H:%M:%SZ")
    (_readings(SimulatedCRT(), np.random.default_rng(1), cal_id="crt-aug")
     .assign(timestamp_utc=old).to_csv(readings, index=False))
    assert calibration_main(["fit", str(readings), "--out", str(tmp_path / "cal")]) == 0
    res = _run("stimuli", "render", "--set", "preview", "--limit", "1", "--out", tmp_path / "r",
               "--workers", "0", "--size", "16", "--spp", "1", "--no-progress",
               "--calibration", tmp_path / "cal" / "calibration.json")
    assert res.returncode == 0, res.stderr
    assert "calibration crt-aug" in res.stderr and "84.0 days old" in res.stderr
    assert "recalibrate" in res.stderr


def test_a_umask_denying_the_owner_is_warned_and_relaxed(tmp_path):
    out = tmp_path / "stimuli.csv"
    res = subprocess.run(
        f"umask 0477 && {sys.executable} -m studydesign stimuli --out {out}", shell=True,
        cwd=REPO, capture_output=True, text=True, check=False, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "the umask 0477 denies you reading or writing" in res.stderr
    assert "umask 022" in res.stderr
    assert os.stat(out).st_mode & 0o600 == 0o600
