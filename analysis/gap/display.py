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
nonuniformity         gain *= 1 + f (x^2 + y^2) / 2 + g x + h y
warmup_drift          gain *= 1 - w exp(-t / tau), t = s since the first reading, tau at most
                      3 records long (a slower drift is nearly a constant gain)
quantisation          drive rounded to a ``bits``-bit DAC grid before the gamma model
====================  ====================================================================

Loss per reading: Gaussian negative log-likelihood (nats) with the photometer's noise
``sd^2 = a^2 + (b L)^2``. The noise is measured from pairs of consecutive repeats of the same
patch (and the check's warm-up series), with slow changes of the display between the two
readings of a pair modelled as a smooth function of time (:func:`fit_noise_drift`), so a
warm-up between repeats is not counted as noise. The floor (the loss of a model right up to
noise) is ``0.5 log(2 pi sd^2) + 0.5`` per reading. The ceiling (:func:`display_ceiling`) is a
penalised smooth of level, position and time fitted to the residuals; a chosen model that
stays significantly above it leaves a gap the catalogue does not explain.

Held out: each patch's repeats alternate between two halves, and the halves are cross-fitted
(:func:`display_folds`: each fitted on the other and held out once), so every reading is held
out and a small effect seen in few readings (a black offset in the darkest patches) is tested
on all of them.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import optimize
from scipy.interpolate import BSpline

from analysis.gap.engine import (
    Candidate,
    GapError,
    candidate,
    catalogue,
    register,
    split_held_out,
)
from calibration import READINGS_COLUMNS, CalibrationError, load_calibration, load_readings

__all__ = [
    "DISPLAY_CANDIDATES",
    "DISPLAY_MIN_SHARE",
    "display_ceiling",
    "display_floor",
    "display_folds",
    "display_frame",
    "display_loss",
    "display_loss_info",
    "display_nll",
    "display_unit_ids",
    "display_where",
    "fit_noise_drift",
    "load_display",
    "localise_display",
    "split_display",
]

#: An attribution must remove >= 80 % of the held-out gap: the calibration was itself estimated
#: from noisy readings, so a small gap remains that no display effect explains.
DISPLAY_MIN_SHARE = 0.8
_TAUS_S = np.geomspace(20.0, 5000.0, 40)
_BITS = (4, 5, 6, 7, 8, 9, 10)
#: Longest warm-up time constant fitted, in records: a slower drift is a constant gain.
_TAU_RECORDS = 3.0
#: Interior knots of the time spline the noise fit may use for drift (None: no drift).
_DRIFT_KNOTS = (None, 0, 1, 2, 4, 8)
#: Smoothing parameters the ceiling's cross-validation chooses from (relative to the data).
_CEIL_LAMBDAS = 10.0 ** np.arange(-3, 6)
_MIN_READINGS = 8
#: Validation readings (one per fraction, no repeats) needed to stand in for in-sample ones:
#: with the procedure's default 9, chance gains on 4 held-out readings were attributed (1 of
#: 20 effect-free calibrations); with 17, none of 20.
_MIN_VALIDATION = 16


# --- reading the files ----------------------------------------------------------------------

def _find(path: Path, name: str) -> Path:
    if path.is_dir():
        hits = sorted(path.rglob(name))
        if not hits:
            raise GapError(f"no {name} under {path}; pass the file or the folder holding it")
        return hits[0]
    if not path.is_file():
        raise GapError(f"{path} not found; pass a {name} file or the folder holding it")
    return path


def _read_any(path: Path) -> pd.DataFrame:
    """Readings from ``readings.csv`` / ``warmup.csv`` (READINGS_COLUMNS exactly) or from
    ``validation.csv`` (READINGS_COLUMNS plus target_fraction)."""
    try:
        return load_readings(path)
    except CalibrationError:
        pass
    try:
        frame = pd.read_csv(path, dtype={"raw_reply": str, "calibration_id": str},
                            keep_default_na=False, on_bad_lines="skip")
    except (OSError, ValueError) as exc:
        raise GapError(f"{path} is not a readings CSV ({exc})") from exc
    missing = [c for c in READINGS_COLUMNS if c not in frame.columns]
    if missing:
        raise GapError(f"{path} lacks column(s) {missing}; pass readings.csv, warmup.csv or "
                       "validation.csv written by the calibration package")
    frame = frame[list(READINGS_COLUMNS)].copy()
    for c in ("x_norm", "y_norm", "level", "luminance_cd_m2", "repeat"):
        frame[c] = pd.to_numeric(frame[c], errors="coerce")
    frame = frame.dropna(subset=["x_norm", "y_norm", "level", "repeat", "luminance_cd_m2"])
    frame["repeat"] = frame["repeat"].astype(int)
    return frame.reset_index(drop=True)


def load_display(real_path, sim_path):
    """Read the readings to diagnose (REAL) and the calibration (SIM), out of sample.

    Parameters
    ----------
    real_path : path
        A check run's folder (``check.json``, ``readings.csv``, optional ``warmup.csv``), a
        ``readings.csv`` or ``validation.csv``, or a folder holding one.
    sim_path : path
        ``calibration.json`` or the calibration's folder.

    Returns
    -------
    (readings, calibration)
        ``readings.attrs["display_source"]`` says what was diagnosed (``real``, ``kind``:
        check / readings / validation, ``in_sample_rows``, ``notes``) and
        ``readings.attrs["noise_frames"]`` holds the readings the noise floor comes from.

    Raises
    ------
    GapError
        If a file is missing or malformed; if the readings are the calibration's own and no
        held-out readings exist (the message names the check run to measure); if fewer than 8
        readings are left.
    """
    real = Path(real_path)
    cpath = _find(Path(sim_path), "calibration.json")
    try:
        cal = load_calibration(cpath)
    except CalibrationError as exc:
        raise GapError(str(exc)) from exc
    notes: list[str] = []
    check = None
    if real.is_dir() and (real / "check.json").is_file():
        check = _read_check(real / "check.json")
        rpath = real / "readings.csv"
        if not rpath.is_file():
            raise GapError(f"check run {real} has no readings.csv; rerun the check to resume")
        kind = "check"
        if check["checked_calibration_id"] != cal.calibration_id:
            notes.append(f"the check run {check['check_id']!r} checked calibration "
                         f"{check['checked_calibration_id']!r}, but --sim is calibration "
                         f"{cal.calibration_id!r}; its readings are compared with --sim")
    else:
        rpath = real if real.is_file() else _find(real, "readings.csv")
        kind = "validation" if "target_fraction" in _header(rpath) else "readings"
    readings = _read_any(rpath)
    noise_frames = [readings]
    warm = rpath.parent / "warmup.csv"
    if check is not None and warm.is_file():
        noise_frames.append(_read_any(warm))
    own = cpath.parent / (cal.readings_file or "readings.csv")
    fitted_rows = _read_any(own) if own.is_file() else None
    same_id = readings["calibration_id"].astype(str) == cal.calibration_id
    if fitted_rows is not None:
        keys = set(_row_keys_list(fitted_rows))
        in_fit = np.array([k in keys for k in _row_keys_list(readings)]) & same_id.to_numpy()
    else:
        in_fit = np.zeros(len(readings), bool)
        if kind == "readings" and same_id.any():
            notes.append(f"{int(same_id.sum())} readings carry the calibration's id "
                         f"{cal.calibration_id!r} but its readings file ({own}) is missing, so "
                         "whether they are the ones it was fitted from cannot be checked; if "
                         "they are, the diagnosis is in-sample and cannot show the gap")
    n_in = int(in_fit.sum())
    source = {"real": str(rpath), "calibration": str(cpath), "kind": kind,
              "in_sample_rows": n_in, "n_rows": len(readings)}
    if n_in:
        rest = readings[~in_fit].reset_index(drop=True)
        msg = (f"{n_in} of {len(readings)} readings in {rpath} are the ones calibration "
               f"{cal.calibration_id!r} was fitted from (same calibration_id, same rows): an "
               "in-sample fit absorbs an offset or a gain change, so they cannot show its gap")
        val = cpath.parent / "validation.csv"
        if len(rest) >= _MIN_READINGS:
            notes.append(msg + f"; diagnosing only the other {len(rest)} readings")
            readings = rest
        elif val.is_file() and len(_read_any(val)) >= _MIN_VALIDATION:
            readings = _read_any(val)
            source |= {"real": str(val), "kind": "validation"}
            notes.append(msg + f"; diagnosing the calibration's {len(readings)} held-out "
                         f"validation readings ({val}) instead. For a later state of the "
                         "display, measure a check run: python -m calibration check "
                         f"--calibration {cpath.parent} --out CHECK_DIR, then pass --real "
                         "CHECK_DIR")
        else:
            raise GapError(msg + ", and there are not enough held-out readings "
                           f"(validation.csv with >= {_MIN_VALIDATION} rows) beside {cpath}. "
                           "Measure a check run: "
                           f"python -m calibration check --calibration {cpath.parent} --out "
                           "CHECK_DIR, then pass --real CHECK_DIR")
        # The calibration's own readings still measure the photometer's noise: a pair of
        # repeats does not depend on the fit.
        noise_frames = [readings] + ([fitted_rows] if fitted_rows is not None else [])
    if len(readings) < _MIN_READINGS:
        raise GapError(f"{rpath}: {len(readings)} readings; the display diagnosis needs "
                       f">= {_MIN_READINGS}")
    # The photometer's noise does not depend on the calibration's fit: the calibration's own
    # repeats, taken with the same instrument, measure it too (drift modelled per file).
    devices = set(readings["device"].astype(str))
    if fitted_rows is not None and not any(f is fitted_rows for f in noise_frames):
        same = fitted_rows[fitted_rows["device"].astype(str).isin(devices)]
        if len(same):
            noise_frames.append(same)
    if not _has_pairs(readings) and len(noise_frames) > 1:
        notes.append("the readings have no repeats: the photometer's noise is measured from "
                     "the repeated readings of the same photometer beside them")
    source["notes"] = notes
    for note in notes:
        warnings.warn(note, stacklevel=2)
    readings = readings.copy()
    readings.attrs["display_source"] = source
    readings.attrs["noise_frames"] = noise_frames
    return readings, cal


def _header(path: Path) -> list[str]:
    with open(path, encoding="utf-8") as fh:
        return fh.readline().strip().split(",")


def _row_keys_list(frame: pd.DataFrame) -> list:
    return [(str(t), round(float(x), 6), round(float(y), 6), round(float(lv), 6), int(r))
            for t, x, y, lv, r in zip(frame["timestamp_utc"], frame["x_norm"], frame["y_norm"],
                                      frame["level"], frame["repeat"])]


def _read_check(path: Path) -> dict:
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise GapError(f"{path} is not valid JSON ({exc}); rerun the check") from exc
    need = ("kind", "check_id", "checked_calibration_id")
    if not isinstance(rec, dict) or rec.get("kind") != "check" or any(k not in rec
                                                                        for k in need):
        raise GapError(f"{path} is not a check record (needs kind 'check', check_id, "
                       "checked_calibration_id); pass a folder written by python -m "
                       "calibration check")
    return rec


def _has_pairs(frame: pd.DataFrame) -> bool:
    return bool(frame.groupby(["x_norm", "y_norm", "level"]).size().max() >= 2)


# --- the noise floor: pairs of repeats, drift modelled in time -----------------------------

def _times(frame: pd.DataFrame) -> pd.Series:
    t = pd.to_datetime(frame["timestamp_utc"], utc=True, errors="coerce", format="ISO8601")
    if t.isna().any():
        raise GapError(f"{int(t.isna().sum())} readings have no ISO 8601 timestamp_utc; "
                       "the drift model needs them (fix or drop those rows)")
    return t


def _pairs(frame: pd.DataFrame, t0) -> tuple[np.ndarray, ...]:
    """Consecutive readings of each patch (x, y, level), in time: (L1, L2, t1, t2) with t in
    s since ``t0``."""
    f = frame.assign(_t=(_times(frame) - t0).dt.total_seconds().to_numpy(float))
    f = f.sort_values("_t", kind="stable")
    out = [[], [], [], []]
    for _, grp in f.groupby(["x_norm", "y_norm", "level"], sort=False):
        if len(grp) < 2:
            continue
        lum, t = grp["luminance_cd_m2"].to_numpy(float), grp["_t"].to_numpy(float)
        for k, v in enumerate((lum[:-1], lum[1:], t[:-1], t[1:])):
            out[k].append(v)
    return tuple(np.concatenate(v) if v else np.zeros(0) for v in out)


def _bspline(x, lo: float, hi: float, n_interior: int, degree: int = 3) -> np.ndarray:
    """Cubic B-spline basis on [lo, hi] (x clipped to it), ``n_interior`` equal interior
    knots; shape (n, n_interior + degree + 1)."""
    hi = max(hi, lo + 1e-9)
    inner = np.linspace(lo, hi, n_interior + 2)[1:-1]
    knots = np.r_[[lo] * (degree + 1), inner, [hi] * (degree + 1)]
    return BSpline.design_matrix(np.clip(np.asarray(x, float), lo, hi), knots,
                                 degree).toarray()


def fit_noise_drift(frames, *, t0=None) -> dict:
    """Photometer noise from pairs of consecutive repeats, with the display's drift in time.

    Each pair ``(L1 at t1, L2 at t2)`` of the same patch differs by noise and by whatever the
    display did between t1 and t2::

        L2 - L1 = Lbar (g(t2) - g(t1)) + (c(t2) - c(t1)) + e,  var e = 2 a^2 + b^2 (L1^2 + L2^2)

    with ``g`` (relative, e.g. warm-up) and ``c`` (cd/m^2, e.g. room light) cubic splines in
    time. ``a``, ``b`` and the splines are fitted by maximum likelihood (splines by weighted
    least squares inside); the splines' knots (none, or 0-8 interior) are chosen by BIC, so a
    drift between repeats is modelled in time instead of being counted as noise.

    Parameters
    ----------
    frames : sequence of DataFrame
        Readings (READINGS_COLUMNS), e.g. a check's readings and its warm-up series.
    t0 : pandas.Timestamp, optional
        Time origin (default: the earliest reading).

    Returns
    -------
    dict
        ``abs`` (a, cd/m^2), ``rel`` (b, fraction), ``n_pairs``, ``drift_knots`` (None: no
        drift), ``drift_pct`` (range of the fitted relative drift g over the record, %),
        ``drift_abs_cd_m2`` (range of c).

    Raises
    ------
    GapError
        With fewer than 4 pairs of repeated readings.
    """
    frames = [f for f in frames if f is not None and len(f)]
    if t0 is None:
        t0 = min(_times(f).min() for f in frames)
    parts = [p for p in (_pairs(f, t0) for f in frames) if p[0].size]
    if sum(p[0].size for p in parts) < 4:
        raise GapError("the display diagnosis needs repeated readings of the same patch "
                       "(same x_norm, y_norm, level; >= 2 repeats) to measure the photometer's "
                       "noise; measure with --repeats 2 or more")
    l1, l2 = (np.concatenate([p[k] for p in parts]) for k in range(2))
    d, lbar, s2 = l2 - l1, 0.5 * (l1 + l2), l1**2 + l2**2
    # Each file (a session) drifts on its own: one spline per file over its own record.
    spans = [(float(min(p[2].min(), p[3].min())), float(max(p[2].max(), p[3].max())))
             for p in parts]
    best = None
    for knots in _DRIFT_KNOTS:
        cols = []
        if knots is not None:
            row = 0
            for p, (lo, hi) in zip(parts, spans):
                db = _bspline(p[3], lo, hi, knots) - _bspline(p[2], lo, hi, knots)
                db = db[:, 1:]  # the splines sum to 1: a constant drops out of a difference
                block = np.zeros((d.size, 2 * db.shape[1]))
                sl = slice(row, row + db.shape[0])
                block[sl] = np.c_[lbar[sl, None] * db, db]
                cols.append(block)
                row += db.shape[0]
        x = np.concatenate(cols, axis=1) if cols else np.zeros((d.size, 0))
        if x.shape[1] > d.size / 3:
            continue
        fit = _fit_pairs(d, s2, x)
        bic = 2 * fit["nll"] + (x.shape[1] + 2) * np.log(d.size)
        if best is None or bic < best[0]:
            best = (bic, knots, fit)
    _, knots, fit = best
    out = {"abs": fit["a"], "rel": fit["b"], "n_pairs": int(d.size), "drift_knots": knots,
           "drift_pct": 0.0, "drift_abs_cd_m2": 0.0}
    if knots is not None:
        k, at = knots + 3, 0
        for lo, hi in spans:
            basis = _bspline(np.linspace(lo, hi, 200), lo, hi, knots)[:, 1:]
            g, c = basis @ fit["beta"][at:at + k], basis @ fit["beta"][at + k:at + 2 * k]
            out["drift_pct"] = max(out["drift_pct"], float(100 * np.ptp(g)))
            out["drift_abs_cd_m2"] = max(out["drift_abs_cd_m2"], float(np.ptp(c)))
            at += 2 * k
    return out


def _fit_pairs(d, s2, x) -> dict:
    def profile(p):
        var = 2 * np.exp(2 * p[0]) + np.exp(2 * p[1]) * s2
        if x.shape[1]:
            sw = 1 / np.sqrt(var)
            beta, *_ = np.linalg.lstsq(x * sw[:, None], d * sw, rcond=1e-10)
            r = d - x @ beta
        else:
            beta, r = np.zeros(0), d
        return 0.5 * np.sum(np.log(var) + r**2 / var), beta
    res = optimize.minimize(lambda p: profile(p)[0], x0=[np.log(0.01), np.log(0.003)],
                            method="Nelder-Mead",
                            options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})
    nll, beta = profile(res.x)
    return {"a": float(np.exp(res.x[0])), "b": float(np.exp(res.x[1])), "nll": float(nll),
            "beta": beta}


