"""Display layer: photometer readings vs the lab's calibration, out of sample.

The workflow a lab follows: calibrate (``python -m calibration run``: ``readings.csv``,
``validation.csv``, ``calibration.json``), later measure a check run against that calibration
(``python -m calibration check``: ``readings.csv``, ``warmup.csv``, ``check.json``), then
diagnose the check's readings (REAL) against the calibration (SIM). The readings a calibration
was fitted from cannot show its gap: the fit absorbed any offset or gain change. So readings
that are the calibration's own (same calibration_id, same rows) are never diagnosed: the
calibration's held-out validation readings are used instead, and the diagnosis says so, or it
refuses with the fix (:func:`load_display`).

The plain simulation is what stimuli assume about the display: the calibration's gamma model
at the screen centre, its above-black part scaled by the calibration's uniformity map::

    mu0(d, x, y) = Lmin + (L_cal(d) - Lmin) * rel(x, y)

(``rel`` = 1 without a uniformity map). Each catalogue candidate (registered with
:func:`analysis.gap.engine.register` under ``"display"``) extends it by one term of::

    mu = Lmin + (L_cal(drive) - Lmin) * rel * gain + offset

====================  ====================================================================
candidate             term (parameters fitted on the training readings)
====================  ====================================================================
black_offset          offset += c (cd/m^2): extra black level or reflected ambient light
gain_change           gain *= 1 + k: the white level changed since the calibration
nonuniformity         gain *= 1 + f (x^2 + y^2) / 2 + g x + h y
warmup_drift          gain *= 1 - w exp(-t / tau), t = s since the first reading, tau at most
                      3 records long (a slower drift is nearly a constant gain)
quantisation          drive rounded to a ``bits``-bit DAC grid before the gamma model
====================  ====================================================================

Loss per reading: Gaussian negative log-likelihood (nats) with the photometer's noise
``sd^2 = a^2 + s L + (b L)^2`` (s: shot noise, where the pairs show it) and a gain between
passes (:data:`~analysis.gap.display.model.PASS_GAIN_SD` of the light above black), the calibration's
gamma parameters moved within their own uncertainty to fit each fold's training readings (:func:`display_loss_given`: a calibration
fitted from noisy readings is no gap in itself), and beside them a slow wander of the black and
the gain in time between and during passes (:func:`~analysis.gap.display.model.pass_columns`:
2 % of the black and 0.3 % of the light per coefficient, never past 1 SD; the misfits in the
lab's units are measured without it); a reading at or below the
meter's floor is censored, ``-log P(L <= floor)``. Effects these readings cannot identify
(:func:`display_identifiability`) are left out of the ranking and named in the words. The noise is measured from pairs of consecutive repeats of the same
patch (and the check's warm-up series; without any, the calibration's noise or the documented
meter model, named in ``loss_info``), with slow changes of the display between the two
readings of a pair modelled as a smooth function of time (:func:`fit_noise_drift`), so a
warm-up between repeats is not counted as noise. The floor (the loss of a model right up to
noise) is ``0.5 log(2 pi sd^2) + 0.5`` per reading. The ceiling (:func:`display_ceiling`) is a
penalised smooth of level, position and time fitted to the residuals; a chosen model that
stays significantly above it leaves a gap the catalogue does not explain.

Held out: each patch's repeats alternate between two halves, and the halves are cross-fitted
(:func:`display_folds`: each fitted on the other and held out once), so every reading is held
out and a small effect seen in few readings (a black offset in the darkest patches) is tested
on all of them.

Files (the shape every gap layer shares)
----------------------------------------
``data.py``
    Reading and checking the files: :func:`load_display` (out of sample) and its checks.
``model.py``
    The simulation: :func:`display_frame` (plain prediction, noise SD), the extended mean,
    :func:`display_nll` / :func:`display_loss`, the noise and drift fit
    (:func:`fit_noise_drift`), the held-out folds (:func:`split_display`,
    :func:`display_folds`) and :func:`display_unit_ids`.
``ceiling.py``
    The flexible model and the floor: :func:`display_ceiling`, :func:`display_floor`; how far
    in the lab's units (:func:`display_misfit`: RMS and worst misfit in % of luminance before,
    after and of the ceiling, cd/m^2 near black; :func:`display_misfit_size`: the size held
    to the design's ``[gap] display_tolerance_pct``, below which a significant difference is
    "no gap that matters").
``null/``
    What the null allows besides a change of the display: the meter's noise, its drift between
    repeats and its floor (``null/noise.py``: a zero is censored below the meter's own floor,
    never the lowest positive reading), the calibration's own uncertainty and model misfit
    (``null/calerror.py``).
``where.py``
    Where the gap lies: :func:`display_where` (words), :func:`localise_display` (numbers).
``candidates.py``
    One registered Candidate per effect (the table above), :data:`DISPLAY_CANDIDATES` and
    :data:`DISPLAY_MIN_SHARE`.

``__init__.py`` (here)
    The layer's face to the engine, :func:`plan` (the same in every layer).

Importing the package registers the display candidates (the engine's ``catalogue("display")``
imports it).
"""

from pathlib import Path

import numpy as np

