"""The display layer of the gap diagnosis on other labs' real readings (issue 29).

Fixtures: tests/data/displays (MIT, copied with their SOURCE.txt and LICENSE): a Dell LCD's
10 measured levels (ISETBio; black subtracted, so level 0 reads exactly 0, no repeats) and a
Samsung OLED's 132 raw PR-650 readings, 11 levels x 12 surround conditions in acquisition order
(BrainardLab). A second pass of a meter over the LCD's light is made here, apart from the code
under test: 0.5 % noise, four significant digits, a zero stays a zero (the meter's floor).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.gap import NOT_A_GAP, diagnose
from calibration import Calibration, choose_gamma_model, fit_gamma_models, save_calibration

DATA = Path(__file__).resolve().parents[2] / "data" / "displays"


def _calibrate(frame: pd.DataFrame, folder: Path) -> Path:
    """A lab's calibration fitted (calibration package, public API) from ``frame``'s level and
    luminance_cd_m2 columns, as ``python -m calibration fit`` would."""
    fits = fit_gamma_models(frame["level"].to_numpy(float),
                            frame["luminance_cd_m2"].to_numpy(float), dac_bits=None)
    best = choose_gamma_model(fits)
    cal = Calibration(calibration_id="lab", created_utc="2026-01-01T00:00:00Z", device="pr650",
                      monitor_name="real", resolution_px=(1920, 1080), width_cm=50.0,
                      distance_cm=57.0, refresh_hz=60.0, gamma_model=best.model,
                      gamma_params=dict(best.params),
                      min_luminance_cd_m2=float(best.luminance(0.0)),
                      max_luminance_cd_m2=float(best.luminance(1.0)), fits=fits)
    folder.mkdir(parents=True, exist_ok=True)
    save_calibration(cal, folder / "calibration.json")
    return folder


def _meter(lum, rng) -> np.ndarray:
    """One pass of a meter over the light ``lum``: 0.5 % noise, four significant digits; a
    zero (below its floor) is read as zero again."""
    lum = np.asarray(lum, float)
    out = lum * (1 + 0.005 * rng.standard_normal(lum.shape))
    scale = 10.0 ** (3 - np.floor(np.log10(np.maximum(out, 1e-9))))
    return np.where(lum > 0, np.round(out * scale) / scale, 0.0)


def _diagnose(check: pd.DataFrame, cal: Path, tmp_path: Path, name: str):
    path = tmp_path / f"{name}.csv"
    check.to_csv(path, index=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return diagnose("display", path, cal, None, seed=0, n_boot=300)[0]


def _lcd() -> pd.DataFrame:
    t = pd.read_csv(DATA / "lcd_dell_iset" / "readings.csv")
    return pd.DataFrame({"level": t["level"] / 255.0, "luminance_cd_m2": t["luminance_cd_m2"]})


@pytest.mark.parametrize("seed", [0, 1])
def test_a_repeat_pass_of_a_real_lcd_has_no_gap_and_its_zero_is_censored(tmp_path, seed):
    """Two passes of the meter over the LCD's light, one calibrated, one checked: not a gap
    (issue 38), within 2 % of luminance (RMS, the
    meter's 0.5 % twice and the calibration model's misfit). The black reading is exactly 0 in both: censored (was: exact, a gap of
    up to 3e11 nats per reading); no repeats: the noise is the documented meter model's."""
    rng = np.random.default_rng(seed)
    lcd = _lcd()
    cal = _calibrate(lcd.assign(luminance_cd_m2=_meter(lcd["luminance_cd_m2"], rng)),
                     tmp_path / "cal")
    diag = _diagnose(lcd.assign(luminance_cd_m2=_meter(lcd["luminance_cd_m2"], rng)), cal,
                     tmp_path, "repeat")
    # Not a gap; since issue 43 inconclusive rather than "no gap that matters": one reading per
    # level at one position, and the calibration model's own misfit reaches about 2.8 % of
    # the light at one level in both passes, so a misfit of 1 % there is not excluded.
    assert diag.verdict in NOT_A_GAP, diag.summary
    assert diag.summary.startswith(("Inconclusive", "No gap that matters"))
    assert diag.misfit_pct_before < 2.0 and diag.misfit["black_cd_m2_before"] < 0.5
    assert diag.loss_info["censored_readings"] >= 1
    assert abs(diag.gap_before) < 1.0
    assert diag.loss_info["noise_source"].startswith("the documented meter model")