# --- the data frame the engine works on -------------------------------------------------------

def display_frame(readings: pd.DataFrame, cal) -> pd.DataFrame:
    """Readings with the plain simulation's prediction and the noise model's SD.

    Columns added: ``t_s`` (s since the first reading), ``L`` (cd/m^2), ``lmin``, ``rel``
    (calibration uniformity at the patch), ``mu0`` (plain prediction, cd/m^2), ``sd`` (noise SD,
    cd/m^2), ``cell`` (patch name ``x,y,level``). ``attrs["noise"]``: :func:`fit_noise_drift`
    on ``readings.attrs["noise_frames"]`` (default: the readings themselves).
    """
    noise_frames = readings.attrs.get("noise_frames") or [readings]
    source = readings.attrs.get("display_source", {})
    out = readings.copy().reset_index(drop=True)
    out.attrs = {}
    t = _times(out)
    out["t_s"] = (t - t.min()).dt.total_seconds().to_numpy(float)
    out["L"] = out["luminance_cd_m2"].to_numpy(float)
    out["lmin"] = float(cal.min_luminance_cd_m2)
    x, y = out["x_norm"].to_numpy(float), out["y_norm"].to_numpy(float)
    if cal.uniformity is not None:
        rel0 = float(np.min(np.asarray(cal.uniformity.relative, float)))
        out["rel"] = rel0 / cal.uniformity.gain_at(x, y)
    else:
        out["rel"] = 1.0
    out["cell"] = [f"{a:+.3f},{b:+.3f},{c:.4f}" for a, b, c in zip(x, y, out["level"])]
    out.attrs["cal"] = cal
    out.attrs["display_source"] = source
    out["mu0"] = _mean(out, [])
    noise = fit_noise_drift(noise_frames)
    out.attrs["noise"] = noise
    out["sd"] = np.sqrt(noise["abs"] ** 2 + (noise["rel"] * out["L"]) ** 2)
    return out


