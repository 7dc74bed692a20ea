"""The procedure end to end: a PsychoPy window under Xvfb, the fake photometer reading its pixels.

The fake instrument runs as its own process (``python -m calibration fake-photometer``) and
reads the X screen under its aim; the procedure runs as ``python -m calibration run``. Faults
are injected through the fake's ``--fault`` switches.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from calibration import READINGS_COLUMNS, SimulatedCRT, load_calibration, load_crt
from calibration.procedure import ProcedureSettings, make_schedule
from tests.calibration.conftest import REPO_ROOT, run_cli

pytestmark = pytest.mark.xvfb

SMALL = ["--fast", "--levels", "6", "--repeats", "1", "--grid", "1", "--validation", "0",
         "--calibration-id", "t1", "--width-cm", "32.5"]


def _run(port, aim, out, *extra, device="pr655"):
    return run_cli(["run", "--device", device, "--port", port, "--out", out, "--sim-aim", aim,
                    *extra])


@pytest.mark.slow
def test_full_run_recovers_the_simulated_display(fake_proc, tmp_path):
    out = tmp_path / "cal"
    with fake_proc("pr655") as (port, aim, _):
        res = _run(port, aim, out, "--fast", "--levels", "9", "--repeats", "2",
                   "--uniformity-levels", "3", "--validation", "5", "--width-cm", "32.5")
    assert res.returncode == 0, res.stderr
    readings = pd.read_csv(out / "readings.csv")
    assert tuple(readings.columns) == READINGS_COLUMNS
    assert len(readings) == 9 * 2 + 8 * 3 * 2
    cal = load_calibration(out / "calibration.json")
    crt = load_crt()
    # The fake read the window's real pixels: the fitted display is the simulated CRT.
    want = crt.luminance(np.linspace(0, 1, 11))
    assert cal.luminance_for_drive(np.linspace(0, 1, 11)) == pytest.approx(want, rel=0.03,
                                                                           abs=0.1)
    assert cal.gamma_model == "extended_power"
    assert cal.gamma_params["gamma"] == pytest.approx(crt.gamma, abs=0.15)
    # Uniformity: the CRT's falloff and tilt, as seen on the X screen (the simulated CRT).
    u = cal.uniformity
    rel = np.array(u.relative)
    assert rel[1, 1] == pytest.approx(1.0)
    assert rel.min() == pytest.approx(1 - crt.falloff * 0.36 - crt.tilt_x * 0.6, abs=0.03)
    assert cal.validation_max_deviation_pct < 2.0
    for name in ("gamma.png", "uniformity.png", "report.txt", "monitors/glossdepth-crt.json"):
        assert (out / name).stat().st_size > 0, name
    assert (out / "gamma.png").read_bytes()[:4] == b"\x89PNG"
    report = (out / "report.txt").read_text()
    assert "max deviation from linear luminance" in report
    # The monitor profile is a PsychoPy Monitor the lab's other experiments can load.
    check = (
        "from psychopy.monitors import calibTools; "
        f"calibTools.monitorFolder = {str(out / 'monitors')!r}; "
        "from psychopy import monitors; m = monitors.Monitor('glossdepth-crt'); "
        "print(m.getWidth(), m.getDistance(), m.currentCalibName)"
    )
    loaded = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True,
                            timeout=120, cwd=REPO_ROOT, check=False)
    assert loaded.stdout.split()[-3:] == ["32.5", "55.0", cal.calibration_id], loaded.stderr


@pytest.mark.slow
def test_bad_replies_are_flagged_and_remeasured(fake_proc, tmp_path):
    out = tmp_path / "cal"
    faults = ["saturated:2", "garbled:4", "out_of_range:5", "timeout:7"]
    with fake_proc("pr655", faults) as (port, aim, _):
        res = _run(port, aim, out, *SMALL)
    assert res.returncode == 0, res.stderr
    readings = pd.read_csv(out / "readings.csv", dtype={"raw_reply": str})
    rejected = pd.read_csv(out / "rejected.csv", dtype={"raw_reply": str})
    assert len(readings) == 6
    assert sorted(rejected["flag"]) == ["garbled", "out_of_range", "saturated"]
    assert not set(rejected["raw_reply"]) & set(readings["raw_reply"])
    assert (readings["luminance_cd_m2"] >= 0).all()
    cal = load_calibration(out)
    assert any("3 photometer replies rejected" in w for w in cal.warnings)


def test_given_refresh_rate_is_recorded_and_flagged(fake_proc, tmp_path, design):
    """A virtual display without vertical blank: --refresh-hz is recorded, with a warning."""
    out = tmp_path / "cal"
    hz = design.display.nominal_refresh_hz
    with fake_proc("pr655") as (port, aim, _):
        res = _run(port, aim, out, *SMALL, "--refresh-hz", str(hz))
    assert res.returncode == 0, res.stderr
    cal = load_calibration(out)
    assert cal.refresh_hz == hz
    assert any("was given (--refresh-hz), not measured" in w for w in cal.warnings)


def test_wrong_port_lists_ports(tmp_path):
    res = run_cli(["run", "--device", "ls100", "--port", tmp_path / "ttyUSB7", "--out",
                   tmp_path / "cal", *SMALL])
    assert res.returncode == 2
    assert "no ls100 answers on port" in res.stderr and "serial ports found" in res.stderr


def test_persistent_timeouts_stop_with_the_last_reply(fake_proc, tmp_path):
    with fake_proc("ls100", ["timeout:all"]) as (port, aim, _):
        res = _run(port, aim, tmp_path / "cal", *SMALL, "--timeout-s", "0.3", "--retries", "1",
                   device="ls100")
    assert res.returncode == 2
    assert "no complete reply after 2 attempt(s)" in res.stderr
    assert "last raw reply 'OK00," in res.stderr


@pytest.mark.slow
def test_unplug_keeps_readings_and_rerun_resumes(fake_proc, tmp_path):
    out = tmp_path / "cal"
    with fake_proc("pr650", ["unplug:4"]) as (port, aim, proc):
        res = _run(port, aim, out, *SMALL, device="pr650")
        proc.wait(timeout=10)  # the fake exits when unplugged
    assert res.returncode == 2 and "serial line lost" in res.stderr
    first = pd.read_csv(out / "readings.csv")
    assert len(first) == 3
    with fake_proc("pr650") as (port, aim, _):
        res = _run(port, aim, out, *SMALL, device="pr650")
        assert res.returncode == 0, res.stderr
        # The same command once more on the finished folder (issue 33): nothing to measure, and
        # calibration.json stays byte for byte (it was rewritten with a new created_utc, so a
        # session that recorded its SHA-256 could not resume).
        before = (out / "calibration.json").read_bytes()
        again = _run(port, aim, out, *SMALL, device="pr650")
        assert again.returncode == 0 and "6 of 6 readings already" in again.stdout
        assert (out / "calibration.json").read_bytes() == before
    assert "3 of 6 readings already" in res.stdout
    both = pd.read_csv(out / "readings.csv")
    assert len(both) == 6
    assert both.iloc[:3].equals(first)  # what was recorded is untouched
    assert not both.duplicated(["x_norm", "y_norm", "level", "repeat"]).any()


@pytest.mark.slow
def test_kill_mid_run_then_resume(fake_proc, tmp_path):
    out = tmp_path / "cal"
    args = ["--fast", "--levels", "17", "--repeats", "1", "--grid", "1", "--validation", "0",
            "--calibration-id", "k1", "--settle-s", "0.2"]
    with fake_proc("pr655") as (port, aim, _):
        proc = subprocess.Popen(
            [sys.executable, "-m", "calibration", "run", "--device", "pr655", "--port", port,
             "--out", out, "--sim-aim", aim, *args], cwd=REPO_ROOT,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        path = out / "readings.csv"
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if path.exists() and len(path.read_text().splitlines()) >= 6:
                break
            assert proc.poll() is None, proc.stderr.read().decode()
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        survived = len(pd.read_csv(path))
        assert 5 <= survived < 17
        res = _run(port, aim, out, *args)
    assert res.returncode == 0, res.stderr
    assert f"{survived} of 17 readings already" in res.stdout
    final = pd.read_csv(out / "readings.csv")
    assert len(final) == 17
    assert sorted(final["level"].round(6)) == sorted(
        make_schedule(ProcedureSettings(calibration_id="k1", device="pr655", seed=20261122,
                                        n_levels=17, n_repeats=1, grid=1))["level"].round(6))


@pytest.mark.slow
def test_refit_without_instrument_matches(fake_proc, tmp_path):
    out = tmp_path / "cal"
    with fake_proc("ls100") as (port, aim, _):
        assert _run(port, aim, out, *SMALL, device="ls100").returncode == 0
    before = json.loads((out / "calibration.json").read_text())
    res = run_cli(["fit", "--out", out])
    assert res.returncode == 0, res.stderr
    after = json.loads((out / "calibration.json").read_text())
    assert after["gamma_params"] == before["gamma_params"]
    assert after["instrument"]["serial"] == "4800 7E2"


def test_schedule_is_randomised_and_complete():
    s = ProcedureSettings(calibration_id="x", device="pr655", seed=3)
    sched = make_schedule(s)
    assert len(sched) == 17 * 2 + 8 * 5 * 2
    centre = sched.iloc[:34]
    assert (centre[["x_norm", "y_norm"]] == 0).all().all()
    assert not centre["level"].is_monotonic_increasing
    # Levels sit on the 8-bit grid, so the value recorded is the value displayed.
    assert np.allclose(sched["level"] * 255, np.round(sched["level"] * 255))
    assert make_schedule(s).equals(sched)
    assert not make_schedule(ProcedureSettings(calibration_id="x", device="pr655",
                                               seed=4)).equals(sched)


@pytest.mark.parametrize("kw, message", [({"n_levels": 3}, "n_levels"),
                                         ({"calibration_id": "a b"}, "calibration_id"),
                                         ({"grid_extent_norm": 1.2}, "grid_extent_norm")])
def test_bad_settings_are_rejected(kw, message):
    from calibration import CalibrationError

    with pytest.raises(CalibrationError, match=message):
        ProcedureSettings(**({"calibration_id": "x", "device": "pr655", "seed": 1} | kw))


def test_simulated_crt_is_the_shipped_one():
    assert load_crt() == SimulatedCRT()
