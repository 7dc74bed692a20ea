"""Simulated data sets for the mixed-model tests (plain numpy; the source study's 2 x 9 x 9 design).

Each case is a response built from known fixed effects and per-participant random effects, so a
fit can be checked against the truth and against lme4 on identical numbers.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.lmm import standardise_predictors

# name: (participants, fixed effects (1, g, d, g:d), random SDs (1, g, d), correlation of 1 and g,
#        residual SD, fraction of trials dropped)
CASES = {
    "gloss": (11, (50.0, 25.0, 6.0, 3.0), (5.0, 4.0, 2.0), 0.3, 12.0, 0.0),
    "depth_bc": (11, (1.9, 0.1, 0.9, 0.0), (0.15, 0.05, 0.2), -0.2, 0.35, 0.0),
    "singular_zero_slope": (11, (50.0, 25.0, 6.0, 3.0), (5.0, 4.0, 0.0), 0.3, 12.0, 0.0),
    "singular_tiny": (11, (50.0, 25.0, 6.0, 0.0), (0.05, 0.05, 0.05), 0.0, 12.0, 0.0),
    "singular_perfect_cor": (11, (50.0, 25.0, 6.0, 3.0), (5.0, 4.0, 2.0), 1.0, 12.0, 0.0),
    "unbalanced_5": (5, (50.0, 25.0, 6.0, 3.0), (6.0, 3.0, 3.0), -0.4, 10.0, 0.2),
}


def simulate_case(name: str, design, rng: np.random.Generator) -> pd.DataFrame:
    """A model frame (participant, gloss, depth, y) for one of `CASES`."""
    n_part, beta, sds, rho, sigma, drop = CASES[name]
    stim = standardise_predictors(design.stimuli(), design)
    rows = []
    cov = np.diag(np.square(sds))
    cov[0, 1] = cov[1, 0] = rho * sds[0] * sds[1]
    for k in range(n_part):
        b = rng.multivariate_normal(np.zeros(3), cov, method="eigh")
        g = stim["gloss"].to_numpy()
        d = stim["depth"].to_numpy()
        y = (beta[0] + b[0] + (beta[1] + b[1]) * g + (beta[2] + b[2]) * d + beta[3] * g * d
             + rng.normal(0.0, sigma, g.size))
        keep = rng.random(g.size) >= drop
        rows.append(pd.DataFrame({"participant": f"P{k + 1:02d}", "gloss": g[keep],
                                  "depth": d[keep], "y": y[keep]}))
    return pd.concat(rows, ignore_index=True)


def sample_thetas(rng: np.random.Generator, n: int = 4) -> np.ndarray:
    """Thetas at which to compare deviances: lme4's start, boundary points and random ones."""
    fixed = [[1.0, 0, 0, 1.0, 0, 1.0], [0.5, 0.1, -0.2, 0.0, 0.3, 0.0], [0.0] * 6]
    rand = rng.normal(0.0, 0.5, (n, 6))
    rand[:, [0, 3, 5]] = np.abs(rand[:, [0, 3, 5]])
    return np.vstack([fixed, rand])
