"""Claim: on real CRTs (a gun threshold), gamma_ramp.csv linearises the display within 1 % at
5-95 % of the range, where any PsychoPy monitor gamma errs by more than 10 %; the profile's gamma
is the one that errs least.

Readings: tests/data/calibration/ (Psychtoolbox's Apple 17" CRT and monitor 'a' from
PTB3TestCal.mat; ISETBio's HP CRT; SOURCE.txt). Each is fitted with ``python -m calibration fit``
into a scratch folder. Side by side, the error of the luminance the calibration predicts at the
drive used against the luminance asked for (% of it above black), at 5/10/25/50/75/90 % of the
range:
- the profile written now, read back by PsychoPy (``Monitor.lineariseLums``, method 1, the pure
  power a Window applies);
- the gamma of PsychoPy's own GammaCalculator (eq. 1) on the same level means;
- the gamma profiles held before (eq. 4's when offset_power was chosen, else the eq. 1 ``power``
  fit's: the issue's table), which a Window applies as a pure power;
- gamma_ramp.csv as written, and after an 8-bit and a 10-bit DAC's rounding.
"""

from __future__ import annotations

import contextlib
import io
import tempfile
from pathlib import Path

import numpy as np

from calibration.__main__ import main as calibration_main
from calibration.ramp import read_gamma_ramp
from calibration.record import load_calibration

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "calibration"
DISPLAYS = {
    "Apple 17\" CRT (PTB3TestCal)": [DATA / "ptb_apple17_crt_2000" / "readings.csv"],
    "HP CRT (ISETBio)": [DATA / "iset_hp_crt" / "readings.csv", "--level-scale", "0-255",
                         "--measured-utc", "2015-01-01T00:00:00Z"],
    "monitor 'a' (PTB3TestCal)": [DATA / "ptb_monitor_a_2006" / "readings.csv"],
}
F = np.array([0.05, 0.10, 0.25, 0.50, 0.75, 0.90])


def _err(cal, f, drive) -> np.ndarray:
    lo, hi = cal.min_luminance_cd_m2, cal.max_luminance_cd_m2
    got = cal.luminance_for_drive(np.clip(drive, 0, 1))
    return 100 * (got - lo - f * (hi - lo)) / (f * (hi - lo))


def _row(label: str, values) -> None:
    print(f"  {label:<46}" + "".join(f"{v:+8.1f}" for v in values))


def _profile_drive(folder: Path, name: str) -> tuple[float, np.ndarray]:
    from psychopy import logging, monitors
    from psychopy.monitors import calibTools

    calibTools.monitorFolder = str(folder / "monitors")
    logging.console.setLevel(logging.ERROR)
    mon = monitors.Monitor(name, verbose=False, autoLog=False)
    return float(np.asarray(mon.getGamma())[0]), np.asarray(mon.lineariseLums(F), float)


def main() -> None:
    from psychopy.monitors.calibTools import GammaCalculator

    scratch = Path(tempfile.mkdtemp(prefix="bench-psychopy-profile-"))
    print(f"{'':<48}" + "".join(f"{100 * f:7.0f}%" for f in F))
    for i, (label, args) in enumerate(DISPLAYS.items()):
        out = scratch / str(i)
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            assert calibration_main(["fit", *map(str, args), "--out", str(out)]) == 0
        cal = load_calibration(out)
        print(f"{label}: chosen {cal.gamma_model}")
        gamma, drive = _profile_drive(out, cal.monitor_name)
        _row(f"profile read by PsychoPy (gamma {gamma:.3f})", _err(cal, F, drive))
        fit = cal.chosen_fit
        x, y = np.asarray(fit.levels), np.asarray(fit.luminance_cd_m2)
        levels = np.unique(x)
        gc = GammaCalculator(inputs=list(levels), lums=[y[x == v].mean() for v in levels],
                             eq=1).gamma
        _row(f"GammaCalculator eq. 1 (gamma {gc:.3f})", _err(cal, F, F ** (1 / gc)))
        # Profiles written before held eq. 4's gamma when offset_power was chosen, else the eq. 1
        # power fit's; a Window applies either as a pure power.
        old = (cal.gamma_params["gamma"] if cal.gamma_model == "offset_power" else
               next(f for f in cal.fits if f.model == "power").params["gamma"])
        _row(f"profile before (gamma {old:.3f})", _err(cal, F, F ** (1 / old)))
        ramp = read_gamma_ramp(out / "gamma_ramp.csv")[:, 0]
        idx = np.rint(F * 255).astype(int)
        f = idx / 255
        _row("gamma_ramp.csv", _err(cal, f, ramp[idx]))
        for bits in (8, 10):
            steps = 2**bits - 1
            _row(f"gamma_ramp.csv after a {bits}-bit DAC", _err(cal, f,
                                                              np.round(ramp[idx] * steps) / steps))


if __name__ == "__main__":
    main()
