"""Reading and checking the observer layer's files (observer layer).

The real responses are session CSVs read with the experiment's own reader
(:func:`read_session_csvs`); the simulation (``--sim``) is an observers TOML table, simulated
session CSVs or a frame (:func:`load_sim`, :func:`base_from_sessions`), checked against the real
data (:func:`check_sim`). :func:`observer_frame` checks the columns and adds the truth in slider
units, the previous response and the base model's mean; :func:`observer_folds` is the held-out
scheme (by participant, else by trial) and :func:`observer_unit_ids` names the held-out units.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.gap.engine import GapError
from analysis.gap.observer.model import (
    RESP,
    ObserverBase,
    base_from_params,
    to_slider_units,
)

__all__ = [
    "base_from_sessions",
    "check_numeric_rows",
    "check_sim",
    "load_sim",
    "observer_folds",
    "observer_frame",
    "observer_unit_ids",
    "read_session_csvs",
    "time_on_task",
]


# --- reading ------------------------------------------------------------------------------

def read_session_csvs(path: str | Path) -> pd.DataFrame:
    """Read every ``*.csv`` session file under ``path`` (a folder searched recursively, or one
    file) with the experiment's own reader (:func:`experiment.read_session`)."""
    from experiment import DataFileError, read_session

    path = Path(path)
    if not path.exists():
        raise GapError(f"{path} does not exist; pass a folder holding <P>_s<N>.csv session files")
    if path.is_file() and path.suffix.lower() != ".csv":
        hint = (" (an observers TOML is a simulation: --real and --sim swapped? --real takes the "
                "real session CSVs, --sim the TOML)" if path.suffix.lower() == ".toml" else "")
        raise GapError(f"{path} is not a session CSV{hint}; pass a folder holding <P>_s<N>.csv "
                       "session files")
    files = [path] if path.is_file() else sorted(path.rglob("*.csv"))
    if not files:
        raise GapError(f"no session CSVs found at {path}; pass a folder holding <P>_s<N>.csv files")
    frames = []
    for f in files:
        try:
            frames.append(read_session(f))
        except DataFileError as exc:
            raise GapError(f"{exc} (session CSVs need the experiment's SESSION_COLUMNS)") from exc
    kept = [(f, fr) for f, fr in zip(files, frames) if len(fr)]
    out = pd.concat([fr for _, fr in kept], ignore_index=True) if kept else None
    if out is None or not len(out):
        raise GapError(f"the session CSVs at {path} hold no trials")
    # Where each row came from (file, data row from 1), for errors that name them.
    out.attrs["rows_from"] = [(str(f), i + 1) for f, fr in kept for i in range(len(fr))]
    return out


#: The columns of a session row that must hold numbers (truth and both settings).
_NUMERIC = ("true_gloss_pct", "true_depth_cm", "gloss_match", "depth_match")


def check_numeric_rows(frame: pd.DataFrame, what: str) -> None:
    """Refuse rows whose truth or settings are empty or not numbers (NaN, inf, text), naming
    the files and data rows (from :func:`read_session_csvs`) or the participants and
    sessions; nothing is changed or dropped.

    Raises
    ------
    GapError
        Such rows, with where they are and the fix.
    """
    missing = [c for c in _NUMERIC if c not in frame.columns]
    if missing:
        raise GapError(f"{what} lack the columns {missing} (session CSVs need the experiment's "
                       "SESSION_COLUMNS)")
    values = frame[list(_NUMERIC)].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    bad = ~np.isfinite(values).all(axis=1)
    if not bad.any():
        return
    cols = [c for c, b in zip(_NUMERIC, (~np.isfinite(values[bad])).any(axis=0)) if b]
    src = frame.attrs.get("rows_from")
    if src is not None and len(src) == len(frame):
        at: dict = {}
        for i in np.flatnonzero(bad):
            at.setdefault(src[i][0], []).append(src[i][1])
        where = "; ".join(f"{f} data rows {r[:8]}{' ...' if len(r) > 8 else ''}"
                          for f, r in list(at.items())[:5])
    else:
        pairs = frame.loc[bad, ["participant", "session"]].drop_duplicates()
        where = "participant, session: " + str(pairs.to_numpy().tolist()[:5])
    raise GapError(f"{what}: {int(bad.sum())} of {len(frame)} rows have empty or non-numeric "
                   f"{cols} ({where}); a session written by an interrupted or broken run: "
                   "simulate these sessions again, or move the damaged files aside "
                   "(nothing is changed by the diagnosis)")


# --- the simulation's files ---------------------------------------------------------------

