"""Read and validate the session CSVs of a data folder.

Every session file ``DATA_DIR/sessions/<participant>_s<session>.csv`` is read with the
experiment's own reader (`experiment.read_session`: its columns, its torn-tail rule), checked
against the study design, and converted to physical units through the design
(`analysis.units.matches_to_physical`). Errors (the data cannot be analysed as they are) raise
`SessionDataError` naming the file, the row and the fix; what can be analysed but is worth
knowing becomes a warning that the report shows: an incomplete session, a participant with one
session, a torn last row (left out, the file is not changed), rows a simulated observer answered
(`experiment.simulated_rows`: ``experiment simulate`` or ``experiment run --simulate``) and data
recorded with more than one calibration.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.units import matches_to_physical
from experiment import DataFileError, read_session
from experiment.datafile import SIMULATED_CALIBRATION_ID, simulated_rows
from labfiles import TornTailWarning
from studydesign import StudyDesign

__all__ = ["SessionData", "SessionDataError", "load_sessions"]

_NAME = re.compile(r"^(?P<participant>[A-Za-z0-9_-]{1,32})_s(?P<session>\d+)\.csv$")
_NUMERIC = ("session", "trial", "order", "gloss_level", "depth_level", "true_gloss_pct",
            "true_depth_cm", "gloss_match", "depth_match", "rt_s")


class SessionDataError(ValueError):
    """A session file that cannot be analysed as it is."""


@dataclass(frozen=True)
class SessionData:
    """All valid trials of a data folder.

    Attributes
    ----------
    frame : DataFrame
        The session columns plus ``gloss_match_pct`` (%), ``depth_match_cm`` (cm),
        ``gloss_bin`` and ``depth_bin`` (the design's low/medium/high); one row per trial.
    warnings : tuple of str
        Incomplete sessions, participants without every session, torn rows left out,
        simulated data and data of more than one calibration.
    files : tuple of str
        The files read, sorted.
    calibrations : tuple of (str, tuple of str, int)
        Each ``calibration_id`` in the data with its participants and number of trials.
    """

    frame: pd.DataFrame
    warnings: tuple
    files: tuple
    calibrations: tuple = ()

    @property
    def participants(self) -> list:
        return sorted(self.frame["participant"].unique())


def _session_dir(data_dir: Path) -> Path:
    if (data_dir / "sessions").is_dir():
        return data_dir / "sessions"
    if data_dir.is_dir() and any(data_dir.glob("*_s*.csv")):
        return data_dir
    raise SessionDataError(
        f"no session files in {data_dir}: expected {data_dir}/sessions/<participant>_s<n>.csv "
        "(written by `python -m experiment run`)"
    )


def _read_one(path: Path, design: StudyDesign, stimuli: pd.DataFrame) -> pd.DataFrame:
    m = _NAME.match(path.name)
    if not m:
        raise SessionDataError(
            f"{path}: file name is not <participant>_s<session>.csv; rename it or move it out "
            "of the sessions folder"
        )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TornTailWarning)
        try:
            frame = read_session(path)
        except DataFileError as exc:
            raise SessionDataError(str(exc)) from exc
        except (pd.errors.ParserError, UnicodeDecodeError) as exc:
            raise SessionDataError(f"{path}: not a readable CSV ({exc})") from exc
    torn = [str(w.message) for w in caught if issubclass(w.category, TornTailWarning)]
    frame.attrs["torn"] = torn
    for col in _NUMERIC:
        values = pd.to_numeric(frame[col], errors="coerce")
        bad = values.isna()
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise SessionDataError(
                f"{path}: row {row + 2} has {col} = {frame[col].iloc[row]!r}, not a number; "
                "fix or remove the row"
            )
        frame[col] = values
    if (frame["participant"] != m["participant"]).any() or (
        frame["session"] != int(m["session"])
    ).any():
        raise SessionDataError(
            f"{path}: rows name participant/session "
            f"{sorted(set(zip(frame['participant'], frame['session'].astype(int))))}, but the "
            f"file name says {m['participant']!r} session {int(m['session'])}"
        )
    lo, hi = design.slider.min, design.slider.max
    for col in ("gloss_match", "depth_match"):
        bad = (frame[col] < lo) | (frame[col] > hi)
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise SessionDataError(
                f"{path}: trial {int(frame['trial'].iloc[row])} has {col} = "
                f"{frame[col].iloc[row]}, outside the slider's [{lo}, {hi}]; matches are raw "
                "slider values"
            )
    bad = ~(np.isfinite(frame["rt_s"]) & (frame["rt_s"] > 0))
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise SessionDataError(
            f"{path}: trial {int(frame['trial'].iloc[row])} has rt_s = {frame['rt_s'].iloc[row]}"
            ", not a response time (a positive number of seconds): the file was edited; put "
            "the recorded file back (the run's log in logs/ holds each trial's rt_s)"
        )
    dup = frame["trial"].duplicated(keep=False)
    if dup.any():
        raise SessionDataError(
            f"{path}: trial numbers {sorted(set(frame['trial'][dup].astype(int)))} occur more "
            "than once; each trial is one row"
        )
    known = stimuli.set_index("stimulus_id")
    unknown = sorted(set(frame["stimulus_id"]) - set(known.index))
    if unknown:
        raise SessionDataError(
            f"{path}: stimuli {unknown[:5]} are not in the design "
            f"({design.source}); was the data recorded with another design file?"
        )
    ref = known.loc[frame["stimulus_id"]]
    for col in ("illumination", "gloss_level", "depth_level", "true_gloss_pct", "true_depth_cm"):
        a = frame[col].to_numpy()
        b = ref[col].to_numpy()
        same = (a == b) if col == "illumination" else np.isclose(a.astype(float), b.astype(float))
        if not same.all():
            row = int(np.flatnonzero(~same)[0])
            raise SessionDataError(
                f"{path}: trial {int(frame['trial'].iloc[row])} ({frame['stimulus_id'].iloc[row]}) "
                f"has {col} = {_show(a[row])} but the design says {_show(b[row])}"
            )
    return frame


def _show(value) -> str:
    return repr(value) if isinstance(value, str) else f"{float(value):g}"


def load_sessions(data_dir, design: StudyDesign) -> SessionData:
    """Read, validate and convert every session CSV of a data folder.

    Parameters
    ----------
    data_dir : str or Path
        A folder holding ``sessions/`` (or the sessions folder itself).
    design : StudyDesign

    Returns
    -------
    SessionData

    Raises
    ------
    SessionDataError
        No session files; a file with a bad name, wrong columns, non-numeric values, matches
        outside the slider range, duplicate trials or trial numbers with gaps, a stimulus that is
        not in the design (or whose levels disagree with it), one stimulus shown twice to a
        participant, or a participant's trials copied under another id.
    """
    folder = _session_dir(Path(data_dir))
    files = sorted(folder.glob("*.csv"))
    stimuli = design.stimuli()
    n_trials = design.sessions.trials_per_session
    frames, notes = [], []
    for path in files:
        frame = _read_one(path, design, stimuli)
        notes += [f"{path.name}: torn last row left out (the experiment app refuses it too): "
                     f"{w}" for w in frame.attrs.pop("torn", [])]
        trials = np.sort(frame["trial"].astype(int).to_numpy())
        expected = np.arange(1, trials.size + 1)
        if trials.size == 0:
            notes.append(f"{path.name}: empty session (no trials); left out")
            continue
        if not np.array_equal(trials, expected):
            gaps = sorted(set(range(1, int(trials.max()) + 1)) - set(trials.tolist()))
            raise SessionDataError(
                f"{path}: trials {gaps[:10]} are missing before trial {int(trials.max())}; rows "
                "are appended as trials run, so a gap means a damaged file"
            )
        if trials.size < n_trials:
            notes.append(
                f"{path.name}: incomplete session, {trials.size} of {n_trials} trials "
                f"(the analysis uses the {trials.size} recorded)"
            )
        frames.append(frame)
    if not frames:
        raise SessionDataError(f"no trials in {folder}; nothing to analyse")
    data = pd.concat(frames, ignore_index=True)
    shown_twice = data.duplicated(["participant", "stimulus_id"], keep=False)
    if shown_twice.any():
        who = data.loc[shown_twice, ["participant", "stimulus_id"]].drop_duplicates()
        raise SessionDataError(
            f"stimuli shown twice to one participant: {who.head(5).values.tolist()}; two files "
            "of one participant overlap (a session recorded twice?)"
        )
    _refuse_copies(data)
    for participant, grp in data.groupby("participant"):
        missing = sorted(set(range(1, design.sessions.n_sessions + 1)) - set(grp["session"]))
        if missing:
            notes.append(f"participant {participant}: session(s) {missing} not recorded")
    calibrations, provenance = _provenance(data)
    notes += provenance
    data = matches_to_physical(data, design)
    data["gloss_bin"] = design.gloss_bin(data["true_gloss_pct"].to_numpy())
    data["depth_bin"] = design.depth_bin(data["true_depth_cm"].to_numpy())
    data = data.sort_values(["participant", "session", "trial"], ignore_index=True)
    return SessionData(frame=data, warnings=tuple(notes), files=tuple(str(f) for f in files),
                       calibrations=calibrations)


def _refuse_copies(data: pd.DataFrame) -> None:
    """Refuse a session file copied under another participant id: trials of two participants
    with the same answers, response time and timestamp (to the last digit) are one recording,
    which the models would count as two independent people."""
    key = ["timestamp_utc", "rt_s", "gloss_match", "depth_match"]
    same = data[data.duplicated(key, keep=False)]
    if same.empty:
        return
    pairs = same.groupby(key)["participant"].agg(lambda p: tuple(sorted(set(p))))
    pairs = pairs[pairs.map(len) > 1]
    if pairs.empty:
        return
    who, n = pairs.value_counts().index[0], int(pairs.value_counts().iloc[0])
    raise SessionDataError(
        f"participants {list(who)} share {n} trials with the same answers, response times and "
        "timestamps: one recording copied under another id? Move the copy's file out of the "
        "sessions folder (keep the participant who was really tested) and run again")


def _provenance(data: pd.DataFrame) -> tuple[tuple, list[str]]:
    """Which calibrations the trials were recorded with; warnings for simulated participants,
    a session of more than one calibration, and data of more than one calibration."""
    ids = data["calibration_id"].fillna("").astype(str)
    calibrations = tuple(
        (cid, tuple(sorted(grp["participant"].unique())), len(grp))
        for cid, grp in data.assign(calibration_id=ids).groupby("calibration_id", sort=True))
    notes = []
    simulated = sorted(data.loc[simulated_rows(data), "participant"].unique())
    if simulated:
        notes.append(
            f"simulated data included: participants {simulated} were answered by a simulated "
            f"observer (calibration_id '{SIMULATED_CALIBRATION_ID}' from `python -m experiment "
            "simulate`, or 'simulated:' in app_version from `python -m experiment run "
            "--simulate`), not by a participant; move their files out of the data folder "
            "unless this is a test")
    per_session = data.assign(calibration_id=ids).groupby(["participant", "session"])
    for (participant, session), grp in per_session:
        used = sorted(grp["calibration_id"].unique())
        if len(used) > 1:
            notes.append(f"{participant} session {int(session)}: trials recorded with "
                         f"calibrations {used} (a session resumed with another calibration); "
                         "check which trials to keep")
    if len(calibrations) > 1:
        notes.append("data of more than one calibration: " + "; ".join(
            f"{cid!r}: {', '.join(who)} ({n} trials)" for cid, who, n in calibrations))
    return calibrations, notes
