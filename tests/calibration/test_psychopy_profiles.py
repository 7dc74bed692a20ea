"""The calibration in a lab's other experiments: gamma_ramp.csv, the PsychoPy profile as PsychoPy
reads it, and Monitor Center profiles as input (issue 32).

Real displays (tests/data/calibration/, SOURCE.txt and LICENSE there), both CRTs whose guns emit
nothing below a threshold, which no PsychoPy gamma equation holds:

* ptb_apple17_crt_2000: Psychtoolbox's PTB3TestCal.mat, an Apple 17" CRT (Expat licence);
* iset_hp_crt: ISETBio's CRT-HP.mat (MIT licence), 10 levels, black subtracted.

The Monitor Center profiles are written by PsychoPy itself (``psychopy.monitors.Monitor``, as its
Monitor Center saves a gamma measurement: levelsPre from ``DACrange``, lumsPre 4 x n, a gamma grid
from ``GammaCalculator``) from a simulated CRT with a threshold and room light, so the imported
calibration's gamma ramp can be scored against the true display.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calibration import SimulatedCRT, load_calibration
from calibration.__main__ import main
from calibration.ramp import read_gamma_ramp
from calibration.readings import parse_utc

DATA = Path(__file__).resolve().parents[1] / "data" / "calibration"
REPO_ROOT = Path(__file__).resolve().parents[2]
REAL = {
    "apple17": [DATA / "ptb_apple17_crt_2000" / "readings.csv"],
    "hp": [DATA / "iset_hp_crt" / "readings.csv", "--level-scale", "0-255",
           "--measured-utc", "2015-01-01T00:00:00Z"],
}
FRACTIONS = np.array([0.05, 0.10, 0.25, 0.50, 0.75, 0.90, 0.95])
#: The lab's CRT behind the Monitor Center profiles: a gun threshold at 20 % of the drive and
#: 0.5 cd/m^2 of black plus room light; 16 DAC bits so the truth has no quantisation of its own.
LAB_CRT = SimulatedCRT(cutoff=0.2, gamma=2.3, ambient_cd_m2=0.4, black_cd_m2=0.1, bits=16)
LAB_DATE = 1717243200.0  # 2024-06-01T12:00:00Z

_READ_PROFILE = """
import json, sys
import numpy as np
from psychopy.monitors import calibTools
out = {}
for folder in sys.argv[2:]:
    calibTools.monitorFolder = folder + '/monitors'
    from psychopy import monitors
    m = monitors.Monitor('glossdepth-crt', verbose=False)
    f = np.array(json.loads(sys.argv[1]))
    res = {'method': m.getLinearizeMethod(), 'window_gamma': np.asarray(m.getGamma()).tolist(),
           'drive': m.lineariseLums(f).tolist(), 'levels': (m.getLevelsPre() / 255).tolist()}
    m.setLineariseMethod(3)
    res['lums'] = np.asarray(m.getLumsPre())[0].tolist()
    res['drive_at_levels'] = m.lineariseLums(np.asarray(res['lums'])).tolist()
    out[folder] = res
print(json.dumps(out))
"""

_WRITE_LAB_PROFILES = """
import json, sys
import numpy as np
from psychopy.monitors import calibTools
calibTools.monitorFolder = sys.argv[1]
from psychopy import monitors
levels = monitors.DACrange(17)
lums = np.array(json.loads(sys.argv[2]))
mon = monitors.Monitor('labcrt', width=34.0, distance=57.0)
mon.setSizePix([1280, 1024])
mon.setLevelsPre(levels)
mon.setLumsPre(np.tile(lums, (4, 1)))
grid = np.ones((4, 3)) * np.nan
for gun in range(4):
    calc = monitors.GammaCalculator(levels, lums, eq=1)
    grid[gun] = [lums[0], lums[-1], calc.gamma]
