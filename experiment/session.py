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
import hashlib
import json
import os
import platform
import re
import warnings
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

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
    write_run_log,
)
from experiment.history import check_no_lost_trials, frame_records, future_record_notes
from experiment.participants import case_twins
from experiment.plan import PLAN_COLUMNS, PlanError, load_or_create_plan, participant_seed
from experiment.provenance import calibration_words, check_earlier_sessions
from experiment.signals import SessionSignal, ending_signals, held_signals
from experiment.trial import TrialResult, run_trial
from labfiles import FolderLock, FolderLocked, RecordFile, TornTailWarning, atomic_path
from stimuli import load_manifest
from studydesign import StudyDesign

__all__ = ["SessionOutcome", "SessionRequest", "prepare_session", "run_session"]

#: A frame interval longer than this many nominal frames counts as dropped.
DROP_FACTOR = 1.5
#: Header of a run's frame-interval CSV.
_FRAMES_HEADER = "trial,interval_s"


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


def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def session_inputs(stim: SessionStimuli, calibration_path, cal) -> dict:
    """What a session's data depend on, as checksums: recorded at its first run.

    Returns
    -------
    dict
        ``calibration`` (absolute path), ``calibration_id``, ``calibration_sha256`` (of the
        file), ``calibration_fit`` (its :attr:`calibration.Calibration.display_model`: a later
        session names what changed), ``manifest`` (absolute path) and ``stimuli_sha256``:
        SHA-256 of this session's
        ``stimulus_id:png_sha256`` lines, sorted (so rows the manifest gains later for other
        stimuli do not count, but any change to one of this session's images does).
    """
    cal_file = Path(calibration_path)
    cal_file = cal_file / "calibration.json" if cal_file.is_dir() else cal_file
    lines = sorted(f"{i}:{h}" for i, h in zip(stim.frame["stimulus_id"], stim.frame["png_sha256"]))
    return {"calibration": str(cal_file.resolve()), "calibration_id": cal.calibration_id,
            "calibration_sha256": _sha256(cal_file), "calibration_fit": cal.display_model,
            "manifest": str(Path(stim.manifest_path).resolve()),
            "stimuli_sha256": hashlib.sha256("\n".join(lines).encode()).hexdigest()}


def _check_same_inputs(inputs: dict, done: pd.DataFrame, events: list[dict], path: Path) -> None:
    """A resumed session must use the calibration and stimuli it started with.

    Raises
    ------
    PreflightError
        Another calibration (by id in the recorded rows, or by checksum in the run log) or other
        stimulus images than the first run's; the message names the files to use.
    """
    if done.empty:
        return
    ids = sorted(set(done["calibration_id"].astype(str)) - {inputs["calibration_id"]})
    first = next((e for e in events if e.get("event") == "start" and "calibration_sha256" in e),
                 None)
    if ids:
        used = f" ({first['calibration']})" if first else ""
        raise PreflightError(
            f"{path}: the {len(done)} trials recorded so far used calibration {ids}{used}, this "
            f"run calibration {inputs['calibration_id']!r} ({inputs['calibration']}); a session "
            "is finished with the calibration it started with. Pass that calibration with "
            "--calibration (or start the participant's data anew in another data folder)")
    if first is None:
        return
    if first["calibration_sha256"] != inputs["calibration_sha256"]:
        raise PreflightError(
            f"{path}: this session started with calibration file {first['calibration']} "
            f"(SHA-256 {first['calibration_sha256'][:12]}...), this run has {inputs['calibration']} "
            f"(SHA-256 {inputs['calibration_sha256'][:12]}...), which differs although its id is "
            "the same; pass the first file with --calibration")
    if first["stimuli_sha256"] != inputs["stimuli_sha256"]:
        raise PreflightError(
            f"{path}: this session started with the stimuli of {first['manifest']}; the images "
            f"this run would show ({inputs['manifest']}) are not the same (other checksums, e.g. "
            "re-rendered or another size). Pass the first manifest with --stimuli (restore its "
            "images if they were replaced)")