def display_loss_info(data: pd.DataFrame) -> dict:
    """The noise model, the drift between repeats and what was diagnosed (for the report)."""
    n = data.attrs["noise"]
    return {"noise_abs_cd_m2": n["abs"], "noise_rel": n["rel"], "noise_pairs": n["n_pairs"],
            "drift_between_repeats_pct": n["drift_pct"],
            "drift_between_repeats_cd_m2": n["drift_abs_cd_m2"],
            "source": data.attrs.get("display_source", {})}


# --- the extended model -------------------------------------------------------------------

def _mean(data: pd.DataFrame, fitted: list) -> np.ndarray:
    """mu = Lmin + (L_cal(drive) - Lmin) rel gain + offset, each fitted candidate's ``apply``
    changing drive, gain or offset."""
    cal = data.attrs["cal"]
    terms = {"drive": data["level"].to_numpy(float), "gain": np.ones(len(data)),
             "offset": np.zeros(len(data))}
    for name, params in fitted:
        terms = candidate("display", name).apply(data, terms, params)
    lmin = data["lmin"].to_numpy(float)
    above = (cal.luminance_for_drive(terms["drive"]) - lmin) * data["rel"].to_numpy(float)
    return lmin + above * terms["gain"] + terms["offset"]


def display_nll(data: pd.DataFrame, mean: np.ndarray) -> np.ndarray:
    """Per-reading Gaussian NLL (nats) of predictions ``mean`` (cd/m^2) under the noise model."""
    sd = data["sd"].to_numpy(float)
    return 0.5 * np.log(2 * np.pi * sd**2) + 0.5 * ((data["L"].to_numpy(float) - mean) / sd) ** 2


