"""The simulation's prediction and likelihood (observer layer).

Both responses are modelled in raw slider units (the design's slider spec maps physical units
to slider positions, :func:`to_slider_units`). The *base* model (:class:`ObserverBase`) is the
simulation: the observer a lab fitted to its own pilot (``python -m experiment fit-observer``,
the ``humanlike`` model's population means), an observers TOML table, or the observer that
generated simulated session CSVs; :func:`adapt_base` gives each participant their own base
within the simulation's between-observer spread. :func:`predict` extends the base by the chosen
catalogue candidates; the per-trial loss (:func:`observer_nll`, :func:`observer_loss`) is the
negative log-likelihood of both responses (nats), Gaussian noise censored at the slider ends,
with a lapse and a label-rounding mixture. The noise SDs are fitted on the training data for
every model (:func:`_fit_sigma`), so a uniformly noisier lab is no gap.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import optimize
from scipy.special import ndtr

from analysis.gap.engine import GapError, candidate

__all__ = [
    "OBSERVER_MIN_GAIN",
    "RESP",
    "ObserverBase",
    "adapt_base",
    "adapt_own_offsets",
    "adapt_population",
    "base_from_params",
    "observer_loss",
    "observer_nll",
    "predict",
    "to_slider_units",
]


RESP = ("gloss", "depth")
#: A candidate, a step or a remaining gap must be >= 0.02 nats per held-out trial (the
#: tolerance below which analysis.gap.layers treats a gap as none): with thousands of trials a
#: gain of a few thousandths of a nat is significant, and one such was attributed on
#: effect-free data.
OBSERVER_MIN_GAIN = 0.02
_LABEL_HALF_WIDTH = 0.025  # slider units: a response this close to a tick label counts as on it

#: The forms of label rounding tried (by the catalogue's label_rounding and by the ceiling):
#: shares of the way to a label a rounding may pull responses (1: snapped onto it), and the
#: weights tried with a pull: an outside check's observers pulled toward the labels (none on
#: a label) beside serial dependence, and were found as serial dependence alone (label
#: rounding's held-out gain 0.015 nats per trial with snapping as its only form; issue 29).
#: At most 0.9: a weight of 1 gives no density outside the pulled windows, and a held-out
#: trial there cost 690 nats (observers pulled halfway to the labels, then a quarter of the
#: way toward their previous setting, seed 3 of the pair's dev seeds: one fold fitted
#: weight 1 and lost 4.8 nats per held-out trial instead of gaining 0.9; issue 38).
_LABEL_PULLS = (0.6, 0.45, 0.3)
_PULL_WEIGHTS = (0.25, 0.5, 0.75, 0.9)
#: Shares of the pull toward the previous response that a rounding of the aimed setting is
#: undone by (stage "aim"). Its own, not serial dependence's fitted share: held out by
#: participant, that fit also takes up each participant's own offset (the previous response
#: carries it) and came out at 0.33 for a true pull of 0.25 (blind generator, dev seed 2),
#: which left the clusters at the labels smeared and label rounding unnamed; the clusters
#: themselves are sharp only at the true share.
_AIM_SHARES = (0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4)


def to_slider_units(slider, gloss_pct, depth_cm) -> tuple[np.ndarray, np.ndarray]:
    """Physical gloss (%) and depth (cm) -> slider positions, the inverse of the design's
    ``slider.to_gloss_pct`` / ``slider.to_depth_cm`` (linear maps, read off at the slider's
    ``min`` and one unit above it); not clipped."""
    lo = float(slider.min)
    g0, g1 = (float(slider.to_gloss_pct(v)) for v in (lo, lo + 1.0))
    d0, d1 = (float(slider.to_depth_cm(v)) for v in (lo, lo + 1.0))
    return (lo + (np.asarray(gloss_pct, float) - g0) / (g1 - g0),
            lo + (np.asarray(depth_cm, float) - d0) / (d1 - d0))


# --- the simulation (base model) ----------------------------------------------------------

@dataclass(frozen=True)
class ObserverBase:
    """The simulated observer's mean response in slider units, ``mid`` the slider's middle::

        depth = mid + a_d + b_d (depth_true - mid)
        gloss = mid + a_g + b_g (gloss_true - mid) + c (depth_true - mid)
                + k (gloss_true - mid)(depth_true - mid)

    (the experiment's humanlike form; the ideal observer is a = c = k = 0, b = 1).

    Attributes
    ----------
    kind : str
        'ideal', 'humanlike' or 'fitted' (a table written by ``experiment fit-observer``).
    source : str
        Where it came from (a path or 'sessions').
    coef : dict
        ``{"gloss": (a_g, b_g, c, k), "depth": (a_d, b_d)}``, slider units.
    participants : tuple of str
        Participant ids of the simulated sessions (or of the fit), if known.
    stimuli : tuple
        Sorted (true_gloss_pct, true_depth_cm) levels of the simulated sessions, if known.
    n_illuminations : int or None
    sd : dict or None
        Between-observer SDs of ``coef`` (same layout, slider units), from a table's
        ``{mean, sd}`` entries: how far one observer may depart from the population.
    se : dict or None
        Standard errors of the population means ``coef`` (same layout, slider units), from a
        fitted table's ``[fit.standard_errors]``: how far the population itself is known.
    """

    kind: str
    source: str
    coef: dict
    participants: tuple = ()
    stimuli: tuple = ()
    n_illuminations: int | None = None
    sd: dict | None = None
    se: dict | None = None

    def mean(self, gloss_u, depth_u, mid: float) -> dict:
        g, d = np.asarray(gloss_u, float) - mid, np.asarray(depth_u, float) - mid
        ag, bg, c, k = self.coef["gloss"]
        ad, bd = self.coef["depth"]
        return {"gloss": mid + ag + bg * g + c * d + k * g * d, "depth": mid + ad + bd * d}


def _table_means(table: Mapping) -> dict:
    """A parameter table's population values: numbers as given, ``{mean, sd}`` -> mean."""
    out = {}
    for name, spec in table.items():
        if isinstance(spec, Mapping) and "mean" in spec:
            out[name] = float(spec["mean"])
        elif isinstance(spec, (int, float)):
            out[name] = float(spec)
    return out


def base_from_params(table: Mapping, kind: str, slider, *, source: str = "",
                     fit_info: Mapping | None = None) -> ObserverBase:
    """The base model of an observers-TOML table (``ideal`` or ``humanlike``, physical units),
    at its population means, converted to slider units with the design's slider.

    Raises
    ------
    GapError
        Unknown kind, or a humanlike table missing a parameter.
    """
    p = _table_means(table)
    sd = se = None
    if kind == "ideal":
        coef = {"gloss": (0.0, 1.0, 0.0, 0.0), "depth": (0.0, 1.0)}
    elif kind in ("humanlike", "fitted"):
        need = ("depth_slope", "depth_intercept_cm", "gloss_slope", "gloss_intercept_pct",
                "crosstalk_pct_per_cm", "interaction_per_cm")
        missing = [n for n in need if n not in p]
        if missing:
            raise GapError(f"observer table {source or ''} lacks {missing}; write it with "
                           "python -m experiment fit-observer")
        coef = _humanlike_coef(p, slider)
        sd = _coef_spread(coef, p, need, {n: table.get(n) for n in need}, "sd", slider)
        errors = ((fit_info or {}).get("standard_errors") or {}).get("humanlike") or {}
        if kind == "fitted" and errors:
            se = _coef_spread(coef, p, need, {n: errors.get(n) for n in need}, "mean", slider)
    else:
        raise GapError(f"unknown observer kind {kind!r}; use ideal or humanlike")
    info = dict(fit_info or {})
    parts = tuple(str(v) for v in info.get("participants", ()))
    return ObserverBase(kind=kind, source=source, coef=coef, participants=parts, sd=sd, se=se)


def _coef_spread(coef: dict, p: Mapping, names, specs: Mapping, key: str, slider) -> dict:
    """SDs of the slider-unit coefficients given SDs ``specs[name][key]`` of the physical
    parameters (independent; each moved by its SD and the squared changes summed)."""
    var = {r: np.zeros(len(v)) for r, v in coef.items()}
    for name in names:
        spec = specs.get(name)
        if isinstance(spec, Mapping) and float(spec.get(key, 0.0)) > 0:
            moved = _humanlike_coef({**p, name: p[name] + float(spec[key])}, slider)
            for r in var:
                var[r] += (np.asarray(moved[r]) - np.asarray(coef[r])) ** 2
    return {r: tuple(float(v) for v in np.sqrt(var[r])) for r in var}


def _humanlike_coef(p: Mapping, slider) -> dict:
    """Slider-unit coefficients of the humanlike model at parameters ``p`` (physical units):
    the physical model evaluated on a grid and read off (exact: both the model and the
    slider map are linear in each variable)."""
    mid = 0.5 * (slider.min + slider.max)
    m_g, m_d = float(slider.to_gloss_pct(mid)), float(slider.to_depth_cm(mid))
    gu = np.array([mid - 1, mid + 1, mid - 1, mid + 1, mid])
    du = np.array([mid - 1, mid - 1, mid + 1, mid + 1, mid])
    g_pct = np.array([float(slider.to_gloss_pct(v)) for v in gu])
    d_cm = np.array([float(slider.to_depth_cm(v)) for v in du])
    dh = m_d + p["depth_slope"] * (d_cm - m_d) + p["depth_intercept_cm"]
    gh = (m_g + p["gloss_slope"] * (g_pct - m_g) + p["crosstalk_pct_per_cm"] * (d_cm - m_d)
          + p["interaction_per_cm"] * (g_pct - m_g) * (d_cm - m_d) + p["gloss_intercept_pct"])
    ghu, dhu = to_slider_units(slider, gh, dh)
    x = np.c_[np.ones(5), gu - mid, du - mid, (gu - mid) * (du - mid)]
    cg = np.linalg.lstsq(x, ghu - mid, rcond=None)[0]
    cd = np.linalg.lstsq(x[:, [0, 2]], dhu - mid, rcond=None)[0]
    return {"gloss": tuple(float(v) for v in cg), "depth": tuple(float(v) for v in cd)}


def _base_x(data: pd.DataFrame, r: str) -> np.ndarray:
    """The base model's regressors of response ``r`` (centred at the slider's middle)."""
    mid = data.attrs["mid"]
    g = data["gloss_u"].to_numpy(float) - mid
    d = data["depth_u"].to_numpy(float) - mid
    return np.c_[np.ones(len(g)), g, d, g * d] if r == "gloss" else np.c_[np.ones(len(g)), d]


def adapt_base(train: pd.DataFrame, test: pd.DataFrame, base: ObserverBase) -> None:
    """Each participant's own base, in place: where a participant is in both parts (folds by
    trial), their coefficients are the posterior mean given their training trials, with the
    simulation's population values as the prior mean and its between-observer SDs as the
    prior SDs (a random-effects model's best linear unbiased predictor): the simulated
    observer allows each observer that much individual departure, so it is no gap. Without
    SDs (the ideal observer, simulated sessions) nothing changes."""
    if not base.sd or not any(any(v > 0 for v in sd) for sd in base.sd.values()):
        return
    lo, hi = train.attrs["range"]
    shared = set(train["participant"]) & set(test["participant"])
    for r in RESP:
        prior_var = np.maximum(np.asarray(base.sd[r], float) ** 2, 1e-10)
        x_tr, x_te = _base_x(train, r), _base_x(test, r)
        y = train[f"{r}_match"].to_numpy(float)
        res = y - train[f"{r}_base"].to_numpy(float)
        inside = (y > lo + 1e-9) & (y < hi - 1e-9)
        noise = float(np.var(res[inside]))
        add_tr, add_te = np.zeros(len(train)), np.zeros(len(test))
        for pid in shared:
            m_tr = (train["participant"] == pid).to_numpy() & inside
            xx = x_tr[m_tr]
            prec = xx.T @ xx / noise + np.diag(1 / prior_var)
            delta = np.linalg.solve(prec, xx.T @ res[m_tr] / noise)
            add_tr[(train["participant"] == pid).to_numpy()] = (
                x_tr[(train["participant"] == pid).to_numpy()] @ delta)
            m_te = (test["participant"] == pid).to_numpy()
            add_te[m_te] = x_te[m_te] @ delta
        train[f"{r}_base"] = train[f"{r}_base"].to_numpy(float) + add_tr
        test[f"{r}_base"] = test[f"{r}_base"].to_numpy(float) + add_te


def _add_base(frame: pd.DataFrame, r: str, add: np.ndarray) -> None:
    frame[f"{r}_base"] = frame[f"{r}_base"].to_numpy(float) + add


def adapt_own_offsets(frame: pd.DataFrame, base: ObserverBase) -> None:
    """Each participant's own offset, in place, where participants are held out whole: the
    posterior mean of their offset (intercept) given their *other* session's responses
    (their other half of the trials with one session), the simulation's population value
    the prior mean and its between-observer SD the prior SD, added to ``*_base``.

    The simulated population gives every observer an offset of their own (SD ``base.sd``);
    a held-out observer's previous response carries it, so without it a pull toward the
    previous response passed for serial dependence on observers with none (the blind
    generator's effect-free case, dev seeds 0 and 12: serial dependence 0.09 of the way,
    0.04-0.08 nats per trial). Taken from the other session, the offset never uses the
    response it predicts. Nothing changes without SDs."""
    if not base.sd or not len(frame):
        return
    lo, hi = frame.attrs["range"]
    who = frame["participant"].to_numpy(str)
    sessions = frame["session"].to_numpy()
    rank = frame.groupby("participant")["order"].rank(method="first").to_numpy(float)
    for r in RESP:
        prior = float(base.sd[r][0]) ** 2
        if prior <= 0:
            continue
        y = frame[f"{r}_match"].to_numpy(float)
        res = y - frame[f"{r}_base"].to_numpy(float)
        inside = (y > lo + 1e-9) & (y < hi - 1e-9)
        add = np.zeros(len(frame))
        for pid in np.unique(who):
            mine = who == pid
            parts = np.unique(sessions[mine])
            part = (sessions if parts.size >= 2
                    else (rank > 0.5 * mine.sum()).astype(int))
            for q in np.unique(part[mine]):
                other = mine & (part != q) & inside
                if other.sum() < 2:
                    continue
                noise = float(np.var(res[other], ddof=1))
                add[mine & (part == q)] = (res[other].mean() * prior
                                           / (prior + noise / other.sum()))
        _add_base(frame, r, add)


def adapt_population(train: pd.DataFrame, test: pd.DataFrame, base: ObserverBase) -> None:
    """The population's coefficients within what the pilot knows of them, in place: where
    the simulation is a fitted table with standard errors of its population means
    (``base.se``), the posterior mean of the real population's departure from them given the
    training participants, added to ``*_base`` of both parts.

    Prior: the departure is N(0, se^2) (the pilot's own sampling error: 8 pilot observers
    give their population's mean slope only to about 0.04). Data: the mean over the training
    participants of their own least-squares departures, whose error is the between-observer
    spread over their number, (sd^2 + their own error^2) / n. Each coefficient is shrunk on
    its own, se^2 / (se^2 + that). Without it, a real sample whose mean slope lay where the
    pilot's sampling error and its own put it (depth slope 0.77 against the pilot's 0.95, dev
    seed 2, both drawn from one population) was named central tendency, the gain of the
    shift the same on every held-out participant. Nothing changes without standard errors
    or where participants are shared by the parts (:func:`adapt_base` then)."""
    if not base.se or not base.sd:
        return
    if set(train["participant"]) & set(test["participant"]):
        return
    lo, hi = train.attrs["range"]
    who = train["participant"].to_numpy(str)
    for r in RESP:
        se2 = np.asarray(base.se[r], float) ** 2
        sd2 = np.asarray(base.sd[r], float) ** 2
        x = _base_x(train, r)
        k = x.shape[1]
        y = train[f"{r}_match"].to_numpy(float)
        res = y - train[f"{r}_base"].to_numpy(float)
        prev = train[f"{r}_prev"].to_numpy(float)
        # The previous response a nuisance regressor: settings pulled a share s toward it
        # have the curve's departure d times (1 - s) as their own, so the departure is the
        # regression's over (1 - s); without it a real serial pull (settings' slopes 0.7 of
        # the curve's) was taken up as a population departure, and serial dependence, fitted
        # on top, lost on the held-out participants pulled least (blind serial case, seed 0).
        x_prev = np.where(np.isnan(prev), 0.0, prev - train[f"{r}_base"].to_numpy(float))
        inside = (y > lo + 1e-9) & (y < hi - 1e-9)
        deltas, errs = [], []
        for pid in np.unique(who):
            m = (who == pid) & inside
            if m.sum() <= k + 2:
                continue
            xx = np.c_[x[m], x_prev[m]]
            d, *_ = np.linalg.lstsq(xx, res[m], rcond=None)
            noise = float(np.sum((res[m] - xx @ d) ** 2)) / (m.sum() - k - 1)
            keep = 1.0 - float(np.clip(d[k], -0.5, 0.9))
            deltas.append(d[:k] / keep)
            errs.append(np.diag(np.linalg.pinv(xx.T @ xx))[:k] * noise / keep ** 2)
        if not deltas:
            continue
        n = len(deltas)
        var = (sd2 + np.mean(errs, axis=0)) / n
        shift = np.mean(deltas, axis=0) * se2 / np.maximum(se2 + var, 1e-12)
        _add_base(train, r, x @ shift)
        _add_base(test, r, _base_x(test, r) @ shift)


# --- the extended model -------------------------------------------------------------------

def predict(data: pd.DataFrame, fitted: list) -> dict:
    """The base model extended by ``fitted`` (``[(candidate name, params), ...]``, applied in
    order): ``{"mu": {response: mean}, "sd": {response: 1}, "lapse": rate, "label": weight}``
    (and ``"label_pull"``, the share of the way to a label, where a candidate pulls rather
    than snaps)
    (``sd`` a multiplier of the fitted noise SD)."""
    pred = {"mu": {r: data[f"{r}_base"].to_numpy(float).copy() for r in RESP},
            "sd": {r: 1.0 for r in RESP}, "lapse": 0.0, "label": 0.0}
    for name, p in fitted:
        pred = candidate("observer", name).apply(data, pred, p)
    return pred


def _nll_parts(data: pd.DataFrame, pred: dict, sigma: dict) -> dict:
    """Per-trial NLL (nats) of each response."""
    lam, w = pred["lapse"], pred["label"]
    lo, hi = data.attrs["range"]
    out = {}
    for r in RESP:
        x = data[f"{r}_match"].to_numpy(float)
        mu = pred["mu"][r]
        sd = np.maximum(np.asarray(sigma[r], float) * pred["sd"][r], 1e-6)
        z = (x - mu) / sd
        dens = np.exp(-0.5 * z * z) / (sd * np.sqrt(2 * np.pi))
        # The slider stops at its ends: a response there is a censored draw, whose probability
        # is the Gaussian tail, spread over the label window so the measure matches rounding.
        at_lo, at_hi = x <= lo + 1e-9, x >= hi - 1e-9
        dens = np.where(at_lo, ndtr((lo - mu) / sd) / _LABEL_HALF_WIDTH, dens)
        dens = np.where(at_hi, ndtr((mu - hi) / sd) / _LABEL_HALF_WIDTH, dens)
        if w > 0:
            dens = (1 - w) * dens + w * _label_density(x, mu, sd, dens, pred, lo, hi,
                                                       _aim_frame(pred, r, x.size))
        if lam > 0:
            dens = (1 - lam) * dens + lam / (hi - lo)
        out[r] = -np.log(np.maximum(dens, 1e-300))
    return out


def _aim_frame(pred: dict, r: str, n: int) -> tuple:
    """``(shift, scale)`` per trial of response ``r``: where the label rounding acts on the
    setting aimed at *before* the serial pull (``label_stage`` "aim", beside serial
    dependence), the setting is ``x = (1 - s) a + s prev`` (a share ``s`` of the way from the
    aimed setting ``a`` toward the previous response), so ``a = (x - shift) / scale`` with
    ``shift = s prev`` and ``scale = 1 - s`` (1 and 0 where no previous response is known;
    ``s`` the rounding's own ``label_share`` where it has one, else serial dependence's);
    otherwise ``(0, 1)``: the rounding acts on the setting itself."""
    serial = pred.get("serial")
    if pred.get("label_stage") != "aim" or not serial or r not in serial:
        return 0.0, 1.0
    s, prev = serial[r]
    s = pred.get("label_share", s)
    known = np.isfinite(prev)
    s = np.where(known, np.clip(float(s), -0.9, 0.9), 0.0)
    return np.where(known, s * np.nan_to_num(prev), 0.0), 1.0 - s


def _label_density(x, mu, sd, dens, pred, lo, hi, frame=(0.0, 1.0)) -> np.ndarray:
    """Density of a response rounded toward the tick labels (integers): snapped onto the
    label the latent response rounds to (``label_pull`` 1, the default: the label's
    probability over the label window), or pulled a share ``s`` of the way to it (the latent
    ``k + (x - k) / (1 - s)``, a response within ``(1 - s) / 2`` of a label; responses at the
    slider's ends keep their censored density). ``frame`` (:func:`_aim_frame`): the rounding
    acts on the aimed setting ``a = (x - shift) / scale`` (mean and SD mapped alike), the
    density divided by ``scale`` (the Jacobian back to ``x``)."""
    shift, scale = frame
    a, mu_a, sd_a = (x - shift) / scale, (mu - shift) / scale, sd / scale
    k = np.round(a) if np.ndim(scale) else np.clip(np.round(a), lo, hi)
    s = float(pred.get("label_pull", 1.0))
    if s >= 1.0:
        on_label = np.abs(a - k) <= _LABEL_HALF_WIDTH
        p_k = ndtr((k + 0.5 - mu_a) / sd_a) - ndtr((k - 0.5 - mu_a) / sd_a)
        snapped = on_label * p_k / (2 * _LABEL_HALF_WIDTH) / scale
        return (snapped if not np.ndim(scale)
                else np.where((x <= lo + 1e-9) | (x >= hi - 1e-9), dens, snapped))
    z = (k + (a - k) / (1 - s) - mu_a) / sd_a
    near = np.abs(a - k) <= 0.5 * (1 - s) + 1e-12
    pulled = near * np.exp(-0.5 * z * z) / (sd_a * np.sqrt(2 * np.pi) * (1 - s)) / scale
    return np.where((x <= lo + 1e-9) | (x >= hi - 1e-9), dens, pulled)


def _nll(data, pred, sigma) -> np.ndarray:
    parts = _nll_parts(data, pred, sigma)
    return parts["gloss"] + parts["depth"]


def observer_nll(data: pd.DataFrame, fitted: list, sigma: dict) -> np.ndarray:
    """Per-trial NLL (nats) of the base extended by ``fitted`` at noise SDs ``sigma``
    ({'gloss', 'depth'}, slider units), on a frame from :func:`observer_frame`."""
    return _nll(data, predict(data, fitted), sigma)


def _fit_sigma(train: pd.DataFrame, pred: dict) -> dict:
    """Maximum-likelihood noise SD per response given the prediction (closed form for a plain
    Gaussian; a bounded search when lapses, label rounding or censored responses count)."""
    lo, hi = train.attrs["range"]
    sig, mads, refine = {}, {}, pred["lapse"] > 0 or pred["label"] > 0
    for r in RESP:
        x = train[f"{r}_match"].to_numpy(float)
        res = (x - pred["mu"][r]) / pred["sd"][r]
        inside = (x > lo + 1e-9) & (x < hi - 1e-9)
        if not inside.any():
            raise GapError(f"every {r} response lies at a slider end; nothing to fit")
        sig[r] = max(float(np.sqrt(np.mean(res[inside] ** 2))), 1e-3)
        mads[r] = max(1.4826 * float(np.median(np.abs(res[inside] - np.median(res[inside])))),
                      1e-2)
        refine = refine or inside.mean() < 0.98
    if refine:
        for r in RESP:
            def f(log_s, r=r):
                return _nll_parts(train, pred, {**sig, r: float(np.exp(log_s))})[r].sum()
            opt = optimize.minimize_scalar(
                f, bounds=(np.log(mads[r] / 3), np.log(3 * max(mads[r], sig[r]))),
                method="bounded", options={"xatol": 2e-3})
            sig[r] = float(np.exp(opt.x))
    return sig


def observer_loss(train: pd.DataFrame):
    """Loss for the engine: noise SDs fitted on ``train`` for each model, per-trial NLL
    (nats) on the data."""
    cache = {}

    def loss(data: pd.DataFrame, fitted: list) -> np.ndarray:
        key = repr(fitted)
        if key not in cache:
            cache[key] = _fit_sigma(train, predict(train, fitted))
        return observer_nll(data, fitted, cache[key])
    return loss


# --- the lapse mixture's E-step (shared by the ceiling and the candidates) ----------------

def _phi(z):
    return np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi)


def _gauss_share(res: np.ndarray, sd: np.ndarray, lapse: float, width: float) -> np.ndarray:
    """Posterior probability that a response is no lapse (the E-step of the lapse mixture)."""
    if lapse <= 0:
        return np.ones(res.size)
    g = (1 - lapse) * _phi(res / sd) / sd
    return g / (g + lapse / width)