def _run_logs(data_dir, stem: str) -> list[tuple[int, dict]]:
    """The run logs ``logs/<stem>_run<k>.json`` of a session as ``(k, log)``, by ``k``; a log
    that does not read as JSON is ``{}``."""
    found = []
    for path in (Path(data_dir) / "logs").glob(f"{stem}_run*.json"):
        number = path.stem[len(stem) + 4:]
        if not number.isdigit():
            continue
        try:
            log = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            log = {}
        found.append((int(number), log if isinstance(log, dict) else {}))
    return sorted(found, key=lambda item: item[0])


def _run_numbers_on_disk(logs: Path, stem: str) -> set[int]:
    """The run numbers ``k`` of every file ``logs/<stem>_run<k>...`` (a log, a frames file or
    plot, a torn tail moved aside): a run killed before its log leaves its frames file."""
    found = set()
    for path in logs.glob(f"{stem}_run*"):
        match = re.match(rf"{re.escape(stem)}_run(\d+)(?!\d)", path.name)
        if match:
            found.add(int(match.group(1)))
    return found


def _read_recorded(read, path: Path, warned: list, torn: list | None = None):
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


def _check_history(req: SessionRequest, session: int, done: pd.DataFrame,
                   records: dict) -> list[str]:
    """A session CSV holding fewer trials than the session's other records (slider histories
    in ``records``, the run history, the run logs, the runs' frame files) is refused (:func:`check_no_lost_trials`);
    returns warnings: participants differing only in case, times after this PC's clock."""
    path = session_path(req.data_dir, req.participant, session)
    events_path = runs_path(req.data_dir, req.participant, session)
    events = _read_recorded(read_run_events, events_path, [], [])
    logs = {Path(req.data_dir) / "logs" / f"{path.stem}_run{k}.json":  # each run's own log
            [{"event": "start", "run": k, "first_trial": log.get("first_trial")},
             {"run": k, "trials_this_run": log.get("trials_this_run")}]
            for k, log in _run_logs(req.data_dir, path.stem)}
    frames = frame_records(Path(req.data_dir) / "logs", path.stem)
    check_no_lost_trials(len(done), path, {**records, events_path: events, **logs, **frames},
                         runs=events_path, restore=tuple(records))
    twins = [f"participant {req.participant!r} and {other!r} ({where}) differ only in case: if "
             "they are one person, session 2 shows stimuli seen before; ask the study lead "
             "before going on" for other, where in case_twins(req.participant,
                                                               req.data_dir).items()]
    return twins + future_record_notes(done, events, path, events_path)


