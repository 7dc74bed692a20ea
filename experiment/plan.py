"""Trial plans: per participant, a seeded permutation of all stimuli split into sessions.

The plan is written once, at the participant's first session, and reused for every later session
so that session 2 runs exactly the stimuli session 1 did not.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd

from experiment.participants import check_new_participant, check_participant_id
from labfiles import LabFileError, read_csv_frame, write_new_file
from studydesign import StudyDesign

__all__ = ["PLAN_COLUMNS", "PlanError", "load_or_create_plan", "make_plan", "participant_seed", "plan_path"]

PLAN_COLUMNS = [
    "participant",
    "seed",
    "session",
    "trial",
    "order",
    "stimulus_id",
    "illumination",
    "gloss_level",
    "depth_level",
    "true_gloss_pct",
    "true_depth_cm",
]


class PlanError(ValueError):
    """A plan file is missing, malformed, or does not match the design."""


def participant_seed(participant: str) -> int:
    """A reproducible 63-bit seed derived from the participant id (SHA-256)."""
    digest = hashlib.sha256(check_participant_id(participant).encode("utf-8")).digest()
    return int.from_bytes(digest[:8], "big") >> 1


def make_plan(design: StudyDesign, participant: str, rng: np.random.Generator, *, seed: int) -> pd.DataFrame:
    """Randomise all stimuli for one participant and split them into sessions.

    Parameters
    ----------
    design : StudyDesign
    participant : str
        Participant id (see :func:`experiment.participants.check_participant_id`).
    rng : numpy.random.Generator
        Source of the permutation.
    seed : int
        The seed ``rng`` was made from; recorded in every row.

    Returns
    -------
    DataFrame
        ``PLAN_COLUMNS``; one row per stimulus. ``order`` is the position in the whole
        permutation (1..n_stimuli), ``trial`` the position within its session (1..trials_per_session).
    """
    check_participant_id(participant)
    stimuli = design.stimuli()
    perm = rng.permutation(len(stimuli))
    plan = stimuli.iloc[perm].reset_index(drop=True)
    n = design.sessions.trials_per_session
    plan.insert(0, "order", np.arange(1, len(plan) + 1))
    plan.insert(0, "trial", (np.arange(len(plan)) % n) + 1)
    plan.insert(0, "session", (np.arange(len(plan)) // n) + 1)
    plan.insert(0, "seed", seed)
    plan.insert(0, "participant", participant)
    return plan[PLAN_COLUMNS]


def plan_path(data_dir: str | Path, participant: str) -> Path:
    """Where a participant's plan lives: ``DATA_DIR/plans/<participant>_plan.csv``."""
    return Path(data_dir) / "plans" / f"{check_participant_id(participant)}_plan.csv"


def _validate(plan: pd.DataFrame, design: StudyDesign, participant: str, path: Path) -> pd.DataFrame:
    missing = [c for c in PLAN_COLUMNS if c not in plan.columns]
    if missing:
        raise PlanError(f"plan {path} lacks columns {missing}; it was not written by this app")
    if set(plan["participant"].astype(str)) != {participant}:
        raise PlanError(f"plan {path} belongs to {sorted(set(plan['participant']))}, not {participant!r}")
    expected = set(design.stimuli()["stimulus_id"])
    got = list(plan["stimulus_id"])
    if len(got) != len(expected) or set(got) != expected:
        raise PlanError(
            f"plan {path} does not hold each of the design's {len(expected)} stimuli exactly once; "
            "it was made for another design. Move it aside to make a new plan (data already "
            "collected with it stays valid only with that plan)"
        )
    return plan[PLAN_COLUMNS]


def _read_plan(path: Path) -> pd.DataFrame:
    """A plan CSV as written, or re-saved by another tool (CRLF, a BOM, UTF-16, quotes)."""
    try:
        return read_csv_frame(path)
    except LabFileError as exc:
        raise PlanError(f"plan {exc}") from None


def load_or_create_plan(design: StudyDesign, participant: str, data_dir: str | Path) -> pd.DataFrame:
    """Load the participant's plan, or make and write it (atomically, with the umask's
    permissions) if none exists yet."""
    path = plan_path(data_dir, participant)
    if path.exists():
        return _validate(_read_plan(path), design, participant, path)
    try:
        check_new_participant(participant, data_dir)
    except ValueError as exc:
        raise PlanError(str(exc)) from None
    seed = participant_seed(participant)
    plan = make_plan(design, participant, np.random.default_rng(seed), seed=seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        # Refuses to replace a plan another process wrote meanwhile: a plan is never overwritten.
        write_new_file(path, plan.to_csv(index=False))
    except FileExistsError:
        return _validate(_read_plan(path), design, participant, path)
    return plan
