"""A participant never sees a stimulus twice (issue 33, finding 3; with findings 2, 4 and 8).

One real session (the app under Xvfb, a simulated observer answering through XTEST, the small
design, a calibration fitted by ``calibration fit``) is paused after three trials; then, as an
operator might: the session CSV moved aside (as the "DAMAGED ... move it aside" advice said),
rows cut from its middle, a relative --data from another directory, ``p01`` typed for ``P01``,
a run history written by a PC whose clock ran a year ahead, the calibration refitted after a
reading was edited (finding 4: the session recorded its SHA-256). The refusals happen before any
window opens, so they run in this process; the session resumes and completes at the end.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from datetime import UTC, datetime, timedelta

import numpy as np
import pandas as pd
import pytest

from calibration import SimulatedCRT
from calibration.__main__ import main as calibration_main
from experiment.__main__ import main
from tests.calibration.test_check import _readings

from .conftest import run_app


def _args(design_path, f, participant="P01", data=None):
    return ["--design", str(design_path), "run", "--participant", participant, "--session", "1",
            "--stimuli", str(f["manifest"]), "--calibration", str(f["calibration"]), "--data",
            str(data or f["data"]), "--simulate", "ideal", "--fast"]


@pytest.mark.xvfb
@pytest.mark.slow
def test_a_session_never_starts_over_while_a_record_of_it_exists(
        small_design_path, session_files, tmp_path, monkeypatch, capsys):
    f = dict(session_files)
    data = f["data"]
    readings = tmp_path / "readings.csv"
    yesterday = (datetime.now(UTC) - timedelta(days=1)).strftime("%Y-%m-%dT%H:%M:%SZ")
    (_readings(SimulatedCRT(), np.random.default_rng(1), cal_id="test")
     .assign(timestamp_utc=yesterday).to_csv(readings, index=False))
    cal_dir = tmp_path / "cal-fitted"
    assert calibration_main(["fit", str(readings), "--out", str(cal_dir)]) == 0
    f["calibration"] = cal_dir / "calibration.json"
    sha = hashlib.sha256(f["calibration"].read_bytes()).hexdigest()
    res = run_app(*_args(small_design_path, f), "--simulate-quit-at", "4")
    assert res.returncode == 3, res.stderr
    csv = data / "sessions" / "P01_s1.csv"
    assert len(csv.read_text().splitlines()) == 4  # header + 3 answered trials

    # (b) The session CSV moved aside: the slider file and the run history still record 3.
    aside = tmp_path / "aside.csv"
    shutil.move(csv, aside)
    assert main(_args(small_design_path, f)) == 2
    err = capsys.readouterr().err
    assert "holds 0 answered trial(s)" in err and "records 3" in err
    assert "Put the original P01_s1.csv back" in err
    assert not csv.exists()  # nothing started over
    assert main(["status", "--participant", "P01", "--data", str(data)]) == 1
    assert "DAMAGED" in capsys.readouterr().out

    # (8) A row cut from the middle: `status` says which trial is missing.
    lines = aside.read_text().splitlines(keepends=True)
    csv.write_text("".join(lines[:2] + lines[3:]))
    assert main(["status", "--participant", "P01", "--data", str(data)]) == 1
    assert "trials [2] are missing" in capsys.readouterr().out
    shutil.copy(aside, csv)
    assert main(["status", "--participant", "P01", "--data", str(data)]) == 0
    capsys.readouterr()

    # (a) A relative --data from another directory would have started over in ./data there.
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    args = _args(small_design_path, f, data="data")
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "relative path" in err and f"--data {elsewhere / 'data'}" in err
    assert main(["plan", "--participant", "P01", "--data", "data"]) == 2
    assert not (elsewhere / "data").exists()

    # (c) p01 (or P01 with spaces) after P01: refused, naming the recorded id.
    for typed, said in (("p01", "differs only in case from 'P01'"),
                        (" P01", "has spaces around it; type --participant P01")):
        assert main(_args(small_design_path, f, participant=typed)) == 2
        assert said in capsys.readouterr().err
        assert main(["plan", "--participant", typed, "--data", str(data)]) in (1, 2)
        assert said in capsys.readouterr().err
    assert main(["status", "--participant", "p01", "--data", str(data)]) == 2
    assert "--participant P01" in capsys.readouterr().err
    assert sorted(p.name for p in (data / "plans").iterdir()) == ["P01_plan.csv"]

    # (4) A reading edited, the folder refitted: the refit is a new calibration beside the old
    # one, whose bytes (and so the SHA-256 the session recorded) are kept.
    edited = pd.read_csv(cal_dir / "readings.csv")
    edited.loc[0, "luminance_cd_m2"] *= 1.5
    edited.to_csv(cal_dir / "readings.csv", index=False)
    assert calibration_main(["fit", "--out", str(cal_dir)]) == 0
    assert "is kept as it was" in capsys.readouterr().out
    assert hashlib.sha256(f["calibration"].read_bytes()).hexdigest() == sha
    beside = [p for p in tmp_path.iterdir() if p.name.startswith("cal-fitted-refit-")]
    assert len(beside) == 1 and (beside[0] / "calibration.json").is_file()
    assert json.loads((beside[0] / "calibration.json").read_text())["calibration_id"] == (
        "test-refit-" + beside[0].name.rsplit("-", 1)[1])

    # (2) A run history stamped a year ahead (a lab PC's clock): the resume warns.
    runs = data / "logs" / "P01_s1_runs.jsonl"
    ahead = (datetime.now(UTC) + timedelta(days=365)).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    with runs.open("a") as fh:
        fh.write(json.dumps({"event": "note", "utc": ahead}) + "\n")
    res = run_app(*_args(small_design_path, f))
    assert res.returncode == 0, res.stderr
    assert "newest recorded time" in res.stdout and "365.0 days after this PC's clock" in res.stdout
    assert len(csv.read_text().splitlines()) == 7  # trials 4-6 added, none repeated