def base_from_sessions(frame: pd.DataFrame, design, *, source: str = "sessions") -> ObserverBase:
    """The base model of simulated session CSVs: their mean response fitted (least squares,
    slider units) in the humanlike form; the kind is read from the files' ``app_version``
    ('simulate_dataset:<kind>') where it says."""
    s = design.slider
    mid = 0.5 * (s.min + s.max)
    gu, du = to_slider_units(s, frame["true_gloss_pct"], frame["true_depth_cm"])
    g, d = gu - mid, du - mid
    yg = frame["gloss_match"].to_numpy(float) - mid
    yd = frame["depth_match"].to_numpy(float) - mid
    x = np.c_[np.ones(len(g)), g, d, g * d]
    cg = np.linalg.lstsq(x, yg, rcond=None)[0]
    cd = np.linalg.lstsq(x[:, [0, 2]], yd, rcond=None)[0]
    kinds = {str(v).rsplit(":", 1)[1] for v in frame.get("app_version", pd.Series(dtype=str))
             .dropna().astype(str) if ":" in str(v)}
    kind = kinds.pop() if len(kinds) == 1 else "unknown"
    who = frame["participant"].astype(str).to_numpy()
    return ObserverBase(kind=kind, source=source,
                        coef={"gloss": tuple(float(v) for v in cg),
                              "depth": tuple(float(v) for v in cd)},
                        participants=tuple(sorted(np.unique(who))),
                        stimuli=_stimuli(frame),
                        n_illuminations=int(frame["illumination"].nunique()),
                        sd={"gloss": _between_sd(x, yg, who), "depth": _between_sd(
                            x[:, [0, 2]], yd, who)} if np.unique(who).size >= 2 else None)


def _between_sd(x: np.ndarray, y: np.ndarray, who: np.ndarray) -> tuple:
    """Between-participant SDs of the coefficients of ``y ~ x`` among the simulated
    participants (slider units): the variance of their own least-squares coefficients less
    the mean of their sampling variances, floored at 0 (method of moments, as fit-observer's
    population). The simulated observers differ from each other by this much, so a real
    observer who does is no gap (issue 43: without it, 3 real participants and nothing added
    read "unexplained ... differing between participants" against simulated sessions)."""
    own, err = [], []
    for pid in np.unique(who):
        m = who == pid
        if m.sum() <= x.shape[1] + 2:
            continue
        b, *_ = np.linalg.lstsq(x[m], y[m], rcond=None)
        noise = float(np.sum((y[m] - x[m] @ b) ** 2)) / (m.sum() - x.shape[1])
        own.append(b)
        err.append(np.diag(np.linalg.pinv(x[m].T @ x[m])) * noise)
    if len(own) < 2:
        return tuple(0.0 for _ in range(x.shape[1]))
    var = np.var(own, axis=0, ddof=1) - np.mean(err, axis=0)
    return tuple(float(v) for v in np.sqrt(np.maximum(var, 0.0)))


def _stimuli(frame: pd.DataFrame) -> tuple:
    pairs = {(round(float(g), 6), round(float(d), 6))
             for g, d in zip(frame["true_gloss_pct"], frame["true_depth_cm"])}
    return tuple(sorted(pairs))


def load_sim(sim, design, *, kind: str | None = None) -> ObserverBase:
    """The base model from ``--sim``: an observers TOML (``.toml``: the ``humanlike`` table, or
    ``kind``), a folder or file of simulated session CSVs, a session frame, or an
    ``ObserverBase``.

    Raises
    ------
    GapError
        A missing or unreadable file, or a kind the file lacks.
    """
    if isinstance(sim, ObserverBase):
        return sim
    if isinstance(sim, pd.DataFrame):
        check_numeric_rows(sim, "the simulated sessions (--sim)")
        return base_from_sessions(sim, design)
    path = Path(sim)
    if path.suffix.lower() == ".toml":
        from experiment import load_observer_params

        try:
            params = load_observer_params(path)
        except (ValueError, TypeError) as exc:
            raise GapError(f"--sim {path}: {exc}") from exc
        kind = kind or "humanlike"
        if kind not in params:
            raise GapError(f"--sim {path} has no [{kind}] table; it has {sorted(params)}")
        fit = params.get("fit") if isinstance(params.get("fit"), Mapping) else None
        return base_from_params(params[kind], kind if fit is None or kind == "ideal"
                                else "fitted", design.slider, source=str(path), fit_info=fit)
    frame = read_session_csvs(path)
    check_numeric_rows(frame, f"the simulated sessions at --sim {path}")
    return base_from_sessions(frame, design, source=str(path))