def _no_record(req: SessionRequest, path: Path, session: int, notes: list) -> None:
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
    done = _read_recorded(read_session, path, notes, torn)
    slider_file = sliders_path(req.data_dir, req.participant, session)
    sliders = _read_recorded(read_slider_histories, slider_file, notes, torn)
    _check_done(done, rows, path)
    notes += _check_history(req, session, done, {slider_file: sliders})
    todo = rows.iloc[len(done):].reset_index(drop=True)
    for earlier in range(1, session):
        n = len(_read_recorded(read_session, session_path(req.data_dir, req.participant, earlier),
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
        events = _read_recorded(read_run_events, runs_path(req.data_dir, req.participant,
                                                           session), notes, torn)
        if len(done) and not any("stimuli_sha256" in e for e in events):
            # The start events are gone (the file was moved or deleted): each run's own log
            # holds the same inputs.
            events = events + [{"event": "start", **log["inputs"]}
                               for _, log in _run_logs(req.data_dir, path.stem)
                               if "inputs" in log]
            if not any("stimuli_sha256" in e for e in events):
                _no_record(req, path, session, notes)
        _check_same_inputs(inputs, done, events, path)
        check_earlier_sessions(
            load_manifest(stim.manifest_path), plan, session, inputs, data_dir=req.data_dir,
            participant=req.participant, notes=notes,
            run_logs=lambda k: [log for _, log in _run_logs(
                req.data_dir, session_path(req.data_dir, req.participant, k).stem)])
        other = [c for c in stim.calibration_ids if c != cal.calibration_id]
        # The same id in a file of other content is another calibration too (recalibrated
        # under its old id); a manifest from before calibration_sha256 records no file.
        files = sorted(set(stim.frame["calibration_sha256"]) - {"", inputs["calibration_sha256"]})
        if other or files:
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


def _now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _stats_ms(values) -> dict:
    v = np.asarray(values, dtype=float) * 1000.0
    if v.size == 0:
        return {"n": 0}
    return {"n": int(v.size), "mean_ms": float(v.mean()), "sd_ms": float(v.std(ddof=0)),
            "median_ms": float(np.median(v)), "p95_ms": float(np.percentile(v, 95)),
            "max_ms": float(v.max()), "min_ms": float(v.min())}


def _versions() -> dict:
    import psychopy
    import pyglet

    out = {"python": platform.python_version(), "psychopy": psychopy.__version__,
           "pyglet": pyglet.version, "numpy": np.__version__, "pandas": pd.__version__,
           "app_version": app_version(), "platform": platform.platform()}
    try:
        import psychtoolbox

        out["psychtoolbox"] = psychtoolbox.__version__
    except ImportError:
        out["psychtoolbox"] = None
    return out


def _plot_frames(intervals_s, frame_s: float, threshold_s: float, path: Path, title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.5))
    v = np.asarray(intervals_s) * 1000
    ax.plot(v, ".", ms=2, color="k")
    ax.axhline(frame_s * 1000, color="tab:blue", lw=1, label=f"frame {frame_s * 1000:.2f} ms")
    ax.axhline(threshold_s * 1000, color="tab:red", lw=1, ls="--",
               label=f"dropped above {threshold_s * 1000:.2f} ms")
    ax.set_xlabel("frame")
    ax.set_ylabel("interval (ms)")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=100, format="png")
    finally:
        plt.close(fig)




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
    total = len(prep.plan)
    for w in prep.warnings:
        if prep.todo.empty or w not in prep.torn:  # a run reports the torn tails it moves
            out(f"warning: {w}")
    if prep.todo.empty:
        out(f"session {prep.session} of {req.participant} is already complete "
            f"({total} trials in {data}); nothing to do")
        return SessionOutcome("already complete", req.participant, prep.session, total, total,
                              str(data))
    logs = Path(req.data_dir) / "logs"
    try:
        lock = FolderLock(logs, f"{data.stem}.lock",
                          what=f"session {prep.session} of {req.participant} (data folder)")
        lock.__enter__()
    except FolderLocked as exc:
        raise PreflightError(str(exc)) from None
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TornTailWarning)
            events = runs_path(req.data_dir, req.participant, prep.session)
            history = read_run_events(events, repair=True)
            starts = [e for e in history if e.get("event") == "start"]
            # The next free run number: no earlier run's log or frames file is ever written
            # to, even when the run history (``*_runs.jsonl``) was lost.
            run = 1 + max([len(starts), *(e["run"] for e in starts
                                          if isinstance(e.get("run"), int)),
                           *_run_numbers_on_disk(logs, data.stem)])
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
        append_run_event(events, {"event": "start", "run": run, "utc": _now(),
                                  "first_trial": int(prep.todo["trial"].iloc[0]),
                                  "pid": os.getpid(), **prep.inputs})
        return _run_trials(prep, data, logs, run, events, out)
    finally:
        lock.__exit__(None, None, None)


