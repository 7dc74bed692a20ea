"""One session at the CRT: pre-flight, the trial loop, data as it happens, resume after a stop.

``run_session`` is what ``python -m experiment run`` calls. In order:

1. pre-flight, before any window (``experiment.checks``): participant id, session number, the
   data folder (writable, space left), the participant's plan, what this session already
   recorded (resume; a torn last row is announced), the stimulus manifest (every PNG present,
   SHA-256 unchanged, decodable at the manifest's size), the calibration (present, recent, the
   design's CRT), that a resumed session keeps the calibration and stimuli it started with, the
   simulated observer's parameters, the screenshot's folder, the X screen's size;
2. the window (``experiment.display``) with all of the session's textures preloaded;
3. trials from the first unanswered one (``experiment.trial.run_trial``): stimulus and two sliders; space
   only once both are set; Esc pauses, Esc again quits (nothing is lost); each answer is appended
   to the session CSV and fsynced before the next stimulus is drawn;
4. the run's log: frame intervals, dropped frames, response -> next onset latency, monitor,
   versions (``DATA_DIR/logs``).

A run holds an exclusive lock on its session (``labfiles.FolderLock``, released by the kernel
even on ``kill -9``), so two runs never write one file. Ctrl-C ends the run like a quit (status
``interrupted``): every answered trial is kept and the log is written.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from experiment import signals
from experiment.checks import (
    PreflightError,
    SessionStimuli,
    check_calibration,
    check_data_folder,
    check_keyboard_libraries,
    check_monitor_profile,
    check_participant,
    check_screen,
    check_screenshot,
    check_session_number,
    check_stimuli,
)
from experiment.datafile import (
    SESSION_COLUMNS,
    DataFileError,
    SessionWriter,
    app_version,
    append_run_event,
    read_run_events,
    read_session,
    read_slider_histories,
    runs_path,
    session_path,
    simulated_app_version,
    sliders_path,
)
from experiment.history import check_history, no_record_of_inputs, read_recorded
from experiment.plan import PLAN_COLUMNS, PlanError, load_or_create_plan, participant_seed
from experiment.provenance import (
    calibration_words,
    check_earlier_sessions,
    check_same_inputs,
    session_inputs,
)
from experiment.runlog import (
    DROP_FACTOR,
    FRAMES_HEADER,
    FrameLog,
    check_refresh,
    finish_log,
    frames_path,
    now_utc,
    recover_run_logs,
    run_logs,
    run_numbers_on_disk,
    start_log,
    unended_last_run,
    versions,
)
from experiment.signals import SessionSignal, ending_signals, held_signals, run_ending
from experiment.simulate import start_hand
from experiment.trial import TrialResult, run_trial
from labfiles import FolderLock, FolderLocked, RecordFile, TornTailWarning
from stimuli import load_manifest
from studydesign import StudyDesign

__all__ = ["SessionOutcome", "SessionRequest", "prepare_session", "run_session"]


@dataclass(frozen=True)
class SessionRequest:
    """What the operator asked for (validated by :func:`prepare_session`).

    ``data_dir`` is the lab's data folder; the command line resolves it (``--data`` or the
    ``GLOSSDEPTH_DATA`` environment variable) to an absolute path, never the working directory.
    """

    design: StudyDesign
    participant: str
    session: int
    manifest: str | None
    calibration: str | None
    data_dir: str
    max_calibration_age_days: float = 30.0
    simulate: str | None = None
    observer_params: str | None = None
    seed: int | None = None
    fast: bool = False
    fullscr: bool = False
    accept_calibration_mismatch: bool = False
    accept_unverified_resume: bool = False
    screenshot: str | None = None
    quit_at_trial: int | None = None
    early_space_probability: float = 0.0


@dataclass
class Prepared:
    request: SessionRequest
    session: int
    plan: pd.DataFrame
    done: pd.DataFrame
    todo: pd.DataFrame
    stimuli: SessionStimuli
    calibration: object
    screen_px: tuple
    monitor_profile: Path | None = None
    warnings: list = field(default_factory=list)
    inputs: dict = field(default_factory=dict)
    observer: object = None
    #: The torn tails among ``warnings``: the run moves them aside and says so itself.
    torn: list = field(default_factory=list)


@dataclass(frozen=True)
class SessionOutcome:
    """How a run ended: ``status`` is ``complete``, ``quit``, ``interrupted`` (Ctrl-C, or the
    SIGTERM / SIGHUP named in ``signal``) or ``already complete``."""

    status: str
    participant: str
    session: int
    trials_done: int
    trials_total: int
    data_file: str
    log_file: str | None = None
    #: The signal that ended an ``interrupted`` run other than Ctrl-C (``"SIGTERM"``, ``"SIGHUP"``).
    signal: str | None = None
    #: A signal (``"SIGINT"`` for Ctrl-C) that came after the last answer of a ``complete`` run,
    #: while its log was written: the run finished its records first.
    signal_after_last_answer: str | None = None


def _check_done(done: pd.DataFrame, plan: pd.DataFrame, path: Path) -> None:
    """The rows already recorded must be the plan's first trials, in order."""
    n = len(done)
    if n > len(plan):
        raise PreflightError(f"{path} holds {n} rows, the session has {len(plan)} trials")
    want = plan.iloc[:n]
    got_trials = done["trial"].astype(int).to_numpy()
    if not np.array_equal(got_trials, want["trial"].to_numpy()):
        raise PreflightError(
            f"{path}: recorded trials {got_trials.tolist()[:10]}... are not 1..{n} in order; the "
            "file was edited or damaged. Move it aside (keep it!) and ask the study lead"
        )
    bad = np.flatnonzero(done["stimulus_id"].to_numpy() != want["stimulus_id"].to_numpy())
    if bad.size:
        i = int(bad[0])
        raise PreflightError(
            f"{path}: trial {i + 1} recorded {done['stimulus_id'].iloc[i]} but the participant's "
            f"plan has {want['stimulus_id'].iloc[i]}; the plan file was replaced after this "
            "session started. Restore the original plan file"
        )


