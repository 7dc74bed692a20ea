"""The ceiling's coefficient draws (observer layer): the estimation error of its smooth
corrections, on the data it was fitted to and on a larger data set like it.

The misfit is a distance from the ceiling (:mod:`analysis.gap.observer.ceiling`), so the
ceiling's own estimation error belongs in the misfit's bound and in the simulation of a larger
data set (:mod:`analysis.gap.observer.power`). Its mean and time corrections are ridge fits
whose penalty (per training trial) is chosen by cross-validation with the one-standard-error
rule, and with more data it falls: the corrections take up more and their error does not shrink
as one over the data's size. Nothing added, 6 participants against a pilot of 8
(``bench/bench_gap_power.py --observer``): the folds' choices ranged 0.1-1000 per trial; the
SD of the squared misfit over the draws was 0.008 slider units^2, refitted in full at 12
participants 0.017-0.029 and at 24 0.015. Drawn again at the penalty that would follow a
fixed prior (the chosen one over the size factor) or the least held-out error's over it, the
simulation put it at 0.007-0.009 at 12 and named 18 participants, which decided 3 of 8 data
sets refitted in full against 86 % simulated. So a larger data set's draws are made with no
penalty to speak of (:data:`LEAST_PENALTY`, the ceiling's least): the spread of an unpenalised
fit, which a ridge penalty can only narrow, on today's data is ``factor`` times what it would be
on ``factor`` times the data (:meth:`CoefficientDraws.at`). It is still below what was measured
(0.013 at 12, 0.009 at 24): a larger data set also sees more of the simulation's own error (a
pilot's sampling error), which this does not draw.

Also tried and dropped: simulating the choice cross-validation would make at the larger size
(each penalty's held-out loss with its estimation error's part shrunk to one ``f``-th, the
one-standard-error rule over ``f`` times the trials) and the misfit measured there (the point
fit at that penalty, less today's estimation error beyond that size's). It put the misfit of
the case above at 0.25-0.27 slider units from 9 to 48 participants (measured in full: 0.23 at
12, 0.21-0.29 at 18, 0.19-0.26 at 36) and named 18 participants (89 % simulated, 3 of 8
decided); for depth rising with gloss at 4 participants (truth 0.3 slider units) it put the
misfit at 0.24-0.26 where 24 participants measured 0.35-0.40, and named "more than 32".
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

__all__ = ["LEAST_PENALTY", "CoefficientDraws"]

#: The ceiling's least ridge penalty per training trial (all but none): the corrections'
#: penalty at a larger data set (see the module's docstring).
LEAST_PENALTY = 1e-4


def _penalty(x: np.ndarray, intercept: bool = True) -> np.ndarray:
    """Ridge penalty matrix, each column scaled by its mean square so one penalty suits all;
    ``intercept=False`` leaves the first column (the intercept) free."""
    ms = np.mean(x * x, axis=0)
    pen = np.where(ms > 0, ms, 1.0)
    if not intercept:
        pen[0] = 0.0
    return np.diag(pen)



#: Resamples of the training participants for the ceiling's coefficient draws.
_COEF_DRAWS = 200


def draw_units(train: pd.DataFrame, by_participant: bool) -> np.ndarray:
    """The units :func:`_coefficient_draws` resamples: participants, or each participant's
    sessions where the held-out trials' participants are trained on (their own terms are then
    estimated from their own trials)."""
    who = train["participant"].to_numpy(str)
    return who + "|" + train["session"].astype(str).to_numpy() if by_participant else who


def _coefficient_draws(mx, tx, y, w, who, lams: tuple, seed: int = 0):
    """The mean and time corrections refitted, at their chosen penalties ``lams``, on
    the training units ``who`` (participants, or their sessions) resampled with replacement
    (a cluster bootstrap with Poisson weights; Cameron & Miller 2015, Hanley & MacGibbon 2006):
    arrays (:data:`_COEF_DRAWS`, terms) of ``b`` and ``b_t`` as :func:`fit_ceiling` fits
    them in its last round (``y`` that round's residual from the model extended).

    The misfit is a distance from the ceiling, so the ceiling's own estimation error belongs
    in its bound: resampling the held-out participants alone left it out, and a drift
    growing since each rest, 1.09x the tolerance within a person, read "excluded" with an
    upper bound of 0.221-0.238 slider units (issue 43, unseen seeds 1011 and 1013). The
    per-cell offsets and the noise model are not refitted (they are shrunk per cell; the
    smooth corrections carry the trends a bound must not miss)."""
    codes, inv = np.unique(np.asarray(who, str), return_inverse=True)
    k, kt = mx.shape[1], tx.shape[1]
    xx = np.zeros((codes.size, k, k))
    xy = np.zeros((codes.size, k))
    tt = np.zeros((codes.size, kt, kt))
    ty = np.zeros((codes.size, kt))
    tm = np.zeros((codes.size, kt, k))
    wsum = np.bincount(inv, weights=w, minlength=codes.size)
    for c in range(codes.size):
        m = inv == c
        wx, wt = w[m, None] * mx[m], w[m, None] * tx[m]
        xx[c], xy[c] = mx[m].T @ wx, wx.T @ y[m]
        tt[c], ty[c], tm[c] = tx[m].T @ wt, wt.T @ y[m], wt.T @ mx[m]
    pen, pen_t = _penalty(mx), _penalty(tx)
    # Poisson weights drawn from each unit's own name: a unit weighs the same in a draw of
    # every fold's ceiling, so the folds' draws are correlated as their training data overlap.
    counts = np.stack([np.random.default_rng([seed, zlib.crc32(c.encode())]).poisson(
        1.0, _COEF_DRAWS) for c in codes], axis=1).astype(float)
    b_draws, t_draws = np.empty((_COEF_DRAWS, k)), np.empty((_COEF_DRAWS, kt))
    for i, cnt in enumerate(counts):
        ws = max(float(cnt @ wsum), 1e-9)
        a = np.tensordot(cnt, xx, 1) + lams[0] * ws * pen + 1e-9 * np.eye(k)
        b = np.linalg.solve(a, cnt @ xy)
        a_t = np.tensordot(cnt, tt, 1) + lams[1] * ws * pen_t + 1e-9 * np.eye(kt)
        b_draws[i], t_draws[i] = b, np.linalg.solve(a_t, cnt @ ty - np.tensordot(cnt, tm, 1) @ b)
    return b_draws, t_draws


@dataclass(frozen=True, eq=False)
class CoefficientDraws:
    """One response's mean and time corrections as :func:`fit_ceiling` fitted them in its last
    round (design ``mx`` and ``tx``, that round's residual ``y`` from the model extended,
    weights ``w``, training units ``who``, chosen penalties ``lams``), to be drawn again.

    :meth:`at` ``(1.0)`` gives the ceiling's own ``coef_draws`` and ``time_draws``;
    ``at(factor)`` with a larger data set in view, the draws at :data:`LEAST_PENALTY` (see the
    module's docstring), whose spread on today's data is ``factor`` times that data set's."""

    mx: np.ndarray
    tx: np.ndarray
    y: np.ndarray
    w: np.ndarray
    who: np.ndarray
    lams: tuple
    _drawn: dict = field(default_factory=dict, repr=False)  # by penalties: draws made

    def at(self, factor: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """``(b_draws, t_draws)``: arrays (:data:`_COEF_DRAWS`, terms) of the mean and time
        corrections' coefficients, at the chosen penalties (``factor`` 1) or, for a data set
        ``factor`` (> 1) times as large, at :data:`LEAST_PENALTY`."""
        if factor < 1.0:
            raise ValueError(f"CoefficientDraws.at: factor {factor} < 1; give the larger data "
                             "set's size over today's")
        lams = self.lams if factor == 1.0 else (LEAST_PENALTY, LEAST_PENALTY)
        if lams not in self._drawn:
            self._drawn[lams] = _coefficient_draws(self.mx, self.tx, self.y, self.w, self.who,
                                                   lams)
        return self._drawn[lams]
