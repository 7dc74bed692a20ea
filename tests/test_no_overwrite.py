"""No command replaces a file without being told to (issue 33, finding 4; and 8's print slab).

Each command of the operator's is run on real files as the issue found it: ``studydesign
stimuli --out`` onto a copy of a session CSV, ``calibration default --out`` onto a measured
calibration.json, ``calibration fit`` into a folder holding a calibration, ``stimuli
export-print`` onto an existing mesh. Each refuses, naming the file and the option; ``--force``
(where the command has it) replaces. The refit of a calibration a session recorded is in
``tests/experiment/test_session_identity.py``.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from calibration import SimulatedCRT
from calibration.__main__ import main as calibration_main
from studydesign.__main__ import main as studydesign_main
from tests.calibration.test_check import _readings

REPO = Path(__file__).resolve().parents[1]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_studydesign_stimuli_and_calibration_default_keep_existing_files(tmp_path, capsys):
    session = tmp_path / "P01_s1.csv"
    session.write_text("participant,session,trial\nP01,1,1\n")
    before = _sha(session)
    assert studydesign_main(["stimuli", "--out", str(session)]) == 1
    err = capsys.readouterr().err
    assert f"{session} exists" in err and "--force" in err
    assert _sha(session) == before
    assert studydesign_main(["stimuli", "--out", str(session), "--force"]) == 0
    assert session.read_text().startswith("stimulus_id")

    readings = tmp_path / "readings.csv"
    now = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    (_readings(SimulatedCRT(), np.random.default_rng(1), cal_id="lab")
     .assign(timestamp_utc=now).to_csv(readings, index=False))
    cal = tmp_path / "cal"
    assert calibration_main(["fit", str(readings), "--out", str(cal)]) == 0
    measured = cal / "calibration.json"
    sha = _sha(measured)
    capsys.readouterr()
    assert calibration_main(["default", "--out", str(measured)]) == 1
    err = capsys.readouterr().err
    assert "(calibration 'lab')" in err and "add --force" in err
    assert _sha(measured) == sha
    # The same fit again (a rerun of the command) keeps the file byte for byte ...
    assert calibration_main(["fit", str(readings), "--out", str(cal)]) == 0
    assert calibration_main(["fit", "--out", str(cal)]) == 0
    assert _sha(measured) == sha
    assert not list(tmp_path.glob("cal-refit-*"))
    # ... other options would replace it: refused, naming the refit that writes beside it.
    capsys.readouterr()
    assert calibration_main(["fit", str(readings), "--out", str(cal), "--dac-bits",
                             "none"]) == 1
    err = capsys.readouterr().err
    assert "never replaced" in err and f"fit --out {cal}" in err
    assert _sha(measured) == sha
    assert json.loads((cal / "run_meta.json").read_text())["fit"]["dac_bits"] == 8


def test_export_print_keeps_an_existing_mesh_and_refuses_a_negative_slab(tmp_path):
    out = tmp_path / "array.stl"
    out.write_bytes(b"solid printed-last-week\n")
    base = [sys.executable, "-m", "stimuli", "export-print", "--depth-level", "3",
            "--spacing-cm", "0.2"]
    res = subprocess.run([*base, str(out)], cwd=REPO, capture_output=True, text=True,
                         check=False, timeout=120)
    assert res.returncode == 1 and "exists and would be replaced" in res.stderr
    assert "--force" in res.stderr and "Traceback" not in res.stderr
    assert out.read_bytes() == b"solid printed-last-week\n"
    res = subprocess.run([*base, "--base-cm", "-1", str(tmp_path / "neg.stl")], cwd=REPO,
                         capture_output=True, text=True, check=False, timeout=120)
    assert res.returncode == 1 and "--base-cm -1" in res.stderr
    assert not (tmp_path / "neg.stl").exists()