def prepare_session(req: SessionRequest) -> Prepared:
    """Every check that needs no window; raises :class:`PreflightError` naming the fix."""
    design = req.design
    check_participant(req.participant)
    session = check_session_number(design, req.session)
    check_data_folder(req.data_dir)
    try:
        plan = load_or_create_plan(design, req.participant, req.data_dir)
    except PlanError as exc:
        raise PreflightError(str(exc)) from exc
    rows = plan[plan["session"] == session].sort_values("trial").reset_index(drop=True)
    path = session_path(req.data_dir, req.participant, session)
    notes: list = []
    torn: list = []
    done = read_recorded(read_session, path, notes, torn)
    slider_file = sliders_path(req.data_dir, req.participant, session)
    sliders = read_recorded(read_slider_histories, slider_file, notes, torn)
    _check_done(done, rows, path)
    notes += check_history(req, session, done, {slider_file: sliders})
    todo = rows.iloc[len(done):].reset_index(drop=True)
    for earlier in range(1, session):
        n = len(read_recorded(read_session, session_path(req.data_dir, req.participant, earlier),
                               notes))
        if n < design.sessions.trials_per_session:
            notes.append(f"session {earlier} of {req.participant} has {n} of "
                         f"{design.sessions.trials_per_session} trials (not finished)")
    screen = profile = stim = cal = observer = None
    inputs: dict = {}
    if len(todo):
        stim = check_stimuli(req.manifest, rows, every_stimulus=plan["stimulus_id"])
        cal = check_calibration(req.calibration, design,
                                max_age_days=req.max_calibration_age_days)
        inputs = session_inputs(stim, req.calibration, cal)
        events = read_recorded(read_run_events, runs_path(req.data_dir, req.participant,
                                                           session), notes, torn)
        if len(done) and not any("stimuli_sha256" in e for e in events):
            # The start events are gone (the file was moved or deleted): each run's own log
            # holds the same inputs.
            events = events + [{"event": "start", **log["inputs"]}
                               for _, log in run_logs(req.data_dir, path.stem)
                               if "inputs" in log]
            if not any("stimuli_sha256" in e for e in events):
                no_record_of_inputs(req, path, session, notes)
        check_same_inputs(inputs, done, events, path)
        check_earlier_sessions(
            load_manifest(stim.manifest_path), plan, session, inputs, data_dir=req.data_dir,
            participant=req.participant, notes=notes,
            run_logs=lambda k: [log for _, log in run_logs(
                req.data_dir, session_path(req.data_dir, req.participant, k).stem)])
        _check_corrected_for(stim, cal, inputs, req, notes)
        observer = _make_observer(req) if req.simulate is not None else None
        shot = check_screenshot(req.screenshot)
        if shot is not None and shot.exists():  # never replaced; the same command still resumes
            notes.append(f"--screenshot {shot} exists (an earlier run's?) and is kept: no "
                         "screenshot is taken; give a new file name for one")
            req = dataclasses.replace(req, screenshot=None)
        from experiment.display import DisplayError, plan_layout

        profile = check_monitor_profile(req.calibration, cal)
        try:
            plan_layout(design, cal, stim.frame)
        except DisplayError as exc:
            raise PreflightError(str(exc)) from exc
        check_keyboard_libraries()
        screen = check_screen(design, fullscr=req.fullscr)
    return Prepared(request=req, session=session, plan=rows, done=done, todo=todo,
                    stimuli=stim, calibration=cal, screen_px=screen, monitor_profile=profile,
                    warnings=notes, inputs=inputs, observer=observer,
                    torn=[w for w in notes if w in torn])


