"""Reading and checking another lab's rating study for the observer layer.

The trials come from the study's own files as its ``study.toml`` describes them
(:func:`experiment.study.read_study_trials`: a malformed header repaired and the repair said);
the simulation (``--sim``) is the rating observer a pilot was fitted with
(:func:`experiment.rating_observer.load_rating_observers`). :func:`rating_frame` adds the
factor relative to the simulation's middle and the previous response; :func:`rating_folds`
holds out trials within participants (by repeat of a stimulus where stimuli repeat), so that
each held-out trial's stimulus and participant are seen in training.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from analysis.gap.engine import GapError
from analysis.gap.observer.data import split_folds
from analysis.gap.observer.rating.model import RatingBase

__all__ = ["check_rating_sim", "load_rating_sim", "rating_folds", "rating_frame",
           "rating_unit_ids", "read_rating_study"]


def read_rating_study(real, study_path, participants=None):
    """``(study, trials, notes)`` of the study at ``study_path`` whose files lie in ``real``.

    Raises
    ------
    GapError
        A study or file that cannot be read (the message names the fix), or ``real`` other
        than the study's folder.
    """
    from experiment import StudyError, load_study, read_study_trials

    try:
        study = load_study(study_path)
        if Path(real).resolve() != study.folder.resolve():
            raise StudyError(f"--real {real} is not the folder of --study {study.source}; the "
                             "trial files are those study.toml names in its own folder")
        trials, notes = read_study_trials(study, participants)
    except StudyError as exc:
        raise GapError(str(exc)) from exc
    return study, trials, notes


def load_rating_sim(sim) -> tuple[RatingBase, dict]:
    """The simulated rating observer of an observers file, and the file's ``[study]`` table
    (a :class:`RatingBase` is returned with an empty table).

    Raises
    ------
    GapError
        Not a rating study's observers file (the message says how to write one).
    """
    if isinstance(sim, RatingBase):
        return sim, {}
    from experiment import load_rating_observers

    try:
        raw = load_rating_observers(sim)
    except ValueError as exc:
        raise GapError(f"--sim {exc}") from exc
    r = raw["rating"]

    def mean_sd(v):
        return (float(v["mean"]), float(v.get("sd", 0.0))) if isinstance(v, dict) else (
            float(v), 0.0)
    (g, g_sd), (a, a_sd) = mean_sd(r["gain"]), mean_sd(r["offset"])
    return RatingBase(gain=g, offset=a, gain_sd=g_sd, offset_sd=a_sd,
                      noise=float(r["noise"]), lapse_rate=float(r["lapse_rate"]),
                      factor_mid=float(raw["study"]["factor_mid"]),
                      participants=tuple(str(p) for p in raw.get("fit", {}).get(
                          "participants", ())),
                      source=str(sim)), raw["study"]


def check_rating_sim(trials: pd.DataFrame, base: RatingBase, sim_study: dict, study) -> list:
    """Warnings (participants the simulation was fitted to); a GapError where the simulation
    is of another scale or factor."""
    if sim_study and (str(sim_study.get("estimates")) != study.estimates
            or [float(v) for v in sim_study.get("scale", ())] != list(study.scale)
            or float(sim_study.get("step", -1)) != study.step):
        raise GapError(f"--sim {base.source} was fitted to {sim_study.get('estimates')!r} on the "
                       f"scale {sim_study.get('scale')} step {sim_study.get('step')}, the study "
                       f"has {study.estimates!r} on {list(study.scale)} step {study.step}; fit "
                       "the observer to a pilot of this study")
    shared = sorted(set(base.participants) & set(trials["participant"]))
    if shared:
        return [(f"the observer was fitted to participants {list(base.participants)}, of "
                 f"whom {shared} are diagnosed: the diagnosis is then in-sample for them; "
                 "diagnose other participants (--participants)")]
    return []


def rating_frame(trials: pd.DataFrame, base: RatingBase, study, labels_ok: bool) -> pd.DataFrame:
    """The trials with ``x`` (factor - the simulation's middle), ``prev`` (the participant's
    previous response, NaN on their first trial) and ``rep`` (the how-many-th showing of the
    stimulus to the participant, from 0); the scale in ``attrs``."""
    out = trials.copy()
    out["participant"] = out["participant"].astype(str)
    out["stimulus"] = out["stimulus"].astype(str)
    out["x"] = out["factor"].to_numpy(float) - base.factor_mid
    out["prev"] = out.groupby("participant")["response"].shift(1)
    out["rep"] = out.groupby(["participant", "stimulus"]).cumcount()
    lo, hi = study.scale
    out.attrs.update(scale=(lo, hi), step=study.step, mid=0.5 * (lo + hi),
                     labels=tuple(study.labels) if labels_ok else (),
                     base_lapse=base.lapse_rate, estimates=study.estimates)
    return out


def rating_folds(data: pd.DataFrame, k: int = 5) -> tuple[list, str]:
    """Folds by repeat (a stimulus's n-th showing to a participant; at most ``k``) where stimuli
    repeat, else by trial order within participants (``k`` folds)."""
    reps = int(data["rep"].max()) + 1
    if reps >= 2:
        kk = min(reps, k)
        fold = data["rep"].to_numpy(int) % kk
        text = (f"{kk}-fold by repeat: each stimulus's showings to a participant split over "
                f"folds ({data['participant'].nunique()} participants, "
                f"{data['stimulus'].nunique()} stimuli)")
    else:
        kk = k
        rank = data.groupby("participant").cumcount().to_numpy(int)
        fold = rank % kk
        text = f"{kk}-fold by trial within each participant"
    return split_folds(data, fold, kk), text


def rating_unit_ids(test: pd.DataFrame) -> np.ndarray:
    """A held-out trial's name: participant|trial."""
    return (test["participant"].astype(str) + "|"
            + test["trial"].astype(float).map("{:g}".format)).to_numpy()
