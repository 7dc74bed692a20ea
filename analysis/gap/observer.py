"""Observer layer: session-CSV responses vs the ``ideal`` simulated observer (truth + noise).

Both responses are modelled in raw slider units. The plain simulation predicts the true value
(``true_gloss_pct``/``true_depth_cm`` mapped through the design's slider) with Gaussian noise;
each catalogue candidate extends that model; the per-trial loss is the negative log-likelihood
of both responses (nats).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy import optimize, stats

from analysis.gap.engine import Candidate, GapError, split_held_out

__all__ = [
    "OBSERVER_CANDIDATES",
    "OBSERVER_MIN_GAIN",
    "load_sessions",
    "localise_observer",
    "observer_floor",
    "observer_frame",
    "observer_loss",
    "observer_nll",
    "observer_unit_ids",
    "split_observer",
]

SESSION_COLUMNS = ("participant", "session", "trial", "order", "stimulus_id", "illumination",
                   "gloss_level", "depth_level", "true_gloss_pct", "true_depth_cm",
                   "gloss_match", "depth_match")
RESP = ("gloss", "depth")
#: A candidate must remove >= 0.02 nats per held-out trial (the tolerance below which
#: analysis.gap.layers treats a gap as none): with thousands of trials a gain of a few
#: thousandths of a nat is significant, and one such was attributed on effect-free data.
OBSERVER_MIN_GAIN = 0.02
_LABEL_HALF_WIDTH = 0.025  # slider units: a response this close to a tick label counts as on it


def load_sessions(path: str | Path) -> pd.DataFrame:
    """Read every ``*.csv`` session file under ``path`` (a folder or one file; recursive)."""
    path = Path(path)
    files = [path] if path.is_file() else sorted(path.rglob("*.csv"))
    if not files:
        raise GapError(f"no session CSVs found at {path}; pass a folder holding <P>_s<N>.csv files")
    frames = []
    for f in files:
        df = pd.read_csv(f)
        missing = [c for c in SESSION_COLUMNS if c not in df.columns]
        if missing:
            raise GapError(f"{f}: columns {missing} missing; session CSVs need {SESSION_COLUMNS}")
        frames.append(df)
    return pd.concat(frames, ignore_index=True)


def observer_frame(frame: pd.DataFrame, design) -> pd.DataFrame:
    """Add truth in slider units (``gloss_u``, ``depth_u``) and the previous response."""
    s = design.slider
    out = frame.copy()
    out["gloss_u"] = out["true_gloss_pct"] / s.gloss_pct_per_unit + s.min
    out["depth_u"] = out["true_depth_cm"] / s.depth_cm_per_unit
    out["illumination"] = out["illumination"].astype(str)
    out = out.sort_values(["participant", "session", "order"]).reset_index(drop=True)
    for r in RESP:
        prev = out.groupby(["participant", "session"])[f"{r}_match"].shift(1)
        out[f"{r}_prev"] = prev.fillna(out[f"{r}_u"]).to_numpy()
    bad = ~np.isfinite(out[["gloss_match", "depth_match"]].to_numpy(float)).all(axis=1)
    if bad.any():
        raise GapError(f"{int(bad.sum())} rows have non-numeric matches; drop or fix them")
    out.attrs["mid"] = 0.5 * (s.min + s.max)
    out.attrs["range"] = (s.min, s.max)
    return out


# --- the extended model -------------------------------------------------------------------

def _means(data: pd.DataFrame, fitted: list) -> dict:
    mid = data.attrs["mid"]
    mu = {r: data[f"{r}_u"].to_numpy(float).copy() for r in RESP}
    truth = {r: data[f"{r}_u"].to_numpy(float) for r in RESP}
    for name, p in fitted:
        if name == "crosstalk":
            mu["gloss"] += p["c"] * (truth["depth"] - mid)
        elif name == "central_tendency":
            for r in RESP:
                mu[r] -= p[r] * (truth[r] - mid)
        elif name == "illumination_gain":
            g = data["illumination"].map(p["gain"]).fillna(0.0).to_numpy(float)
            mu["gloss"] += g * (truth["gloss"] - mid)
        elif name == "serial_dependence":
            for r in RESP:
                mu[r] += p[r] * (data[f"{r}_prev"].to_numpy(float) - truth[r])
    return mu


def _nll(data: pd.DataFrame, fitted: list, sigma: dict | None = None) -> np.ndarray:
    mu = _means(data, fitted)
    extra = dict(fitted)
    lam = extra.get("lapses", {}).get("rate", 0.0)
    w = extra.get("label_rounding", {}).get("weight", 0.0)
    lo, hi = data.attrs["range"]
    total = np.zeros(len(data))
    for r in RESP:
        x = data[f"{r}_match"].to_numpy(float)
        sd = (sigma or _sigma(data, fitted))[r]
        dens = stats.norm.pdf(x, mu[r], sd)
        # The slider stops at its ends: a response there is a censored draw, whose probability
        # is the Gaussian tail, spread over the label window so the measure matches rounding.
        at_lo, at_hi = x <= lo + 1e-9, x >= hi - 1e-9
        dens = np.where(at_lo, stats.norm.cdf(lo, mu[r], sd) / _LABEL_HALF_WIDTH, dens)
        dens = np.where(at_hi, stats.norm.sf(hi, mu[r], sd) / _LABEL_HALF_WIDTH, dens)
        if w > 0:
            k = np.clip(np.round(x), lo, hi)
            on_label = np.abs(x - k) <= _LABEL_HALF_WIDTH
            p_k = stats.norm.cdf(k + 0.5, mu[r], sd) - stats.norm.cdf(k - 0.5, mu[r], sd)
            dens = (1 - w) * dens + w * on_label * p_k / (2 * _LABEL_HALF_WIDTH)
        if lam > 0:
            dens = (1 - lam) * dens + lam / (hi - lo)
        total += -np.log(np.maximum(dens, 1e-300))
    return total


def observer_nll(data: pd.DataFrame, fitted: list, sigma: dict) -> np.ndarray:
    """Per-trial NLL (nats) of the simulation extended by ``fitted`` (a list of
    ``(candidate name, params)``) at fixed noise SDs ``sigma`` ({'gloss', 'depth'}, slider
    units), on a frame from :func:`observer_frame`."""
    return _nll(data, fitted, sigma)


def observer_unit_ids(data: pd.DataFrame) -> list[str]:
    """Trial names ``participant|session|order`` (the held-out units of the diagnosis)."""
    return [f"{p}|{s}|{o}" for p, s, o in
            zip(data["participant"], data["session"], data["order"])]


def _sigma(data: pd.DataFrame, fitted: list) -> dict:
    mu = _means(data, fitted)
    return {r: float(np.std(data[f"{r}_match"].to_numpy(float) - mu[r])) for r in RESP}


def _fit_sigma(train, fitted):
    """Maximum-likelihood noise SD per response given the other fitted parameters."""
    sig = _sigma(train, fitted)
    for r in RESP:
        def f(log_s, r=r):
            s = dict(sig)
            s[r] = float(np.exp(log_s))
            return _nll(train, fitted, s).sum()
        res = optimize.minimize_scalar(f, bounds=(np.log(0.02), np.log(5.0)), method="bounded",
                                       options={"xatol": 1e-3})
        sig[r] = float(np.exp(res.x))
    return sig


def observer_loss(train: pd.DataFrame):
    """Loss for the engine: noise SDs fitted on ``train``, per-trial NLL (nats) on the data."""
    cache = {}

    def loss(data: pd.DataFrame, fitted: list) -> np.ndarray:
        key = repr(fitted)
        if key not in cache:
            cache[key] = _fit_sigma(train, fitted)
        return _nll(data, fitted, cache[key])
    return loss


def split_observer(data: pd.DataFrame, rng: np.random.Generator):
    """Held-out split: by participant when there are >= 4, else half the trials at random."""
    parts = data["participant"].unique()
    mask = None
    if parts.size >= 4:
        test_p = rng.choice(parts, size=parts.size // 2, replace=False)
        mask = data["participant"].isin(test_p).to_numpy()
    return split_held_out(data, mask, rng)


def localise_observer(data: pd.DataFrame, design, rng: np.random.Generator,
                      n_boot: int = 1000) -> pd.DataFrame:
    """Mean residual (response - truth, slider units) per gloss x depth x illumination cell and
    response, with a 95 % bootstrap CI; cells use the design's analysis bins."""
    def bin_of(values, bins):
        out = np.full(len(values), "other", dtype=object)
        for name, members in bins.items():
            out[np.isin(np.round(values, 6), np.round(members, 6))] = name
        return out
    g = bin_of(data["true_gloss_pct"].to_numpy(float), design.analysis.gloss_bins_pct)
    d = bin_of(data["true_depth_cm"].to_numpy(float), design.analysis.depth_bins_cm)
    rows = []
    for r in RESP:
        res = data[f"{r}_match"].to_numpy(float) - data[f"{r}_u"].to_numpy(float)
        frame = pd.DataFrame({"gloss_bin": g, "depth_bin": d,
                              "illumination": data["illumination"].to_numpy(), "res": res})
        for key, grp in frame.groupby(["gloss_bin", "depth_bin", "illumination"]):
            v = grp["res"].to_numpy()
            b = v[rng.integers(0, v.size, (n_boot, v.size))].mean(axis=1)
            lo, hi = np.percentile(b, [2.5, 97.5])
            rows.append({"response": r, "gloss_bin": key[0], "depth_bin": key[1],
                         "illumination": key[2], "n": v.size, "mean_residual": v.mean(),
                         "ci_low": lo, "ci_high": hi})
    return pd.DataFrame(rows)


