"""A lab's readings file through the display layer (issue 40, item 9): readings that cannot
show a display's gap are refused by ``analysis gap diagnose --layer display`` with the file,
the value and the fix (rc 2, no report), the calibration's own readings are recognised by
their content whatever the file's name or calibration_id, and rows dropped are said.

Readings come from analysis.gapbench.bench_display (a CRT written apart from the diagnosis)."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from analysis.gap.__main__ import main as gap_main
from analysis.gap.display.data import load_display
from analysis.gapbench import bench_display
from analysis.gapbench.bench_display import GOGDisplay


@pytest.fixture
def lab(tmp_path):
    """A calibration folder (no held-out validation readings) and its own readings as a
    lab's table: the procedure's columns less calibration_id, device and raw_reply."""
    bench_display.write_calibration_folder(tmp_path / "cal", GOGDisplay(),
                                           np.random.default_rng(4), n_validation=0)
    own = pd.read_csv(tmp_path / "cal" / "readings.csv", dtype=str, keep_default_na=False)
    return tmp_path, own[["timestamp_utc", "x_norm", "y_norm", "level", "repeat",
                          "luminance_cd_m2"]]


def _diagnose(tmp_path, real, capsys) -> str:
    out = tmp_path / "report"
    rc = gap_main(["diagnose", "--layer", "display", "--real", str(real), "--sim",
                   str(tmp_path / "cal"), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and not (out / "diagnosis.json").exists(), err
    line = err.strip().splitlines()[-1]
    assert line.startswith("error: ") and str(real) in line
    return line


def test_readings_that_are_all_zero_are_refused_as_calibration_fit_does(lab, capsys):
    tmp_path, own = lab
    own.assign(luminance_cd_m2="0").to_csv(tmp_path / "zeros.csv", index=False)
    line = _diagnose(tmp_path, tmp_path / "zeros.csv", capsys)
    assert "do not rise with the drive (level means 0 to 0 cd/m^2" in line
    assert "photometer was aimed" in line


def test_ten_readings_at_one_drive_level_are_refused_not_a_black_offset(lab, capsys):
    tmp_path, own = lab
    one = own[own["level"] == own["level"].iloc[5]].head(1)
    one = pd.concat([one] * 10, ignore_index=True)
    one["repeat"] = [str(i) for i in range(10)]
    one["luminance_cd_m2"] = [f"{40 + 0.1 * i:.2f}" for i in range(10)]
    one.to_csv(tmp_path / "one_level.csv", index=False)
    line = _diagnose(tmp_path, tmp_path / "one_level.csv", capsys)
    assert "10 readings at 1 drive level(s)" in line and ">= 3 distinct levels" in line


def test_the_calibrations_own_readings_under_another_name_are_in_sample(lab, capsys):
    """The very readings it was fitted from, saved by the lab under another name and without
    the calibration's id: recognised by their content; no held-out readings, so refused."""
    tmp_path, own = lab
    own.to_csv(tmp_path / "display_march.csv", index=False)
    line = _diagnose(tmp_path, tmp_path / "display_march.csv", capsys)
    assert "171 of 171 readings" in line and "was fitted from (the same readings)" in line
    assert "python -m calibration check --calibration" in line


def test_a_check_run_is_not_taken_for_the_calibrations_own_readings(tmp_path):
    rng = np.random.default_rng(4)
    bench_display.write_calibration_folder(tmp_path / "cal", GOGDisplay(), rng,
                                           n_validation=0)
    bench_display.write_check_folder(tmp_path / "check", GOGDisplay(), rng,
                                     calibration=tmp_path / "cal")
    readings, _ = load_display(tmp_path / "check", tmp_path / "cal")
    assert readings.attrs["display_source"]["in_sample_rows"] == 0


def test_negative_readings_dropped_are_said_with_their_lines(tmp_path):
    """A dark patch read below 0 by the meter: dropped (the calibration package's rule), and
    now said, with the lines, in a warning kept in the diagnosis's source notes."""
    rng = np.random.default_rng(4)
    bench_display.write_calibration_folder(tmp_path / "cal", GOGDisplay(), rng,
                                           n_validation=0)
    check = bench_display.write_check_folder(tmp_path / "check", GOGDisplay(), rng,
                                             calibration=tmp_path / "cal")
    frame = pd.read_csv(check / "readings.csv", dtype=str, keep_default_na=False)
    frame.loc[frame.index[:3], "luminance_cd_m2"] = "-0.012"
    frame.to_csv(check / "readings.csv", index=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        readings, _ = load_display(check, tmp_path / "cal")
    notes = readings.attrs["display_source"]["notes"]
    said = [n for n in notes if "rows dropped" in n]
    assert said and "3 of" in said[0] and "lines 2, 3, 4" in said[0]
    assert "3 negative luminance(s)" in said[0]
    assert any("rows dropped" in str(w.message) for w in caught)
    assert len(readings) == len(frame) - 3


@pytest.mark.parametrize("black", ["0", "0.035"])
def test_a_black_that_reads_zero_where_the_calibration_saw_light_is_named(tmp_path, black):
    """Issue 44, item 2: a check whose 18 black readings are all 0 (a meter at its floor or on
    a wrong range, the black knob turned down) against a calibration that measured 0.35
    cd/m^2 there read "no significant gap" without a word. The zeros are named with the
    verdict (the layer's warnings, kept in diagnosis.json); a black at a tenth, read as light,
    is the diagnosis's to size (no such warning)."""
    from analysis.gap.display import plan

    rng = np.random.default_rng(4)
    bench_display.write_calibration_folder(tmp_path / "cal", GOGDisplay(), rng,
                                           n_validation=0)
    check = bench_display.write_check_folder(tmp_path / "check", GOGDisplay(), rng,
                                             calibration=tmp_path / "cal")
    frame = pd.read_csv(check / "readings.csv", dtype=str, keep_default_na=False)
    at_black = frame["level"].astype(float) == 0
    assert at_black.sum() == 18
    frame.loc[at_black, "luminance_cd_m2"] = black
    frame.to_csv(check / "readings.csv", index=False)
    layer = plan(check, tmp_path / "cal", None, np.random.default_rng(0), n_boot=10)
    named = [w for w in layer.warnings if "read 0 cd/m^2" in w]
    if black == "0":
        assert len(named) == 1, layer.warnings
        assert "18 of 18 readings at drive level 0 read 0 cd/m^2 where calibration " \
               "'lab-cal' saw 0.351 cd/m^2" in named[0]
        assert "cannot say there is no gap that matters" in named[0]
        assert layer.cannot_exclude == tuple(named)
        from analysis.gap import diagnose

        diag = diagnose("display", check, tmp_path / "cal", None, seed=0, n_boot=200)[0]
        assert diag.verdict == "inconclusive", diag.summary  # was no_gap_that_matters
        assert "The data cannot exclude a gap" in diag.summary
        assert "is excluded where the meter measured" in diag.summary
        # More repeats cannot decide what the zeros leave open: no power model, no to_decide.
        assert layer.power is None and not diag.to_decide, diag.to_decide
        assert "check the meter's range and zero" in named[0]
    else:
        assert named == [] and layer.cannot_exclude == ()
