"""Blacks that read 0 in a check where the calibration saw light (issue 44, item 2): evidence
that the light there fell below the meter's floor, not a value to censor away."""

from __future__ import annotations

import numpy as np
import pandas as pd

from calibration.noise import zero_bound

__all__ = ["zeros_against_calibration"]


#: A zero contradicts the calibration where it saw at least this many times the meter's
#: documented floor (a meter without a documented floor: any light its own readings showed).
_ZERO_EVIDENCE_FACTOR = 3.0


def zeros_against_calibration(readings: pd.DataFrame, fitted_rows, cal, path) -> list[str]:
    """Notes naming the drive levels that read 0 where the calibration saw light well above the
    meter's floor (its own readings there all positive, or, without them, its fit).

    A meter reads 0 only below its floor, so such zeros are evidence: the light fell below
    what the meter reads (a black turned down) or the meter did not measure it (a wrong range,
    a dark reading subtracted). The diagnosis censors a zero below the meter's floor, which for
    a meter whose floor is not documented may be as high as the lowest positive reading, so
    such a check could read as no gap (was: 18 blacks read 0 against a calibration's 0.35
    cd/m^2, "no significant gap", no word). The display layer hands these notes to the engine
    as reasons the data cannot exclude a gap (``LayerPlan.cannot_exclude``): the verdict is
    then never ``no_gap_that_matters``.
    """
    lum = readings["luminance_cd_m2"].to_numpy(float)
    if not (lum <= 0).any():
        return []
    level = readings["level"].to_numpy(float)
    device = str(readings["device"].iloc[0]) if "device" in readings else ""
    floor, floor_source = zero_bound(device or cal.device, None, 0.0)
    documented = floor > 0
    notes = []
    for lv in np.unique(level[lum <= 0]):
        if fitted_rows is not None:
            own = fitted_rows["luminance_cd_m2"].to_numpy(float)[
                np.isclose(fitted_rows["level"].to_numpy(float), lv)]
            if not own.size or (own <= 0).any():  # the meter was at its floor then too
                continue
            saw, how = float(own.mean()), f"the mean of its {own.size} readings at that level"
        else:
            saw, how = float(np.ravel(cal.luminance_for_drive(lv))[0]), "its fit"
        if saw <= _ZERO_EVIDENCE_FACTOR * floor or saw <= 0:
            continue
        at = np.isclose(level, lv)
        n_zero = int((at & (lum <= 0)).sum())
        meter = (f", {saw / floor:.0f} x the meter's floor ({floor_source}, {floor:g} cd/m^2)"
                 if documented else "")
        notes.append(
            f"{path}: {n_zero} of {int(at.sum())} readings at drive level {lv:g} read 0 "
            f"cd/m^2 where calibration {cal.calibration_id!r} saw {saw:.3g} cd/m^2 ({how}"
            f"{meter}). A meter reads 0 only below its floor: since the calibration the light "
            "there fell below what the meter reads (the black turned down, another display "
            "mode) or the meter did not measure it (a wrong range, its cap on, a dark reading "
            "subtracted). These zeros are evidence of a change the diagnosis cannot size (a "
            "zero is censored below the meter's floor), so the check cannot say there is "
            "no gap that matters: check the meter's range and zero and the display's black, then remeasure")
    return notes
