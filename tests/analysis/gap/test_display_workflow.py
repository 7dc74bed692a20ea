"""Display diagnosis as a lab runs it: calibrate, check run later, diagnose out of sample.

Readings come from analysis.gapbench.bench_display.GOGDisplay, a gain-offset-gamma CRT written
apart from calibration.SimulatedCRT and from the diagnosis (its own vignetting, warm-up and a
photometer with shot noise that reports four significant digits). Calibrations are written with
the display's own transfer function (``fit="truth"``), so no test depends on the accuracy of
the calibration package's gamma fit.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from analysis.gap import GapError
from analysis.gap.diagnose import diagnose
from analysis.gap.display import fit_noise_drift
from analysis.gap.engine import candidate, catalogue
from analysis.gapbench import bench_display
from analysis.gapbench.bench_display import GOGDisplay
from calibration import load_readings

DISPLAY = GOGDisplay()


def _lab(tmp_path, seed, *, cal_display=DISPLAY, validation=17):
    rng = np.random.default_rng(seed)
    bench_display.write_calibration_folder(tmp_path / "cal", cal_display, rng,
                                           n_validation=validation)
    return rng


def _check(tmp_path, rng, display, **kw):
    return bench_display.write_check_folder(tmp_path / "check", display, rng,
                                            calibration=tmp_path / "cal", **kw)


def test_warmup_drift_between_repeats_is_modelled_in_time_not_counted_as_noise(tmp_path):
    """Repeats measured in passes from power-on while the display warms up (15 %, tau 450 s):
    the spread between repeats is mostly drift. The photometer's noise (0.25 % + shot noise,
    about 0.35 % at white) must still be measured as such, and the drift found."""
    rng = _lab(tmp_path, 21)
    warming = replace(DISPLAY, warmup_frac=0.15)
    _check(tmp_path, rng, warming, order="passes", warmup=False, start_s=0.0, n_levels=17)
    read = load_readings(tmp_path / "check" / "readings.csv")
    # What the spread of repeats alone says (the old floor): several times the true noise.
    bright = read[read["level"] >= 0.5].groupby(["x_norm", "y_norm", "level"])
    spread = bright["luminance_cd_m2"].agg(lambda v: np.std(v, ddof=1) / np.mean(v))
    assert spread.mean() > 0.015
    diag, _ = diagnose("display", tmp_path / "check", tmp_path / "cal", None, seed=1, n_boot=300)
    assert 0.002 < diag.loss_info["noise_rel"] < 0.006
    assert diag.loss_info["drift_between_repeats_pct"] > 3
    assert diag.verdict.split(" + ")[0] == "warmup_drift"
    assert diag.gap_before_ci[0] > 0


def test_noise_and_drift_recovered_from_pairs_of_repeats():
    """Parameter recovery: Gaussian noise a = 0.01 cd/m^2, b = 0.4 %, with a 5 % drift between
    passes; a and b come back within 25 %, and without the drift no drift is fitted."""
    rng = np.random.default_rng(3)
    sched = bench_display.display_schedule(rng, repeats=3, order="passes")
    for drift, want_drift in ((0.05, True), (0.0, False)):
        disp = replace(DISPLAY, warmup_frac=drift, floor_cd_m2=0.01, shot_cd_m2=0.0,
                       rel_noise=0.004, digits=7)
        read = bench_display.measure(disp, sched, rng, calibration_id="x", start_s=0.0)
        noise = fit_noise_drift([read])
        assert noise["abs"] == pytest.approx(0.01, rel=0.25)
        assert noise["rel"] == pytest.approx(0.004, rel=0.25)
        assert (noise["drift_knots"] is not None) == want_drift


def test_ambient_light_in_a_check_run_is_found(tmp_path):
    """+1.8 cd/m^2 of room light during a later check run: black_offset, c = 1.8 cd/m^2."""
    rng = _lab(tmp_path, 5)
    _check(tmp_path, rng, replace(DISPLAY, ambient_cd_m2=DISPLAY.ambient_cd_m2 + 1.8))
    diag, _ = diagnose("display", tmp_path / "check", tmp_path / "cal", None, seed=2, n_boot=300)
    assert diag.verdict.split(" + ")[0] == "black_offset"
    assert diag.steps[0]["params"]["c"] == pytest.approx(1.8, abs=0.05)
    assert diag.loss_info["source"]["kind"] == "check"
    assert diag.loss_info["source"]["in_sample_rows"] == 0


def test_the_calibrations_own_readings_are_not_diagnosed_in_sample(tmp_path):
    """A display calibrated with the +1.8 cd/m^2 present, its own readings passed as REAL: the
    diagnosis says they are in-sample and diagnoses the held-out validation readings."""
    lit = replace(DISPLAY, ambient_cd_m2=DISPLAY.ambient_cd_m2 + 1.8)
    _lab(tmp_path, 6, cal_display=lit)
    with pytest.warns(UserWarning, match="fitted from"):
        diag, _ = diagnose("display", tmp_path / "cal", tmp_path / "cal", None, seed=2,
                                         n_boot=300)
    src = diag.loss_info["source"]
    assert src["kind"] == "validation" and src["in_sample_rows"] > 100
    assert src["real"].endswith("validation.csv")
    # Cross-fitted: each of the 17 validation readings held out once, none of the calibration's.
    assert len(diag.heldout) == 17
    assert "black_offset" not in diag.verdict


@pytest.mark.parametrize("validation", [0, 9])
def test_in_sample_readings_without_enough_held_out_readings_are_refused(tmp_path, validation):
    _lab(tmp_path, 7, validation=validation)
    with pytest.raises(GapError, match="python -m calibration check --calibration"):
        diagnose("display", tmp_path / "cal", tmp_path / "cal", None, seed=0)


def test_a_bad_check_record_is_refused(tmp_path):
    rng = _lab(tmp_path, 8)
    _check(tmp_path, rng, DISPLAY)
    (tmp_path / "check" / "check.json").write_text(json.dumps({"kind": "calibration"}))
    with pytest.raises(GapError, match="not a check record"):
        diagnose("display", tmp_path / "check", tmp_path / "cal", None, seed=0)


def test_a_check_of_another_calibration_is_flagged(tmp_path):
    rng = _lab(tmp_path, 9)
    bench_display.write_check_folder(tmp_path / "check", DISPLAY, rng,
                                     calibration=tmp_path / "cal", checked_id="other-cal")
    with pytest.warns(UserWarning, match="checked calibration 'other-cal'"):
        diag, _ = diagnose("display", tmp_path / "check", tmp_path / "cal", None, seed=0,
                                         n_boot=200)
    assert diag.loss_info["source"]["notes"]


@pytest.mark.parametrize("effect", sorted(bench_display.OUT_OF_CATALOGUE))
def test_out_of_catalogue_display_effect_leaves_a_gap_above_the_ceiling(tmp_path, effect):
    """A mid-range gamma bump, or a gamma that changes across the screen (position x level):
    the catalogue's best model stays significantly above the flexible ceiling, and the
    verdict says where (the bump: mid drive levels, brighter; the gamma rising to the right:
    brighter on the left, darker on the right)."""
    rng = _lab(tmp_path, 11)
    _check(tmp_path, rng, replace(DISPLAY, **{effect: bench_display.OUT_OF_CATALOGUE[effect]}))
    diag, _ = diagnose("display", tmp_path / "check", tmp_path / "cal", None, seed=3, n_boot=300)
    assert diag.verdict == "unexplained"
    assert diag.remaining["ci"][0] > 0 and diag.remaining["gap"] > 1
    # The bump: at some drive levels (beside a gain change, the extended model is brighter
    # at the top, so the most concentrated excess may lie there).
    where = {"mid_gamma_bump": "mostly at drive levels",
             # Since issue 29 the uniformity map may move within its own uncertainty per
             # position, which takes part of the gradient: the excess is at a position, or
             # at mid levels, brighter on the left and darker on the right.
             "gamma_gradient": ("mostly at screen position (",
                                "towards the left, darker towards the right")}[effect]
    assert any(w in diag.remaining["where"] for w in (where if isinstance(where, tuple)
                                                     else (where,)))
    assert diag.remaining["where"] in diag.summary


@pytest.mark.parametrize("effect", ["none", "black_offset", "warmup_drift"])
def test_nothing_remains_above_the_ceiling_when_the_catalogue_explains_it(tmp_path, effect):
    rng = _lab(tmp_path, 12)
    strength = 0.0 if effect == "none" else candidate("display", effect).default_strength
    display = DISPLAY if effect == "none" else bench_display.with_effect(DISPLAY, effect,
                                                                         strength)
    _check(tmp_path, rng, display, warmup=effect != "warmup_drift",
           start_s=30.0 if effect == "warmup_drift" else 1800.0)
    diag, _ = diagnose("display", tmp_path / "check", tmp_path / "cal", None, seed=3, n_boot=300)
    # Nothing added: not a gap. Inconclusive since issue 43 (was "no significant gap"): the
    # check's readings leave about 1.1 % at drive level 0.13 with an upper bound of 1.9 %, so
    # they cannot exclude a misfit of the 1 % tolerance.
    assert diag.verdict.split(" + ")[0] == ("inconclusive" if effect == "none" else effect)
    assert diag.remaining["ci"][0] <= 0


def test_a_faint_black_offset_beside_a_warm_up_is_named_with_it(tmp_path):
    """0.05 cd/m^2 of extra black light shows only in the darkest patches. With one split it
    was tested on half of them and lost to a 0.1 % nonuniformity (verdict 'warmup_drift +
    nonuniformity' for this lab, seed 8, found by trying seeds 0-9); cross-fitted, every
    reading is held out once and the offset is named. (It was 0.025 cd/m^2: since issue 29
    the calibration may move within its own uncertainty, and its black level fitted from noisy
    readings may be off by about that much, so 0.025 is no longer told from it. Its step's p,
    about 0.01 against 0.05 / 4, is resolved with 2000 bootstrap resamples, the default: with
    300 it moved between 2 and 4 of 301 as the noise model changed.)"""
    rng = _lab(tmp_path, 8)
    real = bench_display.with_effect(bench_display.with_effect(DISPLAY, "black_offset", 0.05),
                                     "warmup_drift", 0.04)
    check = _check(tmp_path, rng, real, warmup=False, start_s=30.0)
    diag, _ = diagnose("display", check, tmp_path / "cal", None, seed=1, n_boot=2000)
    assert set(diag.verdict.split(" + ")) == {"warmup_drift", "black_offset"}
    assert len(diag.heldout) == len(load_readings(check / "readings.csv"))
    assert "cross-fitted" in diag.split


def test_display_candidates_are_registered_objects():
    names = [c.name for c in catalogue("display")]
    assert names == ["black_offset", "gain_change", "nonuniformity", "warmup_drift",
                     "quantisation"]
    for c in catalogue("display"):
        assert c.apply and c.inject and c.truth and c.default_strength > 0 and c.units
    with pytest.raises(GapError, match="unknown candidate 'gain' for layer 'display'"):
        candidate("display", "gain")


def test_display_injectors_change_the_simulated_crt():
    from calibration import load_crt

    crt = load_crt()
    assert candidate("display", "black_offset").inject(crt, 0.5).ambient_cd_m2 == \
        pytest.approx(crt.ambient_cd_m2 + 0.5)
    assert candidate("display", "quantisation").inject(crt, 2.0).bits == crt.bits - 2
    assert candidate("display", "warmup_drift").truth(0.03)["w"] == 0.03