def _check_corrected_for(stim: SessionStimuli, cal, inputs: dict, req: SessionRequest,
                         notes: list) -> None:
    """The stimuli must be gamma-corrected for this session's calibration (its id and file);
    refused, or noted with --accept-calibration-mismatch."""
    other = [c for c in stim.calibration_ids if c != cal.calibration_id]
    # The same id in a file of other content is another calibration too (recalibrated
    # under its old id); a manifest from before calibration_sha256 records no file.
    files = sorted(set(stim.frame["calibration_sha256"]) - {"", inputs["calibration_sha256"]})
    if not (other or files):
        return
    what = (f"calibration {other}" if other else
            f"calibration {cal.calibration_id!r} as in the file of SHA-256 "
            f"{' and '.join(files)} (recalibrated under the same id?)")
    msg = (f"the stimuli were gamma-corrected for {what}, but this session uses "
           f"calibration {cal.calibration_id!r} ({calibration_words(inputs)}); "
           "re-render the stimuli with this calibration")
    if not req.accept_calibration_mismatch:
        raise PreflightError(msg + " (or pass --accept-calibration-mismatch, recorded "
                             "in the session log)")
    notes.append(msg)


def _make_observer(req: SessionRequest):
    """The simulated observer, the same in every session and run of a participant (its own
    intercepts and slopes); the trial noise differs per session and run (:func:`_start_hand`)."""
    from experiment.observers import load_observer_params, make_observer

    try:
        params = (load_observer_params(req.observer_params)[req.simulate]
                  if req.observer_params is not None else None)
        base = req.seed if req.seed is not None else participant_seed(req.participant)
        return make_observer(req.simulate, req.participant, np.random.default_rng([base, 0]),
                             params, design=req.design)
    except (ValueError, TypeError, KeyError) as exc:
        raise PreflightError(
            f"--observer-params {req.observer_params}: {exc}; fix the file (TOML, see "
            "experiment/observers.toml) or leave the option out for the shipped parameters"
        ) from exc


def run_session(req: SessionRequest, *, out=print) -> SessionOutcome:
    """Run (or resume) one session. See the module docstring.

    Raises
    ------
    PreflightError
        A problem found before any window opened (the message says what to fix).
    experiment.display.DisplayError
        The window could not show the session as required (it is closed again).
    OSError
        A write failed (``ENOSPC``: the disk is full; everything recorded before is kept).

    SIGTERM and SIGHUP end the run as Ctrl-C does (:mod:`experiment.signals`).
    """
    with ending_signals():
        return _run_prepared(prepare_session(req), out)