def observer_floor(data: pd.DataFrame, sim: pd.DataFrame) -> np.ndarray:
    """Per-trial NLL the ideal observer reaches on data it generated itself (``sim``): the
    mean over ``sim`` of its own plain model's NLL, noise SDs fitted on ``sim``."""
    c = float(_nll(sim, [], _fit_sigma(sim, [])).mean())
    return np.full(len(data), c)


def _resid(train, fitted):
    mu = _means(train, fitted)
    return {r: train[f"{r}_match"].to_numpy(float) - mu[r] for r in RESP}


def _ls(y, x):
    return float(np.dot(x, y) / max(np.dot(x, x), 1e-12))


def _fit_shift(name):
    def fit(train, chosen):
        res = _resid(train, chosen)
        mid = train.attrs["mid"]
        t = {r: train[f"{r}_u"].to_numpy(float) for r in RESP}
        if name == "crosstalk":
            return {"c": _ls(res["gloss"], t["depth"] - mid)}
        if name == "central_tendency":
            return {r: _ls(res[r], -(t[r] - mid)) for r in RESP}
        if name == "serial_dependence":
            return {r: _ls(res[r], train[f"{r}_prev"].to_numpy(float) - t[r]) for r in RESP}
        if name == "illumination_gain":
            gain = {}
            for ill, idx in train.groupby("illumination").indices.items():
                gain[ill] = _ls(res["gloss"][idx], t["gloss"][idx] - mid)
            return {"gain": gain}
        raise GapError(name)
    return fit


def _fit_mixture(name, key, grid):
    def fit(train, chosen):
        base = list(chosen)
        best = None
        for v in grid:
            fitted = base + [(name, {key: v})]
            sig = _fit_sigma(train, fitted)
            nll = _nll(train, fitted, sig).sum()
            if best is None or nll < best[0]:
                best = (nll, v)
        return {key: float(best[1])}
    return fit


OBSERVER_CANDIDATES = [
    Candidate("crosstalk", _fit_shift("crosstalk"), "deeper arrays look glossier"),
    Candidate("central_tendency", _fit_shift("central_tendency"),
              "responses compressed toward the slider middle"),
    Candidate("illumination_gain", _fit_shift("illumination_gain"),
              "gloss gain differs by illumination"),
    Candidate("label_rounding", _fit_mixture("label_rounding", "weight",
                                             np.linspace(0.0, 0.6, 13)),
              "responses snap to tick labels"),
    Candidate("lapses", _fit_mixture("lapses", "rate", np.linspace(0.0, 0.3, 16)),
              "random responses anywhere on the slider"),
    Candidate("serial_dependence", _fit_shift("serial_dependence"),
              "pull toward the previous trial's response"),
]
