"""``python -m experiment status``: how far a participant's sessions are, and whether a
session's records disagree (DAMAGED: a session CSV holding fewer trials than its slider
histories, run history or frames files record, rows cut from the middle, a torn tail).
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

from experiment.checks import PreflightError
from experiment.datafile import (
    DataFileError,
    read_run_events,
    read_session,
    read_slider_histories,
    runs_path,
    session_path,
    simulated_rows,
    sliders_path,
)
from experiment.history import check_no_lost_trials, frame_records
from experiment.participants import (
    case_twins,
    check_new_participant,
    check_participant_id,
)
from experiment.plan import plan_path
from labfiles import TornTailWarning

__all__ = ["print_status", "session_gaps"]


def print_status(design, data: Path, participant: str) -> int:
    """Print how far ``participant``'s sessions are in the data folder ``data`` (stdout);
    returns 1 when a session is DAMAGED (:func:`session_gaps`), 2 for a bad id, else 0."""
    try:
        check_participant_id(participant)
        if not plan_path(data, participant).exists():
            check_new_participant(participant, data)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    plan = plan_path(data, participant)
    print(f"{participant}: data {data}; plan {plan if plan.exists() else '(none yet)'}")
    for other, where in case_twins(participant, data).items():
        print(f"  NOTE: {other!r} ({where}) differs only in case: one person recorded twice? "
              "Ask the study lead")
    n = design.sessions.trials_per_session
    damaged = 0
    for session in range(1, design.sessions.n_sessions + 1):
        path = session_path(data, participant, session)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TornTailWarning)
            try:
                rows = read_session(path)
                runs = read_run_events(runs_path(data, participant, session))
                sliders = read_slider_histories(sliders_path(data, participant, session))
                history = runs_path(data, participant, session)
                slider_file = sliders_path(data, participant, session)
                problem = session_gaps(rows, path, {
                    history: runs, slider_file: sliders,
                    **frame_records(data / "logs", path.stem)},
                    runs=history, restore=(slider_file,), total=n)
            except DataFileError as exc:
                problem = str(exc)
            if problem:
                print(f"  session {session}: DAMAGED: {problem}")
                damaged += 1
                continue
        done = len(rows)
        starts = sum(1 for e in runs if e.get("event") == "start")
        last = runs[-1].get("event") if runs else "-"
        state = "complete" if done == n else ("not started" if done == 0 else "to resume")
        print(f"  session {session}: {done}/{n} trials, {state}; {starts} run(s), last event "
              f"{last!r}")
        simulated = int(simulated_rows(rows).sum()) if done else 0
        if simulated:
            print(f"    NOTE: {simulated} of these trials were answered by a simulated observer "
                  "(not the participant); the analysis lists them")
        for w in caught:
            if issubclass(w.category, TornTailWarning):
                print(f"    WARNING: {w.message}")
    return 1 if damaged else 0


def session_gaps(rows, path, records: dict, **named) -> str | None:
    """What is missing from a session CSV: rows cut from the middle (trials not 1..n in
    order), or fewer rows than its slider histories, run history and frames files record;
    else None. ``named``: the run history and files to restore, as
    :func:`experiment.history.check_no_lost_trials` takes them."""
    trials = [int(t) for t in rows["trial"]] if len(rows) else []
    if trials != list(range(1, len(trials) + 1)):
        gaps = sorted(set(range(1, max(trials) + 1)) - set(trials))
        what = (f"trials {gaps[:10]} are missing between the recorded ones (rows cut from the "
                "middle?)" if gaps else "the recorded trials are not 1..n in order")
        return (f"{path}: {what}; put the original file back (keep this copy) before the "
                "session continues")
    try:
        check_no_lost_trials(len(trials), path, records, **named)
    except PreflightError as exc:
        return str(exc)
    return None