def _start_log(prep: Prepared, data: Path, run: int) -> dict:
    req, cal = prep.request, prep.calibration
    frame_s = 1.0 / cal.refresh_hz
    return {
        "participant": req.participant, "session": prep.session, "run": run,
        "started_utc": _now(), "data_file": str(data), "design": req.design.source,
        "manifest": str(prep.stimuli.manifest_path), "calibration": str(req.calibration),
        "calibration_id": cal.calibration_id, "calibration_age_days": cal.age_days(),
        "calibration_warnings": list(cal.warnings), "screen_px": list(prep.screen_px),
        "fullscr": req.fullscr, "fast": req.fast, "warnings": list(prep.warnings),
        "inputs": dict(prep.inputs),
        "first_trial": int(prep.todo["trial"].iloc[0]), "trials_total": len(prep.plan),
        "frame_s_calibrated": frame_s, "dropped_frame_threshold_s": DROP_FACTOR * frame_s,
    }


def _check_refresh(win, cal, log: dict, out) -> None:
    """Measure the refresh rate; warn (and log) when it is not the calibration's."""
    frame_s = 1.0 / cal.refresh_hz
    measured = win.getActualFrameRate(nIdentical=20, nMaxFrames=240, nWarmUpFrames=20,
                                      threshold=1)
    log["refresh_hz_measured"] = measured
    if measured is None or abs(measured * frame_s - 1) > 0.02:
        got = ("could not be measured (unstable frame intervals: no vsync?)"
               if measured is None else f"measured {measured:.2f} Hz")
        w = (f"refresh rate {got}, the calibration's is {cal.refresh_hz:.2f} Hz; check "
             "the display mode and sync-to-vblank before going on")
        out(f"warning: {w}")
        log["warnings"].append(w)


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
                  dropped_frames=result.dropped_frames, timestamp_utc=_now(),
                  app_version=version, calibration_id=calibration_id)
    return {c: record[c] for c in SESSION_COLUMNS}


class _FrameLog:
    """The run's frame intervals, appended after every trial (``*_run<k>_frames.csv``)."""

    def __init__(self, path: Path):
        self.file = RecordFile(path, header=_FRAMES_HEADER, sync=False)
        self.written = 0

    def __enter__(self):
        self.file.__enter__()
        return self

    def __exit__(self, *exc):
        self.file.close()

    def append(self, intervals, trial: int) -> None:
        new = intervals[self.written:]
        for v in new:
            self.file.append(f"{trial},{v:.6f}")
        if new:
            self.file.sync()
        self.written += len(new)


def _run_trials(prep: Prepared, data: Path, logs: Path, run: int, events: Path,
                out) -> SessionOutcome:
    from experiment.display import SessionDisplay

    req, cal = prep.request, prep.calibration
    stem = data.stem
    stim_frame = prep.stimuli.frame
    stim_frame = stim_frame[stim_frame["stimulus_id"].isin(set(prep.todo["stimulus_id"]))]
    log = _start_log(prep, data, run)
    trials_log: list[dict] = []
    hand = None
    status = "error"
    log_path = None
    ended_by = None
    with SessionDisplay(req.design, cal, stim_frame.reset_index(drop=True), fullscr=req.fullscr,
                        fast=req.fast, monitor_profile=prep.monitor_profile) as disp, \
            SessionWriter(req.data_dir, req.participant, prep.session,
                          background_fsync=True) as writer, \
            _FrameLog(logs / f"{stem}_run{run}_frames.csv") as frames:
        from psychopy import core

        win = disp.win
        log.update(disp.info)
        out(f"{req.participant} session {prep.session} run {run}: trials "
            f"{log['first_trial']}-{len(prep.plan)}, {disp.info['n_textures']} textures loaded, "
            f"calibration {cal.calibration_id} ({cal.age_days():.1f} days old), gamma: no hardware "
            f"table (stimuli pre-corrected), keyboard {disp.info['keyboard_backend']}")
        log["versions"] = _versions()
        win.refreshThreshold = DROP_FACTOR / cal.refresh_hz
        if req.simulate is None:
            _check_refresh(win, cal, log, out)
        else:
            hand = _start_hand(req, prep, disp, log)
        clock = core.Clock()
        win.recordFrameIntervals = True
        shot = req.screenshot
        last_response_s = None
        try:
            for row in prep.todo.to_dict("records"):
                result = run_trial(disp, row, clock, hand, shot)
                if result is None:
                    status = "quit"
                    append_run_event(events, {"event": "operator_quit", "run": run,
                                              "utc": _now(), "at_trial": int(row["trial"])})
                    break
                shot = None if result.screenshot_taken else shot
                if last_response_s is not None:
                    trials_log[-1]["response_to_next_onset_s"] = result.onset_s - last_response_s
                last_response_s = result.onset_s + result.rt_s
                with held_signals():  # the row, the run's count and its frames, or none
                    writer.append(_session_row(row, result, cal.calibration_id, req.simulate),
                                  sliders=result.slider_record())
                    trials_log.append({"trial": int(row["trial"]), "onset_s": result.onset_s,
                                       "rt_s": result.rt_s,
                                       "dropped_frames": result.dropped_frames})
                    frames.append(win.frameIntervals, int(row["trial"]))
            else:
                status = "complete"
        except KeyboardInterrupt as exc:
            status = "interrupted"
            ended_by = exc.name if isinstance(exc, SessionSignal) else "SIGINT"
            log["ended_by"] = ended_by
        finally:
            if hand is not None:
                hand.stop()
            log_path = _finish_log(log, status, win, trials_log, hand, logs, stem, run, out)
            try:
                append_run_event(events, {"event": status, "run": run, "utc": _now(),
                                          "trials_this_run": len(trials_log),
                                          **({"signal": ended_by} if ended_by else {})})
            except OSError as exc:
                # Never hides the error that ended the run (a full disk fails here too).
                out(f"warning: the run's end was not recorded in {events} ({exc})")
    done = len(prep.done) + len(trials_log)
    return SessionOutcome(status, req.participant, prep.session, done, len(prep.plan), str(data),
                          None if log_path is None else str(log_path),
                          ended_by if ended_by != "SIGINT" else None)


