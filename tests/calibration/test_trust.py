"""Trust over time and across runs: age, torn rows, locks, resumes, Ctrl-C, file modes.

Each test reproduces a way the calibration folder could be made to lie or lose data; the
procedure runs as ``python -m calibration run`` against the fake photometer over a
pseudo-terminal (the real drivers), in a PsychoPy window under Xvfb.
"""

from __future__ import annotations

import json
import os
from datetime import UTC, datetime, timedelta

import numpy as np
import pandas as pd
import pytest

from calibration import READINGS_COLUMNS, SimulatedCRT, default_calibration, load_calibration
from calibration.fit import fit_calibration
from calibration.procedure import ProcedureSettings, load_or_create_settings
from calibration.readings import append_row, read_readings
from calibration.record import save_calibration
from calibration.report import write_outputs
from labfiles import FolderLock, TornTailWarning
from tests.calibration.conftest import interrupt_after, run_cli

SMALL = ["--fast", "--levels", "6", "--repeats", "1", "--grid", "1", "--validation", "0",
         "--calibration-id", "t1", "--width-cm", "32.5", "--refresh-hz", "85"]
META = {"calibration_id": "old", "device": "pr655", "monitor_name": "crt-test",
        "resolution_px": (1024, 768), "width_cm": 32.0, "distance_cm": 55.0, "refresh_hz": 85.0}


def _old_folder(tmp_path, days: float):
    """A calibration folder whose readings were taken ``days`` ago (as `run` leaves it)."""
    crt, rng = SimulatedCRT(), np.random.default_rng(3)
    t0 = datetime.now(UTC) - timedelta(days=days)
    folder = tmp_path / "cal"
    folder.mkdir()
    for i, lv in enumerate(np.repeat(np.linspace(0, 1, 9), 2)):
        stamp = (t0 + timedelta(seconds=i)).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        append_row(folder / "readings.csv", {
            "calibration_id": "old", "timestamp_utc": stamp, "device": "pr655", "x_norm": 0.0,
            "y_norm": 0.0, "level": float(lv), "repeat": i % 2,
            "luminance_cd_m2": float(crt.luminance(lv, rng=rng)), "raw_reply": "r"})
    meta = {"calibration_id": "old", "fit": META | {"resolution_px": [1024, 768]}}
    (folder / "run_meta.json").write_text(json.dumps(meta))
    return folder, t0


def test_refit_keeps_the_age_of_the_readings(tmp_path, design, cli):
    """A 90-day-old calibration refitted today still fails the session's 30-day check."""
    from experiment.checks import PreflightError, check_calibration

    folder, t0 = _old_folder(tmp_path, days=90)
    res = cli(["fit", "--out", folder])
    assert res.returncode == 0, res.stderr
    cal = load_calibration(folder)
    assert cal.age_days() == pytest.approx(90, abs=0.01)
    assert datetime.fromisoformat(cal.measured_utc) >= t0
    assert datetime.fromisoformat(cal.created_utc) > t0 + timedelta(days=89)  # when written
    with pytest.raises(PreflightError, match="days old"):
        check_calibration(folder / "calibration.json", design, max_age_days=30)


def test_records_without_measured_utc_still_load(design, tmp_path):
    d = default_calibration(design).to_dict()
    d.pop("measured_utc")
    (tmp_path / "calibration.json").write_text(json.dumps(d))
    cal = load_calibration(tmp_path)
    assert cal.measured_utc is None
    assert cal.age_days() > 20000  # counted from created_utc, 1970


def test_outputs_respect_the_umask(tmp_path):
    """calibration.json, report.txt, the plots and the profile: 0o666 less the umask."""
    folder, _ = _old_folder(tmp_path, days=1)
    readings = read_readings(folder / "readings.csv").frame
    cal = fit_calibration(readings, **META)
    old = os.umask(0o002)
    try:
        paths = write_outputs(cal, readings, tmp_path / "out")
        save_calibration(cal, tmp_path / "out" / "again.json")
    finally:
        os.umask(old)
    for name, path in paths.items():
        assert oct(path.stat().st_mode & 0o777) == oct(0o664), name
    assert oct((tmp_path / "out" / "again.json").stat().st_mode & 0o777) == oct(0o664)


def test_raw_reply_with_line_breaks_stays_one_record(tmp_path):
    path = tmp_path / "readings.csv"
    append_row(path, {"calibration_id": "c", "level": 0.5, "x_norm": 0, "y_norm": 0,
                      "repeat": 0, "luminance_cd_m2": 1.0, "timestamp_utc": "t",
                      "raw_reply": "00000,0,1.0\r\n101 lines\\"})
    assert len(path.read_text().splitlines()) == 2
    assert read_readings(path).frame["raw_reply"].iloc[0] == "00000,0,1.0\\r\\n101 lines\\\\"


def test_torn_last_row_is_moved_aside_and_named(tmp_path, cli):
    """A row cut inside its quotes: the readers name the file and line, keep the bytes."""
    folder, _ = _old_folder(tmp_path, days=1)
    path = folder / "readings.csv"
    whole = path.read_bytes()
    torn = b'old,2026-11-01T00:00:00Z,pr655,0.0,0.0,0.5,1,12.5,"00000,0,12'
    path.write_bytes(whole + torn)
    res = cli(["fit", "--out", folder])
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    assert f"{path}: line 20 is torn" in res.stdout
    side = list(folder.glob("readings.csv.torn-*"))
    assert len(side) == 1 and side[0].read_bytes() == torn
    assert path.read_bytes() == whole
    assert "readings: 18 accepted" in (folder / "report.txt").read_text()