mon.setGammaGrid(grid)
mon.setCalibDate(float(sys.argv[3]))
mon.save()
grid_only = monitors.Monitor('gridonly', width=34.0, distance=57.0)
grid_only.setGammaGrid([[0.3, 80.0, 2.2]] * 4)
grid_only.setCalibDate(float(sys.argv[3]))
grid_only.save()
monitors.Monitor('untouched').save()  # a new profile as PsychoPy makes it: its default grid
"""


def _quiet_main(args) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main([str(a) for a in args])


def _python(code: str, *args) -> str:
    res = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True,
                         text=True, timeout=120, cwd=REPO_ROOT, check=False)
    assert res.returncode == 0, res.stderr
    return res.stdout


def _error_pct(cal, fractions, drive) -> np.ndarray:
    """Luminance at ``drive`` against the fraction of the range asked for, % of it above black
    (written out here rather than taken from calibration.ramp)."""
    lo, hi = cal.min_luminance_cd_m2, cal.max_luminance_cd_m2
    want = np.asarray(fractions) * (hi - lo)
    return 100 * (cal.luminance_for_drive(np.asarray(drive, float)) - lo - want) / want


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    """`calibration fit` of both real CRTs: name -> folder."""
    out = {}
    for name, args in REAL.items():
        folder = tmp_path_factory.mktemp(name)
        assert _quiet_main(["fit", *args, "--out", folder]) == 0
        out[name] = folder
    return out


@pytest.fixture(scope="module")
def psychopy_read(real):
    """Each written profile read back by PsychoPy in a fresh process."""
    text = _python(_READ_PROFILE, json.dumps(FRACTIONS.tolist()), *map(str, real.values()))
    got = json.loads(text.strip().splitlines()[-1])
    return {name: got[str(folder)] for name, folder in real.items()}


@pytest.fixture(scope="module")
def lab_profiles(tmp_path_factory):
    """A lab's Monitor Center folder with profiles written by PsychoPy: 'labcrt' (a gamma
    measurement of LAB_CRT, with readings), 'gridonly' (a gamma grid, no readings) and
    'untouched' (never calibrated)."""
    folder = tmp_path_factory.mktemp("lab_monitors")
    lums = LAB_CRT.luminance(np.array(_dac_levels()) / 255, rng=np.random.default_rng(3))
    _python(_WRITE_LAB_PROFILES, folder, json.dumps(lums.tolist()), LAB_DATE)
    return folder


def _dac_levels() -> list[int]:
    from psychopy.monitors import DACrange

    return [int(v) for v in DACrange(17)]


def _linear_ramp_error_pct(table, lum) -> tuple[np.ndarray, np.ndarray]:
    """Each entry's luminance (``lum`` of its drive) against the linear ramp black -> white, %
    of the luminance asked for above black, for the entries at 5-95 % of the range."""
    n = len(table)
    f = np.arange(n) / (n - 1)
    lo, hi = lum(0.0), lum(1.0)
    keep = (f >= 0.05) & (f <= 0.95)
    err = 100 * (lum(table[keep, 0]) - lo - f[keep] * (hi - lo)) / (f[keep] * (hi - lo))
    return f[keep], err


@pytest.mark.parametrize("name", REAL)
def test_gamma_ramp_linearises_both_real_crts(name, real):
    cal = load_calibration(real[name])
    assert cal.gamma_model == "extended_power" and cal.gamma_params["x0"] > 0.1
    table = read_gamma_ramp(real[name] / "gamma_ramp.csv")
    assert table.shape == (256, 3)
    assert np.array_equal(table[:, 0], table[:, 1]) and np.array_equal(table[:, 0], table[:, 2])
    assert table[0, 0] == 0.0 and table[-1, 0] == 1.0 and np.all(np.diff(table[:, 0]) >= 0)
    # The gun's threshold: the first step above black starts past it.
    assert table[1, 0] > cal.gamma_params["x0"]
    _, err = _linear_ramp_error_pct(table, cal.luminance_for_drive)
    assert np.abs(err).max() < 1.0, err


@pytest.mark.parametrize("name", REAL)
def test_psychopy_reads_the_profile_and_makes_the_error_the_report_states(name, real,
                                                                          psychopy_read):
    cal = load_calibration(real[name])
    got = psychopy_read[name]
    report = (real[name] / "report.txt").read_text()
    stated = re.search(r"PsychoPy's monitor gamma \(([\d.]+), the pure power a Window applies\) "
                       r"reproduces this display within ([\d.]+) % at ([\d.]+) % of the range: "
                       r"load gamma_ramp.csv instead", report)
    assert stated, report
    gamma, within = float(stated[1]), float(stated[2])
    # What a Window applies (its gamma) and what lineariseLums inverts are the same pure power.
    assert got["method"] == 1
    assert got["window_gamma"] == pytest.approx([gamma] * 3, abs=1e-3)
    err = _error_pct(cal, FRACTIONS, got["drive"])
    row = re.search(r"PsychoPy's gamma [\d.]+: (.*) %", report)[1]
    assert err == pytest.approx([float(v) for v in row.split(" / ")], abs=0.06)
    # The stated bound holds on a dense grid and is reached; it is far from the ramp's 1 %.
    dense = np.linspace(0.05, 0.95, 901)
    worst = np.abs(_error_pct(cal, dense, dense ** (1 / gamma))).max()
    assert within - 1 < worst <= within and within > 10
    # No other gamma does better (PsychoPy's own eq. 1 fit made 39-46 % at 5 % of the range).
    for other in (gamma * 0.97, gamma * 1.03, 2.2):
        assert np.abs(_error_pct(cal, dense, dense ** (1 / other))).max() > worst
    # lumsPre are scaled so PsychoPy's interpolation (method 3), despite its precedence slip,
    # inverts the stored readings: each reading gives back its own level (or one as bright).
    back = np.interp(got["drive_at_levels"], got["levels"], got["lums"])
    assert back == pytest.approx(got["lums"], abs=1e-9)
    assert np.min(got["lums"]) <= 0.0 and got["lums"][-1] == 1.0


def test_monitor_center_profile_round_trips_to_a_linear_ramp(lab_profiles, tmp_path, cli,
                                                             monkeypatch):
    from psychopy.monitors import calibTools

    before = {p.name: p.read_bytes() for p in lab_profiles.iterdir()}
    monkeypatch.setattr(calibTools, "monitorFolder", str(lab_profiles))
    out = tmp_path / "imported"
    res = cli(["import-psychopy", "labcrt", "--out", out])
    assert res.returncode == 0, res.stderr
    cal = load_calibration(out)
    assert parse_utc(cal.measured_utc) == parse_utc("2024-06-01T12:00:00Z")
    assert (cal.monitor_name, cal.width_cm, cal.distance_cm, cal.resolution_px) == (
        "labcrt", 34.0, 57.0, (1280, 1024))
    assert len(cal.chosen_fit.levels) == 17 and cal.gamma_model == "extended_power"
    # The ramp linearises the true display (not only the fitted curve).
    _, err = _linear_ramp_error_pct(read_gamma_ramp(out / "gamma_ramp.csv"),
                                    lambda d: LAB_CRT.luminance(d))
    assert np.abs(err).max() < 1.0, err
    # The lab's own profiles are untouched, and nothing is added to its folder.
    assert {p.name: p.read_bytes() for p in lab_profiles.iterdir()} == before
    # The imported readings refit as any readings folder does.
    assert cli(["fit", "--out", out]).returncode == 0


def test_profile_without_readings_is_kept_as_its_fitted_curve(lab_profiles, tmp_path, cli):
    out = tmp_path / "grid"
    res = cli(["import-psychopy", lab_profiles / "gridonly.json", "--out", out])
    assert res.returncode == 0, res.stderr
    cal = load_calibration(out)
    assert cal.fits == () and cal.gamma_model == "power"
    assert (cal.min_luminance_cd_m2, cal.max_luminance_cd_m2) == pytest.approx((0.3, 80.0))
    assert any("no readings in the PsychoPy profile" in w and "not refitted" in w
               for w in cal.warnings)
    assert "given, not fitted" in (out / "report.txt").read_text()
    table = read_gamma_ramp(out / "gamma_ramp.csv")
    f = np.arange(256) / 255
    assert table[:, 0] == pytest.approx(f ** (1 / 2.2), abs=1e-6)


def test_a_profile_that_is_not_there_or_not_calibrated_is_refused(lab_profiles, tmp_path, cli,
                                                                  monkeypatch):
    from psychopy.monitors import calibTools

    monkeypatch.setattr(calibTools, "monitorFolder", str(lab_profiles))
    res = cli(["import-psychopy", "lab-crt", "--out", tmp_path / "a"])
    assert res.returncode == 1
    assert "no PsychoPy monitor 'lab-crt'" in res.stderr and "gridonly, labcrt" in res.stderr
    res = cli(["import-psychopy", "untouched", "--out", tmp_path / "b"])
    assert res.returncode == 1
    assert "PsychoPy's default grid" in res.stderr and "calibration run" in res.stderr
    res = cli(["import-psychopy", "labcrt", "--psychopy-calibration", "nope", "--out",
               tmp_path / "c"])
    assert res.returncode == 1 and "--psychopy-calibration" in res.stderr
    assert not any((tmp_path / d).exists() for d in "abc")


def test_own_profile_imports_back_in_cd_m2(real, tmp_path, cli):
    folder = real["apple17"]
    res = cli(["import-psychopy", folder / "monitors" / "glossdepth-crt.json", "--out",
               tmp_path / "back"])
    assert res.returncode == 0, res.stderr
    first, back = load_calibration(folder), load_calibration(tmp_path / "back")
    assert parse_utc(back.measured_utc) == parse_utc(first.measured_utc)
    assert back.chosen_fit.luminance_cd_m2 == pytest.approx(first.chosen_fit.luminance_cd_m2,
                                                            rel=1e-6, abs=1e-9)
    assert back.gamma_model == first.gamma_model


def test_another_profile_of_the_same_name_is_never_changed(lab_profiles, tmp_path, cli,
                                                          monkeypatch):
    from psychopy.monitors import calibTools

    # PsychoPy's own monitor folder is the lab's: writing a profile must not touch it.
    monkeypatch.setattr(calibTools, "monitorFolder", str(lab_profiles))
    lab_before = {p.name: p.read_bytes() for p in lab_profiles.iterdir()}
    out = tmp_path / "cal"
    (out / "monitors").mkdir(parents=True)
    theirs = (lab_profiles / "labcrt.json").read_bytes()
    (out / "monitors" / "glossdepth-crt.json").write_bytes(theirs)
    (out / "monitors" / "other.json").write_bytes(theirs)
    readings = REAL["apple17"][0]
    res = cli(["fit", readings, "--out", out])
    assert res.returncode == 1
    assert "another PsychoPy profile" in res.stderr and "--force" in res.stderr
    assert (out / "monitors" / "glossdepth-crt.json").read_bytes() == theirs
    assert not (out / "calibration.json").exists()
    res = cli(["fit", readings, "--out", out, "--force"])
    assert res.returncode == 0, res.stderr
    kept = json.loads((out / "monitors" / "glossdepth-crt.json").read_text())
    assert len(kept) == 2 and load_calibration(out).calibration_id in kept
    assert (out / "monitors" / "other.json").read_bytes() == theirs
    assert {p.name: p.read_bytes() for p in lab_profiles.iterdir()} == lab_before
    assert calibTools.monitorFolder == str(lab_profiles)


def test_a_profile_dated_in_the_future_is_refused(lab_profiles, tmp_path, cli):
    """A Monitor Center profile saved on a PC whose clock ran a year ahead would never age
    (issue 33, finding 2): its calibDate is refused as every recorded time after now is."""
    raw = json.loads((lab_profiles / "gridonly.json").read_text())
    text = json.dumps(raw).replace(str(LAB_DATE), "4102444800.0")  # 2100-01-01
    assert text != json.dumps(raw)
    ahead = tmp_path / "monitors" / "gridonly.json"
    ahead.parent.mkdir()
    ahead.write_text(text)
    res = cli(["import-psychopy", ahead, "--out", tmp_path / "cal"])
    assert res.returncode == 1
    assert "calibDate 2100-01-01" in res.stderr and "after this PC's clock" in res.stderr
    assert not (tmp_path / "cal").exists()
