"""A check measures its own patches (issue 33, finding 1).

``calibration check --calibration CAL --out CAL`` used to "resume" from the calibration's own
readings ("66 of 66 already in CAL/readings.csv; measuring 0") and score them against their own
fit: PASS, exit 0, whatever the display did since. Run as the operator would: the command line,
a calibration folder written by ``calibration fit``, the fake photometer on a pseudo-terminal.
"""

from __future__ import annotations

import json

import pytest

from calibration import SimulatedCRT
from tests.calibration.test_check import _calibration


@pytest.mark.xvfb
def test_a_check_into_the_calibrations_own_folder_is_refused(fake_proc, tmp_path, design, cli):
    cal = _calibration(tmp_path, SimulatedCRT(), "lab", design.display.resolution_px)
    before = {p.name: p.read_bytes() for p in cal.iterdir() if p.is_file()}
    with fake_proc("pr655") as (port, aim, _):
        for out in (cal, tmp_path / "." / "lab"):
            res = cli(["check", "--calibration", cal / "calibration.json", "--device", "pr655",
                       "--port", port, "--out", out, "--sim-aim", aim, "--fast"])
            assert res.returncode == 2, res.stdout + res.stderr
            assert "is a calibration's folder" in res.stderr
            assert f"--out {cal.parent / 'lab-check'}" in res.stderr  # what to type next
        # A copy of the calibration's folder (run_meta.json, procedure-less) is no check folder.
        copy = tmp_path / "copy"
        copy.mkdir()
        (copy / "run_meta.json").write_bytes(before["run_meta.json"])
        (copy / "readings.csv").write_bytes(before["readings.csv"])
        res = cli(["check", "--calibration", cal, "--device", "pr655", "--port", port,
                   "--out", copy, "--sim-aim", aim, "--fast"])
        assert res.returncode == 2 and "calibration run's readings" in res.stderr
        # The check's id may not be the checked calibration's.
        res = cli(["check", "--calibration", cal, "--device", "pr655", "--port", port,
                   "--out", tmp_path / "chk", "--sim-aim", aim, "--fast",
                   "--calibration-id", "lab"])
        assert res.returncode == 2 and "is the checked calibration's" in res.stderr
    assert {p.name: p.read_bytes() for p in cal.iterdir() if p.is_file()} == before
    assert not (cal / "check.json").exists()
    assert not (tmp_path / "chk" / "check.json").exists()
    assert json.loads(before["run_meta.json"])["calibration_id"] == "lab"