def display_loss(data: pd.DataFrame, fitted: list) -> np.ndarray:
    """Loss for the engine: NLL of the simulation extended by ``fitted``."""
    return display_nll(data, _mean(data, fitted))


def display_floor(data: pd.DataFrame) -> np.ndarray:
    """Expected NLL of a model right up to the photometer's noise."""
    return 0.5 * np.log(2 * np.pi * data["sd"].to_numpy(float) ** 2) + 0.5


def display_unit_ids(data: pd.DataFrame) -> list[str]:
    """Reading names ``cell|repeat|row``."""
    return [f"{c}|{r}|{i}" for c, r, i in zip(data["cell"], data["repeat"], data.index)]


def split_display(data: pd.DataFrame, rng: np.random.Generator):
    """Held-out split, the same for any seed when patches are repeated: each patch's readings
    in time order alternate between train and held out, starting with train for every other
    patch (patches in order of their first reading). So both halves hold every patch and span
    the whole record, also when the repeats were measured in passes (a drift in time is then
    interpolated, not extrapolated). Without repeats, half the readings at random."""
    if not _has_pairs(data):
        return split_held_out(data, None, rng)
    order = data.sort_values("t_s", kind="stable")
    first = order.groupby("cell", sort=False).ngroup()
    rank = order.groupby("cell", sort=False).cumcount()
    held = pd.Series(((first + rank) % 2 == 1).to_numpy(), index=order.index)
    return split_held_out(data, held.reindex(data.index).to_numpy(bool), rng)