def check_sim(real: pd.DataFrame, base: ObserverBase) -> list[str]:
    """Warnings where the simulation does not match the real data: participant ids, stimuli
    or illuminations that differ, or a simulation of the ideal observer (truth + noise),
    which is not an observer fitted to the lab's data."""
    out = []
    real_ids = tuple(sorted(real["participant"].astype(str).unique()))
    if base.participants:
        shared = sorted(set(base.participants) & set(real_ids))
        if base.kind == "fitted" and shared:
            out.append(f"the observer was fitted to participants {list(base.participants)}, "
                       f"of whom {shared} are in the data diagnosed: the diagnosis is then "
                       "in-sample for them; fit to a pilot or to other sessions")
        elif base.kind != "fitted" and set(base.participants) != set(real_ids):
            out.append(f"the simulated participants {list(base.participants)} are not the real "
                       f"ones {list(real_ids)}: their plans (stimulus orders) differ; simulate "
                       "with the same participant ids")
    real_stimuli = _stimuli(real)
    covered = set(base.stimuli) & set(real_stimuli)
    if base.stimuli and len(covered) < len(real_stimuli):
        out.append(f"mismatch: the simulation covers {len(covered)} of the {len(real_stimuli)} "
                   f"gloss x depth levels of the real sessions ({100 * len(covered) / len(real_stimuli):.0f} %); "
                   "the verdict on the others rests on extrapolation: simulate every real "
                   "participant and session with the real data's study design")
    elif base.stimuli and base.stimuli != real_stimuli:
        out.append(f"the simulated sessions show other stimuli ({len(base.stimuli)} gloss x depth "
                   f"levels) than the real ones ({len(real_stimuli)}); simulate with the "
                   "real data's study design")
    if base.n_illuminations is not None and base.n_illuminations != real["illumination"].nunique():
        out.append(f"the simulation has {base.n_illuminations} illuminations, the real data "
                   f"{real['illumination'].nunique()}")
    if base.kind == "ideal":
        out.append("the simulation is the ideal observer (truth + noise), not an observer fitted "
                   "to your data: the diagnosis names every way your observers differ from "
                   "the truth; to compare with the humanlike simulation, fit one with python -m "
                   "experiment fit-observer PILOT_SESSIONS --out observers.toml and pass --sim "
                   "observers.toml")
    elif base.kind == "humanlike" and base.source.endswith(".toml"):
        out.append(f"the simulation is the humanlike table of {base.source}, which was not "
                   "fitted to a pilot (no [fit] table): fit one with python -m experiment "
                   "fit-observer PILOT_SESSIONS --out observers.toml")
    elif base.kind == "unknown":
        out.append("the simulated sessions do not say which observer made them (app_version)")
    return out


def observer_frame(frame: pd.DataFrame, design, base: ObserverBase | None = None) -> pd.DataFrame:
    """Add truth in slider units (``gloss_u``, ``depth_u``), the previous response of the same
    session (``*_prev``, NaN on a session's first trial) and the base model's mean
    (``*_base``; the ideal observer's without ``base``)."""
    s = design.slider
    need = ("participant", "session", "order", "illumination", "gloss_level", "depth_level",
            "true_gloss_pct", "true_depth_cm", "gloss_match", "depth_match")
    missing = [c for c in need if c not in frame.columns]
    if missing:
        raise GapError(f"session rows lack the columns {missing}")
    check_numeric_rows(frame, "the session rows diagnosed (--real)")
    out = frame.copy()
    # Where each row came from is for the checks' errors only: pandas deep-copies a frame's
    # attrs on every column taken from it, and a list of 3,000 (file, row) pairs made that
    # 90 % of a diagnosis's time (105 of 114 s, cProfile, two benchmark trials).
    out.attrs.pop("rows_from", None)
    out["participant"] = out["participant"].astype(str)
    out["gloss_u"], out["depth_u"] = to_slider_units(s, out["true_gloss_pct"],
                                                     out["true_depth_cm"])
    out["illumination"] = out["illumination"].astype(str)
    out = out.sort_values(["participant", "session", "order"]).reset_index(drop=True)
    for r in RESP:
        out[f"{r}_match"] = out[f"{r}_match"].astype(float)
        out[f"{r}_prev"] = out.groupby(["participant", "session"])[f"{r}_match"].shift(1)
    out["t_session_min"], out["t_rest_min"] = time_on_task(out)
    mid = 0.5 * (s.min + s.max)
    base = base or base_from_params({}, "ideal", s)
    mu = base.mean(out["gloss_u"], out["depth_u"], mid)
    for r in RESP:
        out[f"{r}_base"] = mu[r]
    out.attrs["mid"] = mid
    out.attrs["range"] = (float(s.min), float(s.max))
    return out


