"""What a session's records say happened: how many trials were answered, and when.

A session CSV is the record the analysis reads, but not the only one: each trial's slider
histories (``sliders/``), the run history (``logs/*_runs.jsonl``), each run's log
(``logs/*_run<k>.json``) and its frame intervals (``logs/*_run<k>_frames.csv``, the one record a
killed run leaves besides its rows) say how far the session got. Before a session resumes they are
compared with the CSV, so that a CSV moved aside, replaced by an older copy or cut short never
makes the session start over (a participant would see stimuli twice); their times are compared
with this PC's clock.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import pandas as pd

from calibration import CalibrationError
from experiment.checks import PreflightError
from experiment.datafile import (
    DataFileError,
    read_run_events,
    runs_path,
    session_path,
    unended_runs,
)
from experiment.participants import case_twins
from experiment.runlog import run_logs
from labfiles import TornTailWarning
from labfiles.clock import future_problem

__all__ = ["check_history", "check_no_lost_trials", "check_unended_runs_files", "frame_records",
           "future_record_notes", "no_record_of_inputs", "read_recorded", "recorded_trials",
           "unended_runs"]


def recorded_trials(records: list[dict]) -> int:
    """How many trials a slider-histories file or a run history shows answered.

    A slider history is written just before its trial's row (a crash between them leaves one
    history without its row, and the trial is taken again): the last trial of the histories may
    be unanswered. A run that started at trial ``first_trial`` had ``first_trial - 1`` answered
    before it, and its end event adds ``trials_this_run``.
    """
    n = 0
    first = {}
    for r in records:
        if "gloss_history" in r and isinstance(r.get("trial"), int):
            n = max(n, r["trial"] - 1)
        elif r.get("event") == "start" and isinstance(r.get("first_trial"), int):
            first[r.get("run")] = r["first_trial"]
            n = max(n, r["first_trial"] - 1)
        elif isinstance(r.get("trials_this_run"), int) and r.get("run") in first:
            n = max(n, first[r.get("run")] - 1 + r["trials_this_run"])
    return n


def frame_records(logs, stem: str) -> dict:
    """Each run's frame-interval file ``logs/<stem>_run<k>_frames.csv`` as run events
    ``{path: [start, end]}``: a trial's intervals are appended after its row is written, so the
    trials a file names were answered, even when the run was killed before its end event and
    its log. A file that does not read (another encoding, a torn tail) counts for what reads."""
    from labfiles import LabFileError, read_csv_records

    found = {}
    for path in sorted(Path(logs).glob(f"{stem}_run*_frames.csv")):
        match = re.fullmatch(rf"{re.escape(stem)}_run(\d+)_frames\.csv", path.name)
        if match is None:
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a torn tail is the writer's to move aside
                trials = pd.to_numeric(read_csv_records(path, repair=False)["trial"],
                                       errors="coerce").dropna().astype(int)
        except (OSError, LabFileError, KeyError, ValueError, pd.errors.ParserError):
            continue
        if trials.empty:
            continue
        run = int(match.group(1))
        found[path] = [{"event": "start", "run": run, "first_trial": int(trials.min())},
                       {"run": run, "trials_this_run": int(trials.max() - trials.min() + 1)}]
    return found


def check_no_lost_trials(n_done: int, path: Path, records: dict, *, runs: Path | None = None,
                         restore=(), total: int | None = None) -> None:
    """A session never starts over (nor goes back) while a record of later trials exists.

    Parameters
    ----------
    n_done : int
        Rows of the session CSV ``path``.
    records : dict
        Path -> its records (slider histories, run events, :func:`frame_records`), as read.
    runs : Path, optional
        The run history among ``records``: a run in it with no end is named in the message.
    restore : sequence of Path
        Other files among ``records`` the fix names when they too record fewer trials (the
        slider histories moved aside with the CSV).
    total : int, optional
        The session's trials: a session CSV holding them all is never refused for a missing
        frames file.

    Raises
    ------
    PreflightError
        A record shows more answered trials than ``path`` holds: the file was moved aside,
        replaced by an older copy or cut short. Resuming would show the participant stimuli
        again. Or a run of the history ``runs`` never ended and its frames file is gone
        (:func:`check_unended_runs_files`).
    """
    if not records:
        return
    n, where = max((recorded_trials(recs), str(where)) for where, recs in records.items())
    if n > n_done:
        crashed = ", ".join(f"run {k} started at trial {t}" for k, t in
                            unended_runs(records.get(runs, [])).items())
        if crashed:
            crashed = (f" (the run history {runs}: {crashed} and never ended: killed or "
                       "crashed after showing those trials)")
        back = f"{path.name} back in {path.parent}" + "".join(
            f" and {p.name} in {p.parent}" for p in restore
            if recorded_trials(records.get(p, [])) < n)
        raise PreflightError(
            f"{path} holds {n_done} answered trial(s), but {where} records {n}{crashed}: the "
            "session file was moved aside, replaced by an older copy or cut short, and starting "
            f"from trial {n_done + 1} would show the participant stimuli again. Put the original "
            f"{back} (keep every copy), then run the same command; `python -m experiment "
            "status` shows what is recorded")
    if runs is not None and (total is None or n_done < total):
        check_unended_runs_files(n_done, path, records.get(runs, []), runs, restore)


def check_unended_runs_files(n_done: int, path: Path, events: list[dict], runs: Path,
                             restore=()) -> None:
    """The run history alone refuses a session whose killed run left no other record.

    A run creates its frames file (``<stem>_run<k>_frames.csv``, beside the history) before
    its start event is appended, so a run that started and never ended (killed, crashed, the PC
    lost power) always has one. When it is missing, the files that run wrote were moved aside or
    deleted, with the session CSV, its slider histories, and so how many trials it showed is
    unknown: starting from trial ``n_done + 1`` could show the participant stimuli again.

    Raises
    ------
    PreflightError
        Naming the run, the missing files (the frames file; the session CSV and the files of
        ``restore`` when absent) and the fix: put them back.
    """
    stem = runs.name.removesuffix("_runs.jsonl")
    for run, first in unended_runs(events).items():
        frames = runs.parent / f"{stem}_run{run}_frames.csv"
        if not isinstance(run, int) or not isinstance(first, int) or frames.exists():
            continue
        gone = [frames] + [p for p in (path, *restore) if not Path(p).exists()]
        raise PreflightError(
            f"the run history {runs} records run {run} starting at trial {first} and never "
            f"ending (killed or crashed while it showed trials), but "
            f"{' and '.join(str(p) for p in gone)} {'is' if len(gone) == 1 else 'are'} missing "
            f"(moved aside or deleted): how many trials run {run} showed is unknown, and "
            f"starting from trial {n_done + 1} could show the participant stimuli again. Put "
            "the original files back (keep every copy), then run the same command; `python -m "
            "experiment status` shows what is recorded")


def future_record_notes(rows: pd.DataFrame, events: list, path: Path, runs: Path) -> list[str]:
    """Warnings for a session whose records carry times after this PC's clock.

    A run on a PC whose clock ran ahead (or this PC's clock set back since) stamps trials and
    run events in the future: the session can go on, but its times are not in order; the
    warning names the newest time and the fix (set the clock right).
    """
    from calibration.readings import parse_utc

    found = []
    for where, texts in ((path, rows.get("timestamp_utc", ())),
                         (runs, [e.get("utc") for e in events])):
        times = []
        for text in texts:
            try:
                times.append(parse_utc(text))
            except CalibrationError:
                continue
        problem = future_problem(max(times), f"{where}: newest recorded time") if times else None
        if problem:
            found.append(problem.replace(", then give the true time", "; the session goes on "
                                         "but its times are out of order"))
    return found


def read_recorded(read, path: Path, warned: list, torn: list | None = None):
    """``read(path)`` (a session CSV or run log reader) with a torn tail turned into a
    pre-flight warning (nothing is moved yet: the run does that, holding the lock)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TornTailWarning)
        try:
            records = read(path)
        except DataFileError as exc:
            raise PreflightError(str(exc)) from exc
    found = [str(w.message) for w in caught if issubclass(w.category, TornTailWarning)]
    warned += found
    if torn is not None:
        torn += found
    return records