def test_a_later_check_of_the_real_lcd_with_a_brighter_white_is_a_gain_change(tmp_path):
    """The same LCD with its white 27 % brighter (a brightness setting): a gain change, in
    words as the issue asks; never quantisation."""
    rng = np.random.default_rng(2)
    lcd = _lcd()
    cal = _calibrate(lcd.assign(luminance_cd_m2=_meter(lcd["luminance_cd_m2"], rng)),
                     tmp_path / "cal")
    diag = _diagnose(lcd.assign(luminance_cd_m2=_meter(1.27 * lcd["luminance_cd_m2"], rng)),
                     cal, tmp_path, "bright")
    assert diag.verdict.split(" + ")[0] == "gain_change", diag.summary
    assert "quantisation" not in diag.verdict
    assert "the display is 27 % brighter than its calibration at every level" in diag.summary


def _oled() -> pd.DataFrame:
    return pd.read_csv(DATA / "oled_samsung_brainardlab" / "readings.csv")


def test_the_oleds_load_is_never_a_warm_up(tmp_path):
    """The OLED calibrated with one screen layout (stabilizer 0.45, bias region 260 px), then
    measured under the 11 others in the lab's order (blocks of conditions): it dims by up to a
    third when more of the screen is bright. Was: 'warmup_drift' (88 %). Now the file's
    condition columns are kept: warm-up is not identifiable (no timestamps; the run's order
    follows the conditions), the verdict is unexplained and says the gap follows a condition,
    darker as more of the screen is bright."""
    oled = _oled()
    one = (oled["stabilizer_gray"] == 0.45) & (oled["bias_width_px"] == 260)
    cal = _calibrate(oled[one], tmp_path / "cal")
    diag = _diagnose(oled[~one], cal, tmp_path, "load")
    assert "warmup_drift" not in diag.verdict
    assert "warmup_drift" in diag.not_identifiable
    assert diag.verdict == "unexplained" and diag.unexplained_remains, diag.summary
    assert ("following stabilizer_gray" in diag.summary
            and "darker as stabilizer_gray rises" in diag.summary), diag.summary
    assert diag.loss_info["conditions"][:2] == ["stabilizer_gray", "bias_width_px"]


def test_the_oled_with_a_smaller_bright_region_is_brighter_by_a_gain(tmp_path):
    """Calibrated with a large bright region (stabilizer 0.9, bias 580: white 392 cd/m^2),
    checked with a small one (stabilizer 0, bias 100: white 580): a gain change, brighter."""
    oled = _oled()

    def cond(s, b):
        return oled[(oled["stabilizer_gray"] == s) & (oled["bias_width_px"] == b)]
    cal = _calibrate(cond(0.9, 580), tmp_path / "cal")
    diag = _diagnose(cond(0.0, 100), cal, tmp_path, "small")
    assert diag.verdict.split(" + ")[0] == "gain_change", diag.summary
    assert diag.steps[0]["params"]["k"] > 0.3
    assert "quantisation" not in diag.verdict and "warmup_drift" not in diag.verdict


def test_a_reading_at_the_meters_floor_is_censored_not_exact():
    """A zero says only 'below the floor' (here 1 cd/m^2): any prediction below the floor
    explains it (loss about 0 nats, was 0.5 (0.5 / 0.01)^2 = 1250 with the zero taken as
    exact), one far above it does not."""
    from analysis.gap.display import display_nll

    data = pd.DataFrame({"L": [0.0, 0.0], "sd": [0.01, 0.01], "censored": [True, True]})
    data.attrs["floor"] = 1.0
    below, above = display_nll(data, np.array([0.5, 1.2]))
    assert below < 1e-6 and above > 100
