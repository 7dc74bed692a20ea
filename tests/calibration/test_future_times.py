"""Times after now are refused where a calibration reads them (issue 33, finding 2).

A ``--measured-utc 2099-...``, or readings stamped by a lab PC whose clock ran a year ahead,
made a calibration that never aged: sessions said "(-365.0 days old)" and the 30-day rule never
fired. Run through the command line on real files; the session side in
``tests/experiment/test_session_identity.py``.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

import numpy as np

from calibration import SimulatedCRT, load_calibration
from tests.calibration.test_check import _readings


def _stamp(delta: timedelta) -> str:
    return (datetime.now(UTC) + delta).strftime("%Y-%m-%dT%H:%M:%SZ")


def test_future_times_are_refused_by_fit_and_load(tmp_path, cli):
    frame = _readings(SimulatedCRT(), np.random.default_rng(3))
    untimed = tmp_path / "untimed.csv"
    frame.drop(columns=["timestamp_utc"]).to_csv(untimed, index=False)
    res = cli(["fit", untimed, "--out", tmp_path / "a", "--measured-utc",
               "2099-01-01T00:00:00Z"])
    assert res.returncode == 1 and "--measured-utc 2099-01-01T00:00:00Z is" in res.stderr
    assert "days after this PC's clock" in res.stderr and "timedatectl" in res.stderr
    assert not (tmp_path / "a" / "calibration.json").exists()
    # A lab PC whose clock ran a year ahead stamped the readings.
    ahead = tmp_path / "ahead.csv"
    frame.assign(timestamp_utc=_stamp(timedelta(days=365))).to_csv(ahead, index=False)
    res = cli(["fit", ahead, "--out", tmp_path / "b"])
    assert res.returncode == 1, res.stdout
    assert "newest timestamp_utc" in res.stderr and "365.0 days after" in res.stderr
    assert not (tmp_path / "b" / "calibration.json").exists()
    # Two PCs' clocks a minute apart: accepted.
    near = tmp_path / "near.csv"
    frame.assign(timestamp_utc=_stamp(timedelta(seconds=60))).to_csv(near, index=False)
    assert cli(["fit", near, "--out", tmp_path / "c"]).returncode == 0
    # A calibration.json written ahead (older code, another PC): refused where it is read.
    record = json.loads((tmp_path / "c" / "calibration.json").read_text())
    record["measured_utc"] = _stamp(timedelta(days=30))
    (tmp_path / "c" / "calibration.json").write_text(json.dumps(record))
    try:
        load_calibration(tmp_path / "c")
    except ValueError as exc:
        assert "measured_utc" in str(exc) and "30.0 days after" in str(exc)
    else:
        raise AssertionError("a calibration measured in 30 days' time was loaded")
