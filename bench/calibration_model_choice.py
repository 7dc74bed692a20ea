"""Claim: choosing the gamma model by held-out error linearises a CRT with a gun threshold better
than PsychoPy's default (GammaCalculator, eq. 1).

Side by side on the same simulated readings (the shipped crt.toml display, 17 levels x 2 repeats,
its measurement noise), for several noise seeds:
- ours: fit_gamma_models + choose_gamma_model, inverse = Calibration.drive_for_fraction;
- PsychoPy: GammaCalculator(inputs, mean lums per level, eq=1), inverse = gammaInvFun(eq=1).
Each inverse is applied to 101 evenly spaced fractions of the luminance range, quantised to 8 bits,
and shown on the noiseless simulated CRT; printed: the largest deviation from linear luminance in %
of the range (mean over seeds) and the ratio PsychoPy / ours.
"""

from __future__ import annotations

import time

import numpy as np

from calibration import choose_gamma_model, fit_gamma_models, load_crt
from calibration.gamma import gamma_drive_for_luminance


def main(n_seeds: int = 10) -> None:
    from psychopy.monitors.calibTools import GammaCalculator, gammaInvFun

    crt = load_crt()
    levels = np.repeat(np.round(np.linspace(0, 1, 17) * 255) / 255, 2)
    f = np.linspace(0, 1, 101)
    true_min, true_max = float(crt.luminance(0.0)), float(crt.luminance(1.0))

    def deviation_pct(drive):
        shown = crt.luminance(np.round(np.clip(drive, 0, 1) * 255) / 255)
        return 100 * np.max(np.abs((shown - true_min) / (true_max - true_min) - f))

    ours, theirs, t_ours, t_theirs = [], [], 0.0, 0.0
    for seed in range(n_seeds):
        lum = crt.luminance(levels, rng=np.random.default_rng(seed))
        t = time.perf_counter()
        best = choose_gamma_model(fit_gamma_models(levels, lum))
        lo, hi = float(best.luminance(0.0)), float(best.luminance(1.0))
        drive = gamma_drive_for_luminance(lo + f * (hi - lo), model=best.model,
                                          params=best.params)
        t_ours += time.perf_counter() - t
        ours.append(deviation_pct(drive))
        t = time.perf_counter()
        u = np.unique(levels)
        means = [lum[levels == v].mean() for v in u]
        calc = GammaCalculator(inputs=list(u), lums=means, eq=1)
        drive_pp = np.asarray(gammaInvFun(f, calc.min, calc.max, calc.gamma, eq=1))
        t_theirs += time.perf_counter() - t
        theirs.append(deviation_pct(drive_pp))
    o, p = float(np.mean(ours)), float(np.mean(theirs))
    print(f"simulated CRT (crt.toml), {n_seeds} noise seeds, 17 levels x 2 repeats")
    print("max deviation from linear luminance after correction, % of range (mean over seeds):")
    print(f"  ours (held-out model choice): {o:.3f} %   fit time {t_ours / n_seeds:.2f} s")
    print(f"  PsychoPy GammaCalculator eq1: {p:.3f} %   fit time {t_theirs / n_seeds:.3f} s")
    print(f"ratio PsychoPy / ours: {p / o:.1f}x")


if __name__ == "__main__":
    main()
