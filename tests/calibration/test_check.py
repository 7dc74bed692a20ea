"""`python -m calibration check`: warm-up drift and a few patches against a calibration.

The fake photometer runs as its own process over a pseudo-terminal, measuring a simulated CRT
that warms up (``warmup_drift``, ``warmup_tau_s`` in its ``[crt]`` table, counted from the
fake's first measurement: its "power-on"); the check runs as ``python -m calibration check`` in a PsychoPy
window under Xvfb, through the real drivers.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from calibration import READINGS_COLUMNS, CalibrationError, SimulatedCRT, load_calibration
from calibration.check import WarmupRule, check_deviation, predicted_luminance, warmup_stability
from calibration.fit import fit_calibration
from tests.calibration.conftest import interrupt_after, run_cli

META = {"device": "pr655", "monitor_name": "crt-test", "width_cm": 32.0, "distance_cm": 55.0,
        "refresh_hz": 85.0}


def _readings(crt, rng, cal_id="lab") -> pd.DataFrame:
    """Readings of ``crt`` on the procedure's 3 x 3 grid, written here from its equations."""
    rows = []
    for x in (-0.6, 0.0, 0.6):
        for y in (-0.6, 0.0, 0.6):
            levels = np.linspace(0, 1, 17) if x == y == 0 else np.linspace(0, 1, 5)
            for r in range(2):
                for lv in np.round(levels * 255) / 255:
                    rows.append({"calibration_id": cal_id,
                                 "timestamp_utc": "2026-11-20T10:00:00Z", "device": "pr655",
                                 "x_norm": x, "y_norm": y, "level": lv, "repeat": r,
                                 "luminance_cd_m2": float(crt.luminance(lv, x, y, rng=rng)),
                                 "raw_reply": "r"})
    return pd.DataFrame(rows, columns=READINGS_COLUMNS)


def _calibration(tmp_path, crt, name, resolution_px):
    """A calibration folder of ``crt`` (fitted from its readings, as `fit READINGS.csv` does)."""
    from calibration.run import fit_readings_file
    from studydesign import load_design

    src = tmp_path / f"{name}.csv"
    _readings(crt, np.random.default_rng(2), cal_id=name).to_csv(src, index=False)
    fit_readings_file(src, tmp_path / name, load_design(), progress=lambda *_: None)
    cal = load_calibration(tmp_path / name)
    assert tuple(cal.resolution_px) == tuple(resolution_px)
    return tmp_path / name


def test_warmup_rule_finds_the_stable_time():
    """Exponential warm-up 8 % deficit, tau 300 s, readings every 10 s with 0.3 % noise.

    Analytic (continuous readings): the means of the windows (t - w, t] and (t - 2w, t - w]
    differ by d (tau / w) (exp(w / tau) - 1)^2 exp(-t / tau) of white, with w = 120 s; that is
    <= 0.5 % when exp(-t / tau) <= 0.005 / (0.08 * 0.605), t >= 681 s. The noise moves the
    verdict by a few readings (600-690 s over seeds 0-4).
    """
    rng = np.random.default_rng(4)
    t = np.arange(0, 3600, 10.0)
    lum = 90 * (1 - 0.08 * np.exp(-t / 300)) * (1 + 0.003 * rng.standard_normal(t.size))
    rule = WarmupRule()
    stable_after, change = warmup_stability(t, lum, rule)
    assert 550 < stable_after < 760
    assert change <= 0.5
    # A display that never settles (a slow 20 %/hour drift) is never called stable.
    drifting = 90 * (1 + 0.2 * t / 3600)
    assert warmup_stability(t, drifting, rule)[0] is None
    # Fewer readings than two windows: no verdict yet.
    assert warmup_stability(t[:20], lum[:20], rule) == (None, None)


def test_warmup_readings_slower_than_the_windows_stop_with_the_fix():
    """An instrument slower than planned would leave windows of one reading: never stable."""
    from calibration.check import _check_spacing

    rule = WarmupRule(interval_s=0.1, window_s=0.5)
    _check_spacing([0.0, 0.2, 0.4, 0.6], rule)
    with pytest.raises(CalibrationError, match="every 0.41 s.*--warmup-window-s 2"):
        _check_spacing([0.0, 0.41, 0.82, 1.23], rule)