def _run_prepared(prep: Prepared, out) -> SessionOutcome:
    req = prep.request
    data = session_path(req.data_dir, req.participant, prep.session)
    for w in prep.warnings:
        if prep.todo.empty or w not in prep.torn:  # a run reports the torn tails it moves
            out(f"warning: {w}")
    logs = Path(req.data_dir) / "logs"
    events = runs_path(req.data_dir, req.participant, prep.session)
    if prep.todo.empty:
        return _already_complete(prep, data, events, out)
    lock = _lock(logs, data, prep)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TornTailWarning)
            history = read_run_events(events, repair=True)
            starts = [e for e in history if e.get("event") == "start"]
            # The next free run number: no earlier run's log or frames file is ever written
            # to, even when the run history (``*_runs.jsonl``) was lost.
            run = 1 + max([len(starts), *(e["run"] for e in starts
                                          if isinstance(e.get("run"), int)),
                           *run_numbers_on_disk(logs, data.stem)])
            read_slider_histories(sliders_path(req.data_dir, req.participant, prep.session),
                                  repair=True)
            try:
                recorded = read_session(data, repair=True)
            except DataFileError as exc:  # e.g. re-saved as UTF-16: read, but not appended to
                raise PreflightError(str(exc)) from None
            if len(recorded) != len(prep.done):
                raise PreflightError(f"{data} changed while this run was starting (another run "
                                     "of the session?); start the session again")
        for w in caught:
            out(f"warning: {w.message}")
        # The frames file before the start event: a run in the history always has one, so
        # that one missing says the run's files were moved aside (experiment.history).
        with RecordFile(frames_path(logs, data.stem, run), header=FRAMES_HEADER):
            pass
        append_run_event(events, {"event": "start", "run": run, "utc": now_utc(),
                                  "first_trial": int(prep.todo["trial"].iloc[0]),
                                  "pid": os.getpid(), **prep.inputs})
        return _run_trials(prep, data, logs, run, events, out)
    finally:
        lock.__exit__(None, None, None)


def _session_row(row: dict, result: TrialResult, calibration_id: str,
                 simulate: str | None = None) -> dict:
    """The session CSV's row (``SESSION_COLUMNS``) for one plan row and its answer; a simulated
    observer's (``simulate``: its kind) is tagged in ``app_version``, so that the analysis
    never takes it for a participant's."""
    version = (app_version() if simulate is None
               else simulated_app_version(simulate, through_app=True))
    record = {c: row[c] for c in PLAN_COLUMNS if c in SESSION_COLUMNS}
    record.update(gloss_match=result.gloss_match, depth_match=result.depth_match,
                  rt_s=result.rt_s, onset_s=result.onset_s,
                  dropped_frames=result.dropped_frames, timestamp_utc=now_utc(),
                  app_version=version, calibration_id=calibration_id)
    return {c: record[c] for c in SESSION_COLUMNS}


def _lock(logs: Path, data: Path, prep: Prepared) -> FolderLock:
    """The session's lock, held (the caller releases it)."""
    try:
        lock = FolderLock(logs, f"{data.stem}.lock",
                          what=f"session {prep.session} of {prep.request.participant} (data "
                          "folder)")
        lock.__enter__()
    except FolderLocked as exc:
        raise PreflightError(str(exc)) from None
    return lock


def _already_complete(prep: Prepared, data: Path, events: Path, out) -> SessionOutcome:
    """A complete session: nothing to run; the log and end event its last run never wrote
    (killed after its last answer) are written from its records
    (:func:`experiment.runlog.recover_run_logs`)."""
    req, total = prep.request, len(prep.plan)
    recovered = None
    if unended_last_run(read_recorded(read_run_events, events, []), total) is not None:
        lock = _lock(events.parent, data, prep)
        try:
            recovered = recover_run_logs(events, prep.done, data_file=data, total=total)
        finally:
            lock.__exit__(None, None, None)
    if recovered is not None:
        log, written = recovered
        what = (f"its log {log} (marked 'recovered': versions and screen were not recorded) "
                "and its end event" if written else f"its end event (its log {log} exists)")
        out(f"warning: the run that answered the last trial ended without recording its end "
            f"(killed, or the PC lost power); {what} written now in {events.parent}")
    out(f"session {prep.session} of {req.participant} is already complete "
        f"({total} trials in {data}); nothing to do")
    return SessionOutcome("already complete", req.participant, prep.session, total, total,
                          str(data), None if recovered is None else str(recovered[0]))