from analysis.gap.display.candidates import (
    DISPLAY_CANDIDATES,
    DISPLAY_MIN_GAIN,
    DISPLAY_MIN_SHARE,
    display_identifiability,
    quantisation_resolution,
)
from analysis.gap.display.ceiling import (
    DISPLAY_SIZE_UNIT,
    NEAR_BLACK_FRACTION,
    display_ceiling,
    display_floor,
    display_misfit,
    display_misfit_size,
    display_misfit_upper,
)
from analysis.gap.display.data import load_display
from analysis.gap.display.model import (
    display_folds,
    display_frame,
    display_loss,
    display_loss_given,
    display_loss_info,
    display_nll,
    display_unit_ids,
    fit_noise_drift,
    split_display,
)
from analysis.gap.display.power import display_power
from analysis.gap.display.where import display_where, localise_display
from analysis.gap.engine import DiagnosisSettings, LayerFunctions, LayerPlan

__all__ = [
    "DISPLAY_CANDIDATES",
    "DISPLAY_MIN_GAIN",
    "DISPLAY_MIN_SHARE",
    "DISPLAY_SIZE_UNIT",
    "NEAR_BLACK_FRACTION",
    "display_ceiling",
    "display_floor",
    "display_folds",
    "display_frame",
    "display_identifiability",
    "display_loss",
    "display_loss_given",
    "display_loss_info",
    "display_misfit",
    "display_misfit_size",
    "display_misfit_upper",
    "display_nll",
    "display_power",
    "display_unit_ids",
    "display_where",
    "fit_noise_drift",
    "load_display",
    "localise_display",
    "plan",
    "quantisation_resolution",
    "split_display",
]


def plan(real, sim, design, rng: np.random.Generator, *, n_boot: int, **_) -> LayerPlan:
    """Photometer readings (``readings.csv``, its folder or a frame) against the calibration
    (``calibration.json``, its folder or a Calibration), cross-fitted over folds of readings
    drawn from ``rng``. The calibration is the display's simulation; from ``design`` (the
    shipped design's when None) only ``[gap] display_tolerance_pct``: the verdict is no gap
    that matters only where the upper 95 % bound of the systematic misfit
    (:func:`display_misfit_upper`) lies below it; neither a gap nor that, inconclusive, with
    the misfit these readings detect and how many more decide (:func:`display_power`).
    The misfit in the lab's units (:func:`display_misfit`) is recorded in the diagnosis."""
    if design is None:
        from studydesign import load_design

        design = load_design()
    readings, cal = (load_display(real, sim) if isinstance(real, (str, Path)) else (real, sim))
    data = display_frame(readings, cal)
    folds, text = display_folds(data, rng)
    bits, note = quantisation_resolution(data)
    functions = LayerFunctions(loss=display_loss_given, floor=display_floor,
                               ceiling=display_ceiling, where=display_where,
                               size=display_misfit_size, size_upper=display_misfit_upper,
                               unit_ids=display_unit_ids)
    # The noise variance measured from n pairs is known to a relative SD of sqrt(2 / n) (a
    # chi-square's), so the floor, 0.5 log(2 pi sd^2) + 0.5 per reading, to 0.5 sqrt(2 / n)
    # nats: the floor is called mis-estimated only beyond that (an assumed noise: 0).
    pairs = data.attrs["noise"]["n_pairs"]
    floor_sd = 0.5 * float(np.sqrt(2.0 / pairs)) if pairs else 0.0
    # The calibration model's misfit (the readings' ``lof``) is the same at a level in every
    # pass, so the calibration's allowed shift, fitted on one half, removes part of it from the
    # other: the floor lies between the one that counts it in full and the one without it (the
    # mean of 0.5 lof^2 / sd^2 per reading lower). Called mis-estimated only below both: that
    # range is a further 1.96 SDs of the floor's own error.
    lof_share = float(np.mean(0.5 * data["lof"].to_numpy(float) ** 2
                              / data["sd"].to_numpy(float) ** 2))
    floor_sd = float(np.hypot(floor_sd, lof_share / 1.96))
    zeros = readings.attrs.get("display_source", {}).get("zero_evidence", ())
    return LayerPlan(
        functions, DiagnosisSettings(n_boot=n_boot, min_share=DISPLAY_MIN_SHARE,
                                     min_gain=DISPLAY_MIN_GAIN, floor_sd=floor_sd,
                                     min_size=design.gap.display_tolerance_pct,
                                     size_unit=DISPLAY_SIZE_UNIT,
                                     size_source="the design's [gap] display_tolerance_pct",
                                     tolerate_chosen=True),
        localise=lambda _diag, rng: localise_display(data, rng, n_boot=min(n_boot, 500)),
        folds=folds, split=text,
        loss_info=display_loss_info(data) | {"quantisation_visible_bits": bits},
        warnings=(*zeros, *((note,) if note else ())), cannot_exclude=tuple(zeros),
        not_identifiable=display_identifiability(data),
        sizes=lambda diag: display_misfit(folds, [(st["added"], st["params"])
                                                  for st in diag.steps]),
        # No more repeats decide what blacks read as 0 leave open (cannot_exclude).
        power=None if zeros else (lambda diag: display_power(folds, diag)))