@pytest.mark.parametrize("kw, message", [({"interval_s": 0}, "interval_s"),
                                         ({"window_s": 5, "interval_s": 10}, "2 readings"),
                                         ({"max_s": math.nan}, "max_s")])
def test_bad_warmup_rule_is_refused(kw, message):
    with pytest.raises(CalibrationError, match=message):
        WarmupRule(**kw)


def test_deviation_uses_the_uniformity_map(rng):
    crt = SimulatedCRT()
    cal = fit_calibration(_readings(crt, rng), calibration_id="lab", resolution_px=(1024, 768),
                          **META)
    corner = float(np.ravel(predicted_luminance(cal, 1.0, -0.6, 0.6))[0])
    assert corner == pytest.approx(float(crt.luminance(1.0, -0.6, 0.6)), rel=0.01)
    # A display 5 % dimmer above black than calibrated fails at white, passes at black.
    frame = pd.DataFrame({"x_norm": 0.0, "y_norm": 0.0, "level": [0.0, 1.0],
                          "luminance_cd_m2": [float(crt.luminance(0.0)),
                                              0.6 + 0.95 * (float(crt.luminance(1.0)) - 0.6)]})
    dev = check_deviation(frame, cal, tolerance_pct=3.0, tolerance_cd_m2=0.05)
    assert [d["pass"] for d in dev] == [True, False]
    assert dev[1]["deviation_pct"] == pytest.approx(-4.9, abs=0.3)
    assert dev[1]["deviation_cd_m2"] == pytest.approx(-0.05 * 95, rel=0.1)


@pytest.mark.xvfb
@pytest.mark.slow
def test_check_measures_warmup_then_the_deviation(fake_proc, tmp_path, design):
    """Warm-up until stable, then patches within tolerance of the right calibration; a wrong
    calibration (gamma 2.2 for the display's 2.4) fails at mid levels, exit code 1."""
    warm = SimulatedCRT(warmup_drift=0.3, warmup_tau_s=4.0)
    display = tmp_path / "warming.toml"
    display.write_text("[crt]\n" + "".join(f"{k} = {v}\n" for k, v in warm.to_dict().items()))
    res_px = design.display.resolution_px
    right = _calibration(tmp_path, SimulatedCRT(), "right", res_px)
    wrong = _calibration(tmp_path, SimulatedCRT(gamma=2.2), "wrong", res_px)
    out = tmp_path / "check"
    patches = ["--fast", "--levels", "4", "--uniformity-levels", "2", "--repeats", "1",
               "--warmup-interval-s", "0.1", "--warmup-window-s", "2"]
    with fake_proc("pr655", display=display) as (port, aim, _):
        res = run_cli(["check", "--calibration", right, "--device", "pr655", "--port", port,
                       "--out", out, "--sim-aim", aim, *patches, "--warmup-max-s", "60"])
        assert res.returncode == 0, res.stdout + res.stderr
        res2 = run_cli(["check", "--calibration", wrong / "calibration.json", "--device",
                        "pr655", "--port", port, "--out", tmp_path / "check2", "--sim-aim", aim,
                        *patches, "--warmup-max-s", "0.5"])
    result = json.loads((out / "check.json").read_text())
    assert result["kind"] == "check" and result["checked_calibration_id"] == "right"
    assert result["check_id"].startswith("right-check-")
    assert result["checked_calibration"] == str((right / "calibration.json").resolve())
    warmup = pd.read_csv(out / "warmup.csv")
    assert tuple(warmup.columns) == READINGS_COLUMNS
    assert (warmup["level"] == 1.0).all() and (warmup[["x_norm", "y_norm"]] == 0).all().all()
    assert list(warmup["repeat"]) == list(range(len(warmup)))
    assert (warmup["calibration_id"] == result["check_id"]).all()
    # The display warmed up while it was read: white rose by more than the noise.
    lum = warmup["luminance_cd_m2"].to_numpy()
    assert lum[-5:].mean() > 1.02 * lum[:5].mean()
    w = result["warmup"]
    assert w["stable"] is True and 4.0 <= w["stable_after_s"] <= 60
    assert w["rule"]["window_s"] == 2.0 and w["last_change_pct"] <= 0.5
    readings = pd.read_csv(out / "readings.csv")
    assert (readings["calibration_id"] == result["check_id"]).all()
    assert len(readings) == 4 + 8 * 2
    newest = pd.to_datetime(pd.concat([readings, warmup])["timestamp_utc"], utc=True).max()
    assert pd.Timestamp(result["created_utc"]) == newest
    assert len(result["deviation"]) == 4 + 8 * 2
    assert result["passed"] is True, (out / "check_report.txt").read_text()
    assert max(abs(d["deviation_pct"]) for d in result["deviation"]) < 3.0
    # The wrong calibration: not warmed-up verdict within 0.5 s, and mid levels fail.
    assert res2.returncode == 1, res2.stderr
    bad = json.loads((tmp_path / "check2" / "check.json").read_text())
    assert bad["warmup"] == bad["warmup"] | {"stable": False, "stable_after_s": None}
    assert bad["passed"] is False
    failed = {round(d["level"], 3) for d in bad["deviation"] if not d["pass"]}
    assert failed and failed <= {0.333, 0.667}
    assert "FAIL" in (tmp_path / "check2" / "check_report.txt").read_text()