def _finish_log(log: dict, status: str, win, trials_log: list, hand, logs: Path, stem: str,
                run: int, out) -> Path | None:
    """Complete and write the run's log and frame plot; returns the log's path.

    A failure to write (a full disk) is reported through ``out`` and returns None, so that the
    error that ended the run is the one raised.
    """
    frame_s = log["frame_s_calibrated"]
    log["finished_utc"] = _now()
    log["status"] = status
    intervals = list(win.frameIntervals)
    log["frame_intervals"] = _stats_ms(intervals)
    log["dropped_frames"] = int(win.nDroppedFrames)
    latencies = [t["response_to_next_onset_s"] for t in trials_log
                 if "response_to_next_onset_s" in t]
    log["response_to_next_onset"] = _stats_ms(latencies)
    log["trials_this_run"] = len(trials_log)
    log["trials"] = trials_log
    if hand is not None:
        log["simulated"]["intended"] = {str(k): v for k, v in hand.intended.items()}
        if hand.error is not None:
            log["simulated"]["error"] = repr(hand.error)
    try:
        if intervals:
            _plot_frames(intervals, frame_s, DROP_FACTOR * frame_s,
                         logs / f"{stem}_run{run}_frames.png",
                         f"{stem} run {run}: {len(intervals)} frames, "
                         f"{win.nDroppedFrames} dropped")
        return write_run_log(logs / f"{stem}_run{run}.json", log)
    except OSError as exc:
        out(f"warning: the run's log {logs / f'{stem}_run{run}.json'} was not written ({exc})")
        return None


def _start_hand(req: SessionRequest, prep: Prepared, disp, log: dict):
    from experiment.simulate import SimulatedHand

    base = req.seed if req.seed is not None else participant_seed(req.participant)
    run = log["run"]
    hand = SimulatedHand(prep.observer, np.random.default_rng([base, prep.session, run]),
                         lambda: disp.frame_count, fast=req.fast,
                         early_space_probability=req.early_space_probability,
                         quit_at_trial=req.quit_at_trial)
    hand.start()
    log["simulated"] = {"observer": prep.observer.to_dict(), "seed": [base, prep.session, run],
                        "input": "XTEST events into the X display"}
    return hand