def display_folds(data: pd.DataFrame, rng: np.random.Generator):
    """Cross-fitting folds: the :func:`split_display` halves, each held out once.

    Every reading is then held out (fitted on the other half), so a test rests on all the
    readings, not half of them: an effect seen only in a few readings (a black offset shows in
    the darkest patches alone) is tested on twice as many of them as with one split.

    Returns
    -------
    (folds, text)
        ``folds``: ``[(train, test), (test, train)]``; ``text``: how readings were held out,
        in words.
    """
    train, test = split_display(data, rng)
    how = ("each patch's repeats alternating between two halves" if _has_pairs(data)
           else "two random halves")
    return [(train, test), (test, train)], (f"cross-fitted: {how}, each half fitted on the "
                                            "other and held out once")


def _wls(res, x, w):
    """Weighted least squares of residuals ``res`` on the columns of ``x``."""
    x = np.atleast_2d(np.asarray(x, float).T).T
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(x * sw[:, None], res * sw, rcond=None)
    return coef


def _above(train, chosen):
    """Above-black part of the model ``chosen`` (its offset removed), cd/m^2."""
    mu = _mean(train, chosen)
    off = sum(p["c"] for n, p in chosen if n == "black_offset")
    return mu, mu - train["lmin"].to_numpy(float) - off


# Each candidate: its fit, its term in the mean, its injector (a change of the simulated
# display's parameters, by name, so no simulator is imported here), its default strength and
# the parameters a right fit should recover at a strength.

def _apply_black(data, terms, p):
    return terms | {"offset": terms["offset"] + p["c"]}


def _fit_black(train, chosen):
    res = train["L"].to_numpy(float) - _mean(train, chosen)
    w = 1 / train["sd"].to_numpy(float) ** 2
    return {"c": float(_wls(res, np.ones(len(train)), w)[0])}


def _apply_nonuniformity(data, terms, p):
    x, y = data["x_norm"].to_numpy(float), data["y_norm"].to_numpy(float)
    return terms | {"gain": terms["gain"] * (1 + p["f"] * (x**2 + y**2) / 2 + p["g"] * x
                                             + p["h"] * y)}


def _fit_nonuniformity(train, chosen):
    mu, above = _above(train, chosen)
    x, y = train["x_norm"].to_numpy(float), train["y_norm"].to_numpy(float)
    if np.unique(np.c_[x, y], axis=0).shape[0] < 3:
        return {"f": 0.0, "g": 0.0, "h": 0.0}
    cols = np.c_[above * (x**2 + y**2) / 2, above * x, above * y]
    res = train["L"].to_numpy(float) - mu
    f, g, h = _wls(res, cols, 1 / train["sd"].to_numpy(float) ** 2)
    return {"f": float(f), "g": float(g), "h": float(h)}


def _apply_warmup(data, terms, p):
    t = data["t_s"].to_numpy(float)
    return terms | {"gain": terms["gain"] * (1 - p["w"] * np.exp(-t / p["tau_s"]))}


def _fit_warmup(train, chosen):
    res0 = train["L"].to_numpy(float) - _mean(train, chosen)
    base = [c for c in chosen if c[0] != "warmup_drift"]
    mu, above = _above(train, base)
    res = train["L"].to_numpy(float) - mu
    w = 1 / train["sd"].to_numpy(float) ** 2
    t = train["t_s"].to_numpy(float)
    best = (np.sum(w * res0**2), {"w": 0.0, "tau_s": float(_TAUS_S[0])})
    # A drift must decay within the record: a longer time constant is a constant gain.
    for tau in _TAUS_S[_TAUS_S <= max(_TAU_RECORDS * t.max(), _TAUS_S[0])]:
        col = -above * np.exp(-t / tau)
        a = float(_wls(res, col, w)[0])
        a = min(max(a, 0.0), 0.9)
        sse = float(np.sum(w * (res - a * col) ** 2))
        if sse < best[0]:
            best = (sse, {"w": a, "tau_s": float(tau)})
    return best[1]