#: A pause between a response and the next onset at least this long (s) is a rest: the
#: time since a rest starts again after it (:func:`time_on_task`).
REST_PAUSE_S = 30.0


def time_on_task(data: pd.DataFrame, rest_pause_s: float = REST_PAUSE_S):
    """Minutes since the session's start and minutes since its last rest, per trial.

    ``data`` sorted by participant, session and order (as :func:`observer_frame` sorts it),
    with ``onset_s`` (stimulus onset on the session clock, s) and ``rt_s``. A rest is a pause
    of at least ``rest_pause_s`` between a response and the next onset, or the session clock
    starting again (a resumed run); the session's start is its first onset. Rows without
    times (NaN) give 0: no trend in time can then be fitted, and none is claimed.

    Returns
    -------
    (ndarray, ndarray)
        ``(t_session_min, t_rest_min)``, shape (n_trials,), minutes.
    """
    onset = pd.to_numeric(data.get("onset_s"), errors="coerce") if "onset_s" in data else None
    if onset is None:
        zeros = np.zeros(len(data))
        return zeros, zeros.copy()
    onset = onset.to_numpy(float)
    rt = pd.to_numeric(data["rt_s"], errors="coerce").to_numpy(float) if "rt_s" in data \
        else np.zeros(len(data))
    keys = (data["participant"].astype(str) + "|" + data["session"].astype(str)).to_numpy()
    t_sess, t_rest = np.zeros(len(data)), np.zeros(len(data))
    start = rest_at = offset = 0.0
    for i in range(len(data)):
        new_session = i == 0 or keys[i] != keys[i - 1]
        if not np.isfinite(onset[i]):
            continue
        if new_session:
            start = rest_at = onset[i]
            offset = 0.0
        else:
            prev_end = onset[i - 1] + (rt[i - 1] if np.isfinite(rt[i - 1]) else 0.0)
            if not np.isfinite(onset[i - 1]) or onset[i] < onset[i - 1]:
                # The clock started again (a resumed run): time goes on from the last trial.
                offset = t_sess[i - 1] * 60.0 if i else 0.0
                start = rest_at = onset[i]
                t_rest[i], t_sess[i] = 0.0, offset / 60.0
                continue
            if onset[i] - prev_end >= rest_pause_s:
                rest_at = onset[i]
        t_sess[i] = (offset + onset[i] - start) / 60.0
        t_rest[i] = (onset[i] - rest_at) / 60.0
    return t_sess, t_rest


# --- held-out units and folds ------------------------------------------------------------

def observer_unit_ids(data: pd.DataFrame) -> list[str]:
    """Trial names ``participant|session|order`` (the held-out units of the diagnosis)."""
    return [f"{p}|{s}|{o}" for p, s, o in
            zip(data["participant"], data["session"], data["order"])]


def observer_folds(data: pd.DataFrame, k: int = 5) -> tuple[list, str]:
    """Deterministic K-fold held-out scheme (no random split, so the seed cannot change it):
    by participant (sorted ids, id i in fold i mod K, K = min(k, participants)) when there are
    >= 4 participants, else by trial (presentation order mod K within each session).

    Returns
    -------
    (folds, description)
        ``folds`` a list of (train, test) frames that keep ``data.attrs``.
    """
    parts = sorted(data["participant"].unique())
    if len(parts) >= 4:
        kk = min(k, len(parts))
        fold_of = {p: i % kk for i, p in enumerate(parts)}
        fold = data["participant"].map(fold_of).to_numpy(int)
        text = f"{kk}-fold by participant ({len(parts)} participants)"
    else:
        kk = k
        rank = data.groupby(["participant", "session"])["order"].rank(method="first")
        fold = (rank.to_numpy(int) - 1) % kk
        text = (f"{kk}-fold by trial within each session ({len(parts)} participant(s); >= 4 "
                "allow held-out participants)")
    return split_folds(data, fold, kk), text


def split_folds(data: pd.DataFrame, fold: np.ndarray, k: int) -> list:
    """``[(train, test), ...]``: row ``i`` of ``data`` is held out in fold ``fold[i]`` (0 to
    ``k - 1``); each part keeps ``data.attrs``."""
    folds = []
    for f in range(k):
        m = fold == f
        tr, te = data[~m].copy(), data[m].copy()
        tr.attrs, te.attrs = dict(data.attrs), dict(data.attrs)
        folds.append((tr, te))
    return folds