def _run_trials(prep: Prepared, data: Path, logs: Path, run: int, events: Path,
                out) -> SessionOutcome:
    from experiment.display import SessionDisplay

    req, cal = prep.request, prep.calibration
    stem = data.stem
    stim_frame = prep.stimuli.frame
    stim_frame = stim_frame[stim_frame["stimulus_id"].isin(set(prep.todo["stimulus_id"]))]
    log = start_log(prep, data, run)
    trials_log: list[dict] = []
    hand = None
    status = "error"
    log_path = ended_by = after_last = None
    with SessionDisplay(req.design, cal, stim_frame.reset_index(drop=True), fullscr=req.fullscr,
                        fast=req.fast, monitor_profile=prep.monitor_profile) as disp, \
            SessionWriter(req.data_dir, req.participant, prep.session,
                          background_fsync=True) as writer, \
            FrameLog(frames_path(logs, stem, run)) as frames:
        win = disp.win
        log.update(disp.info)
        out(f"{req.participant} session {prep.session} run {run}: trials "
            f"{log['first_trial']}-{len(prep.plan)}, {disp.info['n_textures']} textures loaded, "
            f"calibration {cal.calibration_id} ({cal.age_days():.1f} days old), gamma: no hardware "
            f"table (stimuli pre-corrected), keyboard {disp.info['keyboard_backend']}")
        log["versions"] = versions()
        win.refreshThreshold = DROP_FACTOR / cal.refresh_hz
        if req.simulate is None:
            check_refresh(win, cal, log, out)
        else:
            hand = start_hand(req, prep, disp, log)
        try:
            with signals.unwrapped_signals():  # a signal inside a ctypes call comes wrapped
                status = _answer_trials(prep, disp, hand, writer, frames, trials_log, events, run)
        except KeyboardInterrupt as exc:
            name = exc.name if isinstance(exc, SessionSignal) else "SIGINT"
            if len(trials_log) == len(prep.todo):  # after the last answer: complete all the same
                status, after_last = "complete", name
                log["signal_after_last_answer"] = name
            else:
                status, ended_by = "interrupted", name
                log["ended_by"] = ended_by
        finally:
            late = run_ending()  # the log, the end event and the window's closing are finished
            if hand is not None:
                hand.stop()
            log_path = finish_log(log, status, win, trials_log, hand, logs, stem, run, out)
            try:
                append_run_event(events, {"event": status, "run": run, "utc": now_utc(),
                                          "trials_this_run": len(trials_log),
                                          **({"signal": ended_by} if ended_by else {}),
                                          **({"signal_after_last_answer": after_last}
                                             if after_last else {})})
            except OSError as exc:
                # Never hides the error that ended the run (a full disk fails here too).
                out(f"warning: the run's end was not recorded in {events} ({exc})")
    if status == "complete" and after_last is None and late:
        after_last = signal.Signals(late[0]).name
    done = len(prep.done) + len(trials_log)
    return SessionOutcome(status, req.participant, prep.session, done, len(prep.plan), str(data),
                          None if log_path is None else str(log_path),
                          ended_by if ended_by != "SIGINT" else None, after_last)


def _answer_trials(prep: Prepared, disp, hand, writer, frames, trials_log: list, events: Path,
                   run: int) -> str:
    """Show the session's remaining trials, committing each answer (its row, slider histories,
    the run's count and frame intervals) whole; returns ``"complete"`` or ``"quit"``."""
    from psychopy import core

    req, cal, win = prep.request, prep.calibration, disp.win
    clock = core.Clock()
    win.recordFrameIntervals = True
    shot = req.screenshot
    last_response_s = None
    for row in prep.todo.to_dict("records"):
        result = run_trial(disp, row, clock, hand, shot)
        if result is None:
            append_run_event(events, {"event": "operator_quit", "run": run, "utc": now_utc(),
                                      "at_trial": int(row["trial"])})
            return "quit"
        shot = None if result.screenshot_taken else shot
        if last_response_s is not None:
            trials_log[-1]["response_to_next_onset_s"] = result.onset_s - last_response_s
        last_response_s = result.onset_s + result.rt_s
        with held_signals():  # the row, the run's count and its frames, or none
            writer.append(_session_row(row, result, cal.calibration_id, req.simulate),
                          sliders=result.slider_record())
            trials_log.append({"trial": int(row["trial"]), "onset_s": result.onset_s,
                               "rt_s": result.rt_s, "dropped_frames": result.dropped_frames})
            frames.append(win.frameIntervals, int(row["trial"]))
    return "complete"