def _apply_quantisation(data, terms, p):
    steps = 2 ** int(p["bits"]) - 1
    return terms | {"drive": np.round(terms["drive"] * steps) / steps}


def _fit_quantisation(train, chosen):
    base = [c for c in chosen if c[0] != "quantisation"]
    w = 1 / train["sd"].to_numpy(float) ** 2
    best = None
    for b in _BITS:
        mu = _mean(train, base + [("quantisation", {"bits": b})])
        sse = float(np.sum(w * (train["L"].to_numpy(float) - mu) ** 2))
        if best is None or sse < best[0] - 1e-9:
            best = (sse, b)
    return {"bits": int(best[1])}


def _change(**how):
    """An injector: ``inject(display, strength) -> display`` with the named parameters of a
    frozen-dataclass display changed by ``how[name](old value, strength)``."""
    from dataclasses import replace

    def inject(display, strength):
        return replace(display, **{k: f(getattr(display, k), float(strength))
                                   for k, f in how.items()})
    return inject


register("display", Candidate(
    "black_offset", _fit_black, "extra black level or reflected ambient light",
    apply=_apply_black, inject=_change(ambient_cd_m2=lambda v, s: v + s),
    default_strength=0.05, units="cd/m^2", truth=lambda s: {"c": float(s)}))
register("display", Candidate(
    "nonuniformity", _fit_nonuniformity,
    "spatial non-uniformity beyond the calibration's map (falloff, gradients)",
    apply=_apply_nonuniformity,
    inject=_change(falloff=lambda v, s: v + s, tilt_x=lambda v, s: v + s / 2),
    default_strength=0.06, units="fractional loss at the corners",
    # To first order the extra falloff s and tilt s / 2 are f = -s, g = s / 2.
    truth=lambda s: {"f": -float(s), "g": float(s) / 2, "h": 0.0}))
register("display", Candidate(
    "warmup_drift", _fit_warmup, "luminance rises while the display warms up",
    apply=_apply_warmup, inject=_change(warmup_drift=lambda v, s: s),
    default_strength=0.03, units="fractional deficit at switch-on",
    truth=lambda s: {"w": float(s), "tau_s": 600.0}))
register("display", Candidate(
    "quantisation", _fit_quantisation, "coarser DAC than the calibration assumes",
    apply=_apply_quantisation, inject=_change(bits=lambda v, s: round(v - s)),
    default_strength=2.0, units="DAC bits lost", truth=lambda s: {"bits": 8 - round(s)}))

DISPLAY_CANDIDATES = catalogue("display")


# --- the ceiling: a penalised smooth of level, position and time ------------------------------

def _ceiling_design(data: pd.DataFrame, span: dict):
    """Columns of the ceiling's smooth (cd/m^2 per unit coefficient) with their penalty kinds.

    Blocks: a constant; a cubic spline in drive (8 interior knots), additive and times the
    predicted above-black light ``a``; per screen position a constant, ``a`` and
    ``a ln(drive)`` (an exponent change there); a line in time and a cubic spline in time (3
    interior knots) times ``a`` (a drift of the light). Each block has its own smoothing
    parameter: "level" and "time" blocks a second-difference penalty, "pos" blocks a ridge.
    """
    lv = data["level"].to_numpy(float)
    a = np.maximum(data["mu0"].to_numpy(float) - data["lmin"].to_numpy(float), 0.0)
    t = data["t_s_abs"].to_numpy(float)
    bl = _bspline(lv, 0.0, 1.0, 8)
    bt = _bspline(t, span["t_lo"], span["t_hi"], 3)
    pos = np.array([span["pos"].index(p) if p in span["pos"] else -1
                    for p in zip(np.round(data["x_norm"], 4), np.round(data["y_norm"], 4))])
    onehot = (pos[:, None] == np.arange(len(span["pos"]))[None, :]).astype(float)
    shape = a * np.log(np.maximum(lv, 1e-3))
    line = (t - span["t_lo"]) / max(span["t_hi"] - span["t_lo"], 1.0)
    return [(np.ones((len(data), 1)), None), (line[:, None], None),
            (bl[:, 1:], "level"), (bl * a[:, None], "level"),
            (onehot, "pos"), (onehot * a[:, None], "pos"), (onehot * shape[:, None], "pos"),
            (bt[:, 1:] * a[:, None], "time")]


_PENALTY_KINDS = ("level", "pos", "time")


def _penalties(blocks, xtwx_diag) -> dict:
    """One penalty matrix per kind (level, time: second differences; pos: identity), each
    block scaled by its mean diagonal of X'WX so that one grid of smoothing parameters fits
    all."""
    sizes = [b[0].shape[1] for b in blocks]
    p = sum(sizes)
    out = {k: np.zeros((p, p)) for k in _PENALTY_KINDS}
    k = 0
    for (_, kind), n in zip(blocks, sizes):
        if kind is not None:
            scale = float(np.mean(xtwx_diag[k:k + n])) or 1.0
            if kind != "pos" and n >= 3:
                dm = np.diff(np.eye(n), 2, axis=0)
                out[kind][k:k + n, k:k + n] = scale * dm.T @ dm
            else:
                out[kind][k:k + n, k:k + n] = scale * np.eye(n)
        k += n
    return out