def test_check_folder_refuses_another_calibration(tmp_path, rng, cli):
    """A check folder records what it checks; resuming it against another calibration stops."""
    from calibration import save_calibration

    readings = _readings(SimulatedCRT(), rng)
    for name in ("a", "b"):
        cal = fit_calibration(readings, calibration_id=name, resolution_px=(1024, 768), **META)
        save_calibration(cal, tmp_path / name / "calibration.json")
    out = tmp_path / "check"
    res = cli(["check", "--calibration", tmp_path / "a", "--device", "pr655", "--port",
                   tmp_path / "nope", "--out", out, "--fast"])
    assert res.returncode == 2 and "no pr655 answers" in res.stderr
    res = cli(["check", "--calibration", tmp_path / "b", "--device", "pr655", "--port",
                   tmp_path / "nope", "--out", out, "--fast"])
    assert res.returncode == 2
    assert "checks calibration 'a'" in res.stderr and "new --out" in res.stderr


@pytest.mark.xvfb
@pytest.mark.slow
def test_check_stopped_by_ctrl_c_resumes(fake_proc, tmp_path, design):
    """Ctrl-C mid-check: exit 130 naming what was kept; the rerun keeps the stable warm-up and
    measures only the missing patches."""
    cal = _calibration(tmp_path, SimulatedCRT(), "lab", design.display.resolution_px)
    out = tmp_path / "check"
    with fake_proc("pr655") as (port, aim, _):
        args = ["check", "--calibration", cal, "--device", "pr655", "--port", port, "--out", out,
                "--sim-aim", aim, "--fast", "--settle-s", "0.2", "--repeats", "1",
                "--warmup-interval-s", "0.1", "--warmup-window-s", "0.5"]
        path = out / "readings.csv"
        code, err = interrupt_after(args, path, 5)
        assert code == 130, err
        assert "Traceback" not in err and "check stopped (Ctrl-C)" in err
        kept = len(pd.read_csv(path))
        n_warm = len(pd.read_csv(out / "warmup.csv"))
        res = run_cli(args)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "warm-up: already stable" in res.stdout
    assert f"{kept} of 29 readings already" in res.stdout
    assert len(pd.read_csv(out / "warmup.csv")) == n_warm
    final = pd.read_csv(path)
    assert len(final) == 29 and not final.duplicated(["x_norm", "y_norm", "level"]).any()
    assert json.loads((out / "check.json").read_text())["passed"] is True