def test_torn_row_cut_outside_quotes_is_not_merged_with_the_next(tmp_path):
    path = tmp_path / "readings.csv"
    row = {"calibration_id": "c", "timestamp_utc": "t", "device": "d", "x_norm": 0,
           "y_norm": 0, "level": 0.5, "repeat": 0, "luminance_cd_m2": 10.0, "raw_reply": "r"}
    append_row(path, row)
    with open(path, "ab") as fh:
        fh.write(b"c,t,d,0,0,0.75,0,3")  # cut in the luminance: no quote, no line end
    with pytest.warns(TornTailWarning, match="line 3 is torn"):
        append_row(path, row | {"level": 1.0, "luminance_cd_m2": 20.0})
    frame = read_readings(path).frame
    assert list(frame["level"]) == [0.5, 1.0] and list(frame["luminance_cd_m2"]) == [10, 20]


def test_second_run_into_a_locked_folder_is_refused(tmp_path, cli):
    out = tmp_path / "cal"
    with FolderLock(out, what="calibration folder"):
        res = cli(["run", "--device", "pr655", "--port", tmp_path / "nope", "--out", out,
                       *SMALL])
    assert res.returncode == 2
    assert "is in use by another run" in res.stderr and f"pid {os.getpid()}" in res.stderr


@pytest.mark.parametrize("option, value, stored", [
    ("--levels", "17", "--levels 6"),
    ("--calibration-id", "t2", "--calibration-id t1"),
])
def test_resume_with_other_settings_is_refused(tmp_path, option, value, stored, cli):
    out = tmp_path / "cal"
    load_or_create_settings(out, ProcedureSettings(calibration_id="t1", device="pr655",
                                                   seed=20261122, n_levels=6, n_repeats=1,
                                                   grid=1, n_validation=0))
    args = list(SMALL)
    args[args.index(option) + 1] = value
    res = cli(["run", "--device", "pr655", "--port", tmp_path / "nope", "--out", out, *args])
    assert res.returncode == 2
    assert f"was started with {stored}" in res.stderr and "new --out" in res.stderr
    # The fix is a command the operator can type as it is written.
    assert f"`python -m calibration run` again with {stored}" in res.stderr
    # Leaving the options out resumes with the stored ones (it gets as far as the port).
    res = cli(["run", "--device", "pr655", "--port", tmp_path / "nope", "--out", out,
                   "--fast"])
    assert res.returncode == 2 and "no pr655 answers" in res.stderr


@pytest.mark.xvfb
@pytest.mark.slow
def test_torn_row_is_measured_again(fake_proc, tmp_path):
    out = tmp_path / "cal"
    with fake_proc("pr655") as (port, aim, _):
        args = ["run", "--device", "pr655", "--port", port, "--out", out, "--sim-aim", aim, *SMALL]
        assert run_cli(args).returncode == 0
        path = out / "readings.csv"
        data = path.read_bytes()
        cut = data.rstrip(b"\n").rfind(b"\n") + 1
        lost = pd.read_csv(path).iloc[-1]
        path.write_bytes(data[:cut + 25])  # a crash mid-write of the last row
        res = run_cli(args)
    assert res.returncode == 0, res.stderr
    assert f"{path}: line 7 is torn" in res.stdout + res.stderr
    assert "5 of 6 readings already" in res.stdout
    final = pd.read_csv(path)
    assert tuple(final.columns) == READINGS_COLUMNS and len(final) == 6
    assert lost["level"] in set(final["level"])
    side = list(out.glob("readings.csv.torn-*"))
    assert len(side) == 1 and side[0].read_bytes() == data[cut:cut + 25]


@pytest.mark.xvfb
def test_ctrl_c_stops_cleanly_and_says_how_to_resume(fake_proc, tmp_path):
    out = tmp_path / "cal"
    args = ["--fast", "--levels", "17", "--repeats", "1", "--grid", "1", "--validation", "0",
            "--calibration-id", "c1", "--refresh-hz", "85", "--settle-s", "0.2"]
    with fake_proc("pr655") as (port, aim, _):
        code, err = interrupt_after(["run", "--device", "pr655", "--port", port, "--out", out,
                                     "--sim-aim", aim, *args], out / "readings.csv", 4)
    assert code == 130, err
    assert "Traceback" not in err
    assert "stopped (Ctrl-C)" in err and "readings in" in err and "again to resume" in err
    # Only the files the run wrote are named (a run writes no warm-up readings).
    assert "warmup.csv" not in err and "validation.csv" not in err
    assert len(read_readings(out / "readings.csv").frame) >= 3


def test_ctrl_c_during_a_fit_exits_130_without_a_traceback(tmp_path, cli, monkeypatch):
    """A fit of many levels takes seconds: Ctrl-C then ends with a line, not a traceback."""
    import calibration.run

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(calibration.run, "fit_readings_file", interrupted)
    src = tmp_path / "r.csv"
    src.write_text("level,luminance_cd_m2\n0,0.5\n1,90\n")
    res = cli(["fit", src, "--out", tmp_path / "cal", "--measured-utc", "2026-08-01T10:00:00Z"])
    assert res.returncode == 130
    assert "fit stopped (Ctrl-C)" in res.stderr and "same command again" in res.stderr