def _solve(x, r, w, pen):
    xtw = x.T * w
    # Least squares, not solve: with few readings the penalised system can be singular.
    return np.linalg.lstsq(xtw @ x + pen, xtw @ r, rcond=None)[0]


def display_ceiling(train: pd.DataFrame, test: pd.DataFrame, *, folds: int = 5,
                    seed: int = 0) -> np.ndarray:
    """Held-out loss of a flexible data-driven model of the readings: the ceiling.

    The residual ``L - mu0`` of the plain simulation is fitted on ``train`` by penalised
    weighted least squares (weights 1 / sd^2, the noise model) on the smooth of
    :func:`_ceiling_design`: any systematic structure in level, position or time that the
    catalogue lacks (a gamma change in the mid-range, a position x level interaction) is
    fitted by it. The three smoothing parameters (level, position, time) are chosen by
    ``folds``-fold cross-validation on ``train`` (folds by patch, so a patch is predicted from
    the others; coordinate descent over a grid, two sweeps from the smoothest model). When
    the smooth predicts left-out patches no better than the plain simulation (too few
    readings), the ceiling is the plain simulation.

    Parameters
    ----------
    train, test : DataFrame
        :func:`display_frame` rows (the engine's split).
    folds : int
        Cross-validation folds.
    seed : int
        Seeds the fold assignment (the result hardly depends on it).

    Returns
    -------
    ndarray, shape (len(test),)
        Gaussian NLL (nats) of each held-out reading under the fitted smooth.
    """
    both = pd.concat([train, test])
    t_all = _times(both)
    t0 = t_all.min()
    span = {"t_lo": 0.0, "t_hi": float((t_all.max() - t0).total_seconds()),
            "pos": sorted(set(zip(np.round(both["x_norm"], 4), np.round(both["y_norm"], 4))))}

    def design(d):
        d = d.assign(t_s_abs=(_times(d) - t0).dt.total_seconds().to_numpy(float))
        blocks = _ceiling_design(d, span)
        return np.concatenate([b[0] for b in blocks], axis=1), blocks
    x_tr, blocks = design(train)
    x_te, _ = design(test)
    r = (train["L"] - train["mu0"]).to_numpy(float)
    w = 1 / train["sd"].to_numpy(float) ** 2
    pens = _penalties(blocks, np.einsum("ij,i,ij->j", x_tr, w, x_tr))
    cells = train["cell"].to_numpy()
    uniq = np.unique(cells)
    fold_of = dict(zip(uniq, np.random.default_rng(seed).permutation(uniq.size) % folds))
    fold = np.array([fold_of[c] for c in cells])

    def cv_error(lams):
        pen = sum(lams[k] * pens[k] for k in _PENALTY_KINDS)
        err = 0.0
        for k in range(folds):
            m = fold != k
            if m.all() or not m.any():
                continue
            beta = _solve(x_tr[m], r[m], w[m], pen)
            err += float(np.sum(w[~m] * (r[~m] - x_tr[~m] @ beta) ** 2))
        return err
    # Coordinate descent over the grid, from the smoothest model: two sweeps.
    lams = dict.fromkeys(_PENALTY_KINDS, float(_CEIL_LAMBDAS[-1]))
    for _ in range(2):
        for kind in _PENALTY_KINDS:
            errs = [cv_error(lams | {kind: float(v)}) for v in _CEIL_LAMBDAS]
            lams[kind] = float(_CEIL_LAMBDAS[int(np.argmin(errs))])
    pen = sum(lams[k] * pens[k] for k in _PENALTY_KINDS)
    # A smooth that predicts left-out patches worse than the plain simulation (too few
    # readings to fit one, e.g. a handful of validation readings) is no ceiling: use the plain
    # simulation's prediction instead.
    zero = float(sum(np.sum(w[fold == k] * r[fold == k] ** 2) for k in range(folds)))
    if cv_error(lams) >= zero:
        return display_nll(test, test["mu0"].to_numpy(float))
    beta = _solve(x_tr, r, w, pen)
    return display_nll(test, test["mu0"].to_numpy(float) + x_te @ beta)


_WHERE_AXES = ("drive level", "screen position", "time in the run")


def _where_cells(test: pd.DataFrame) -> dict[str, list[str]]:
    """Each held-out reading's cell on the three axes the words use: drive level in five bands,
    screen position, and third of the run's time span."""
    t = test["t_s"].to_numpy(float)
    span = max(float(t.max() - t.min()), 1e-9)
    third = np.clip(((t - t.min()) / span * 3).astype(int), 0, 2)
    names = ("the first third", "the middle third", "the last third")
    return {"drive level": [f"drive levels {b}" for b in _fifths(test["level"])],
            "screen position": [f"screen position {p}" for p in _positions(test)],
            "time in the run": [f"{names[k]} of the run" for k in third]}