def check_history(req, session: int, done: pd.DataFrame, records: dict) -> list[str]:
    """A session CSV holding fewer trials than the session's other records (slider histories
    in ``records``, the run history, the run logs, the runs' frame files) is refused
    (:func:`check_no_lost_trials`; ``req``: the session's request); returns warnings: participants differing only in case, times after this PC's clock."""
    path = session_path(req.data_dir, req.participant, session)
    events_path = runs_path(req.data_dir, req.participant, session)
    events = read_recorded(read_run_events, events_path, [], [])
    logs = {Path(req.data_dir) / "logs" / f"{path.stem}_run{k}.json":  # each run's own log
            [{"event": "start", "run": k, "first_trial": log.get("first_trial")},
             {"run": k, "trials_this_run": log.get("trials_this_run")}]
            for k, log in run_logs(req.data_dir, path.stem)}
    frames = frame_records(Path(req.data_dir) / "logs", path.stem)
    check_no_lost_trials(len(done), path, {**records, events_path: events, **logs, **frames},
                         runs=events_path, restore=tuple(records),
                         total=req.design.sessions.trials_per_session)
    twins = [f"participant {req.participant!r} and {other!r} ({where}) differ only in case: if "
             "they are one person, session 2 shows stimuli seen before; ask the study lead "
             "before going on" for other, where in case_twins(req.participant,
                                                               req.data_dir).items()]
    return twins + future_record_notes(done, events, path, events_path)


def no_record_of_inputs(req, path: Path, session: int, notes: list) -> None:
    """A resumed session whose start record is gone (``_runs.jsonl`` deleted or its start line
    torn, the run logs missing): refused, since every image could have been swapped, unless
    the operator vouches for the inputs with --accept-unverified-resume (logged)."""
    msg = (f"{path}: no record of the stimuli and calibration file this session started with "
           f"({runs_path(req.data_dir, req.participant, session)} and the run logs are missing "
           "or torn), so this resume cannot check that the images are the ones its first trials "
           "showed")
    if not req.accept_unverified_resume:
        raise PreflightError(msg + "; restore the missing file from a backup, or, once you have "
                             "checked that --stimuli and --calibration are the ones the session "
                             "started with, add --accept-unverified-resume (recorded in the log)")
    notes.append(msg + " (--accept-unverified-resume given)")