def _fifths(frac) -> list[str]:
    """Labels of the fifth of [0, 1] each value lies in ("0.2-0.4")."""
    edges = np.linspace(0, 1, 6)
    band = np.clip(np.digitize(np.asarray(frac, float), edges[1:-1]), 0, 4)
    return [f"{edges[k]:.1f}-{edges[k + 1]:.1f}" for k in band]


def _positions(data: pd.DataFrame) -> list[str]:
    """Labels of the readings' screen positions ("(+0.60, -0.60)", normalised units)."""
    return [f"({a:+.2f}, {b:+.2f})" for a, b in zip(data["x_norm"], data["y_norm"])]


def display_where(fits: list) -> str:
    """Words for where the chosen model falls short of the ceiling.

    On each axis (drive level in five bands, screen position, third of the run) the cell that
    carries the most held-out excess loss (the chosen model's loss minus the ceiling's) is
    found; the axis whose top cell is the most concentrated (its share of the excess over its
    share of the readings) is named, with the cell's share of the excess and whether the
    readings that carry it are brighter or darker than the extended model there (or some of
    each: a gamma that changes across the screen is brighter on one side, darker on the
    other). A second axis is named too where its top cell holds at least twice its share of
    the readings.

    ``fits``: ``[(train, test, fitted, ceiling_loss), ...]`` per fold (see
    engine.diagnose_losses; ``ceiling_loss`` from `display_ceiling`, in the test's row order).
    """
    rows = []
    for _train, test, fitted, ceiling_loss in fits:
        rows.append(pd.DataFrame(_where_cells(test) | {
            "excess": display_loss(test, list(fitted)) - np.asarray(ceiling_loss, float),
            "brighter": test["L"].to_numpy(float) > _mean(test, list(fitted)),
            "x": test["x_norm"].to_numpy(float), "y": test["y_norm"].to_numpy(float)}))
    if not rows:
        return ""
    data = pd.concat(rows, ignore_index=True)
    data["pos_excess"] = data["excess"].clip(lower=0.0)
    ranked = []
    for axis in _WHERE_AXES:
        net = data.groupby(axis)["excess"].sum()
        total = float(net.clip(lower=0.0).sum())
        if net.size < 2 or total <= 0:
            continue
        cell = net.idxmax()
        share = float(max(net[cell], 0.0)) / total
        ranked.append((share * len(data) / int((data[axis] == cell).sum()), axis, cell, share))
    if not ranked:
        return ""
    ranked.sort(key=lambda r: r[0], reverse=True)
    words = []
    for rank, (lift, axis, cell, share) in enumerate(ranked[:2]):
        if rank and lift < 2:
            break
        words.append(f"at {cell} (readings {_side(data[data[axis] == cell])}; "
                     f"{100 * share:.0f} % of the excess)")
    return "mostly " + ", and ".join(words)


def _side(cell: pd.DataFrame) -> str:
    """Brighter or darker than the extended model, where >= 75 % of the cell's excess is on one
    side; else which side of the screen is brighter, where the brighter readings'
    excess-weighted mean x (or y) differs from the darker ones' by more than a third of the
    screen (2 / 3 in normalised units)."""
    w = cell["pos_excess"].to_numpy(float)
    up = cell["brighter"].to_numpy(bool)
    frac = float(w[up].sum() / max(w.sum(), 1e-300))
    if frac >= 0.75:
        return "brighter than the extended model"
    if frac <= 0.25:
        return "darker than the extended model"
    best = ""
    for col, (lo, hi) in (("x", ("left", "right")), ("y", ("bottom", "top"))):
        v = cell[col].to_numpy(float)
        d = (np.average(v[up], weights=w[up] + 1e-300)
             - np.average(v[~up], weights=w[~up] + 1e-300))
        if abs(d) > 2 / 3 and (not best or abs(d) > best[0]):
            side = hi if d > 0 else lo
            other = lo if d > 0 else hi
            words = f"brighter than the extended model towards the {side}, darker towards the"
            best = (abs(d), f"{words} {other}")
    return best[1] if best else "some brighter, some darker than the extended model"


def localise_display(data: pd.DataFrame, rng: np.random.Generator,
                     n_boot: int = 1000) -> pd.DataFrame:
    """Mean relative residual (100 (L - mu0) / mu0, %) over the luminance range (the
    calibration's luminance fraction in 5 bins) and per screen position, with 95 % bootstrap
    CIs over readings. Generic localisation columns: axis, cell, n, mean_residual, ci_low,
    ci_high."""
    res = 100 * (data["L"] - data["mu0"]).to_numpy(float) / np.maximum(
        data["mu0"].to_numpy(float), 1e-6)
    cal = data.attrs["cal"]
    frac = (data["mu0"].to_numpy(float) - cal.min_luminance_cd_m2) / (
        cal.max_luminance_cd_m2 - cal.min_luminance_cd_m2)
    rows = []
    for axis, labels in (("luminance fraction", _fifths(frac)),
                         ("screen position (x, y norm)", _positions(data))):
        frame = pd.DataFrame({"cell": labels, "res": res})
        for cell, grp in frame.groupby("cell"):
            v = grp["res"].to_numpy()
            b = v[rng.integers(0, v.size, (n_boot, v.size))].mean(axis=1)
            lo, hi = np.percentile(b, [2.5, 97.5])
            rows.append({"axis": axis, "cell": cell, "n": v.size, "mean_residual": v.mean(),
                         "ci_low": lo, "ci_high": hi, "unit": "% of predicted luminance"})
    return pd.DataFrame(rows)
