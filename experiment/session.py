"""One session at the CRT: pre-flight, the trial loop, data as it happens, resume after a stop.

``run_session`` is what ``python -m experiment run`` calls. In order:

1. pre-flight, before any window (``experiment.checks``): participant id, session number, the
   participant's plan, what this session already recorded (resume), the stimulus manifest
   (every PNG present, SHA-256 unchanged), the calibration (present, recent, the design's CRT),
   the X screen's size;
2. the window (``experiment.display``) with all of the session's textures preloaded;
3. trials from the first unanswered one: stimulus and two sliders; space only once both are set;
   Esc pauses, Esc again quits (nothing is lost); each answer is appended to the session CSV and
   fsynced before the next stimulus is drawn;
4. the run's log: frame intervals, dropped frames, response -> next onset latency, monitor,
   versions (``DATA_DIR/logs``).

A run holds an exclusive lock on its session (``fcntl.flock``, released by the kernel even on
``kill -9``), so two runs never write one file.
"""

from __future__ import annotations

import fcntl
import json
import os
import platform
import sys
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from experiment.checks import (
    PreflightError,
    SessionStimuli,
    check_calibration,
    check_keyboard_libraries,
    check_monitor_profile,
    check_participant,
    check_screen,
    check_session_number,
    check_stimuli,
)
from experiment.datafile import (
    SESSION_COLUMNS,
    DataFileError,
    SessionWriter,
    app_version,
    read_session,
    session_path,
    write_json_new,
)
from experiment.plan import PlanError, load_or_create_plan, participant_seed
from studydesign import StudyDesign

__all__ = ["SessionOutcome", "SessionRequest", "prepare_session", "run_session"]

#: How long the "set both sliders" hint stays up after an early space press (s).
HINT_S = 2.0
#: A frame interval longer than this many nominal frames counts as dropped.
DROP_FACTOR = 1.5


@dataclass(frozen=True)
class SessionRequest:
    """What the operator asked for (validated by :func:`prepare_session`)."""

    design: StudyDesign
    participant: str
    session: int
    manifest: str | None
    calibration: str | None
    data_dir: str = "data"
    max_calibration_age_days: float = 30.0
    simulate: str | None = None
    observer_params: str | None = None
    seed: int | None = None
    fast: bool = False
    fullscr: bool = False
    accept_calibration_mismatch: bool = False
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


@dataclass(frozen=True)
class SessionOutcome:
    """How a run ended: ``status`` is ``complete``, ``quit`` or ``already complete``."""

    status: str
    participant: str
    session: int
    trials_done: int
    trials_total: int
    data_file: str
    log_file: str | None = None


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
    try:
        plan = load_or_create_plan(design, req.participant, req.data_dir)
    except PlanError as exc:
        raise PreflightError(str(exc)) from exc
    rows = plan[plan["session"] == session].sort_values("trial").reset_index(drop=True)
    path = session_path(req.data_dir, req.participant, session)
    try:
        done = read_session(path)
    except DataFileError as exc:
        raise PreflightError(str(exc)) from exc
    _check_done(done, rows, path)
    todo = rows.iloc[len(done):].reset_index(drop=True)
    warnings = []
    for earlier in range(1, session):
        n = len(read_session(session_path(req.data_dir, req.participant, earlier)))
        if n < design.sessions.trials_per_session:
            warnings.append(f"session {earlier} of {req.participant} has {n} of "
                            f"{design.sessions.trials_per_session} trials (not finished)")
    stim = check_stimuli(req.manifest, rows) if len(todo) else None
    cal = check_calibration(req.calibration, design,
                            max_age_days=req.max_calibration_age_days) if len(todo) else None
    if stim is not None:
        other = [c for c in stim.calibration_ids if c != cal.calibration_id]
        if other:
            msg = (f"the stimuli were gamma-corrected for calibration {other}, but this session "
                   f"uses calibration {cal.calibration_id!r}; re-render the stimuli with this "
                   "calibration")
            if not req.accept_calibration_mismatch:
                raise PreflightError(msg + " (or pass --accept-calibration-mismatch, recorded "
                                     "in the session log)")
            warnings.append(msg)
    screen = profile = None
    if len(todo):
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
                    warnings=warnings)


class _SessionLock:
    """``DATA_DIR/logs/<p>_s<n>.lock`` held with ``flock`` for the run's lifetime."""

    def __init__(self, folder: Path, stem: str):
        folder.mkdir(parents=True, exist_ok=True)
        self.path = folder / f"{stem}.lock"
        self.fd = None

    def __enter__(self):
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self.fd)
            self.fd = None
            raise PreflightError(f"another run of this session is active (lock {self.path}); "
                                 "close it first") from None
        return self

    def __exit__(self, *exc):
        if self.fd is not None:
            os.close(self.fd)


def _append_event(path: Path, event: dict) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (json.dumps(event, default=str) + "\n").encode())
        os.fsync(fd)
    finally:
        os.close(fd)


def _run_number(events: Path) -> int:
    if not events.exists():
        return 1
    lines = events.read_text(encoding="utf-8").splitlines()
    return 1 + sum(1 for line in lines if line.strip() and json.loads(line).get("event") == "start")


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
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run_session(req: SessionRequest, *, out=print) -> SessionOutcome:
    """Run (or resume) one session. See the module docstring.

    Raises
    ------
    PreflightError
        A problem found before any window opened (the message says what to fix).
    experiment.display.DisplayError
        The window could not show the session as required (it is closed again).
    """
    prep = prepare_session(req)
    data = session_path(req.data_dir, req.participant, prep.session)
    total = len(prep.plan)
    for w in prep.warnings:
        out(f"warning: {w}")
    if prep.todo.empty:
        out(f"session {prep.session} of {req.participant} is already complete "
            f"({total} trials in {data}); nothing to do")
        return SessionOutcome("already complete", req.participant, prep.session, total, total,
                              str(data))
    logs = Path(req.data_dir) / "logs"
    stem = data.stem
    with _SessionLock(logs, stem):
        if len(read_session(data)) != len(prep.done):
            raise PreflightError(f"{data} changed while this run was starting (another run of "
                                 "the session?); start the session again")
        events = logs / f"{stem}_runs.jsonl"
        run = _run_number(events)
        _append_event(events, {"event": "start", "run": run, "utc": _now(),
                               "first_trial": int(prep.todo["trial"].iloc[0]), "pid": os.getpid()})
        return _run_trials(prep, data, logs, stem, run, events, out)


def _run_trials(prep: Prepared, data: Path, logs: Path, stem: str, run: int, events: Path,
                out) -> SessionOutcome:
    from experiment.display import SessionDisplay

    req, cal = prep.request, prep.calibration
    design = req.design
    stim_frame = prep.stimuli.frame
    todo_ids = set(prep.todo["stimulus_id"])
    stim_frame = stim_frame[stim_frame["stimulus_id"].isin(todo_ids)].reset_index(drop=True)
    frame_s = 1.0 / cal.refresh_hz
    hand = None
    status = "error"
    log: dict = {
        "participant": req.participant, "session": prep.session, "run": run,
        "started_utc": _now(), "data_file": str(data), "design": design.source,
        "manifest": str(prep.stimuli.manifest_path), "calibration": str(req.calibration),
        "calibration_id": cal.calibration_id, "calibration_age_days": cal.age_days(),
        "calibration_warnings": list(cal.warnings), "screen_px": list(prep.screen_px),
        "fullscr": req.fullscr, "fast": req.fast, "warnings": list(prep.warnings),
        "first_trial": int(prep.todo["trial"].iloc[0]), "trials_total": len(prep.plan),
        "frame_s_calibrated": frame_s, "dropped_frame_threshold_s": DROP_FACTOR * frame_s,
    }
    trials_log: list[dict] = []
    frames_csv = logs / f"{stem}_run{run}_frames.csv"
    with SessionDisplay(design, cal, stim_frame, fullscr=req.fullscr, fast=req.fast,
                        monitor_profile=prep.monitor_profile) as disp, \
            SessionWriter(req.data_dir, req.participant, prep.session,
                          background_fsync=True) as writer:
        from psychopy import core

        win = disp.win
        log.update(disp.info)
        out(f"{req.participant} session {prep.session} run {run}: trials "
            f"{log['first_trial']}-{len(prep.plan)}, {disp.info['n_textures']} textures loaded, "
            f"calibration {cal.calibration_id} ({cal.age_days():.1f} days old), gamma: no hardware "
            f"table (stimuli pre-corrected), keyboard {disp.info['keyboard_backend']}")
        log["versions"] = _versions()
        win.refreshThreshold = DROP_FACTOR * frame_s
        if req.simulate is None:
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
        else:
            hand = _start_hand(req, prep, disp, log)
        clock = core.Clock()
        win.recordFrameIntervals = True
        frames_written = 0
        shot = req.screenshot
        last_response_s = None
        try:
            for row in prep.todo.to_dict("records"):
                result = _one_trial(disp, row, clock, hand, shot, out)
                if result is None:
                    status = "quit"
                    _append_event(events, {"event": "operator_quit", "run": run, "utc": _now(),
                                           "at_trial": int(row["trial"])})
                    break
                shot = None if result.get("screenshot") else shot
                response_s = result["onset_s"] + result["rt_s"]
                if last_response_s is not None:
                    trials_log[-1]["response_to_next_onset_s"] = result["onset_s"] - last_response_s
                last_response_s = response_s
                record = {
                    **{c: row[c] for c in ("participant", "session", "trial", "order",
                                           "stimulus_id", "illumination", "gloss_level",
                                           "depth_level", "true_gloss_pct", "true_depth_cm")},
                    "gloss_match": result["gloss"], "depth_match": result["depth"],
                    "rt_s": result["rt_s"], "onset_s": result["onset_s"],
                    "dropped_frames": result["dropped"], "timestamp_utc": _now(),
                    "app_version": app_version(), "calibration_id": cal.calibration_id,
                }
                writer.append({c: record[c] for c in SESSION_COLUMNS},
                              sliders={"onset_s": result["onset_s"],
                                       "gloss_history": result["gloss_history"],
                                       "depth_history": result["depth_history"],
                                       "gloss_trace": result["gloss_trace"],
                                       "depth_trace": result["depth_trace"],
                                       "early_space_s": result["early_space_s"],
                                       "pauses": result["pauses"]})
                trials_log.append({"trial": int(row["trial"]), "onset_s": result["onset_s"],
                                   "rt_s": result["rt_s"], "dropped_frames": result["dropped"]})
                frames_written = _append_frames(frames_csv, win.frameIntervals, frames_written,
                                                int(row["trial"]))
            else:
                status = "complete"
        finally:
            if hand is not None:
                hand.stop()
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
            if intervals:
                _plot_frames(intervals, frame_s, DROP_FACTOR * frame_s,
                             logs / f"{stem}_run{run}_frames.png",
                             f"{stem} run {run}: {len(intervals)} frames, "
                             f"{win.nDroppedFrames} dropped")
            log_path = write_json_new(logs / f"{stem}_run{run}.json", log)
            _append_event(events, {"event": status, "run": run, "utc": _now(),
                                   "trials_this_run": len(trials_log)})
    done = len(prep.done) + len(trials_log)
    return SessionOutcome(status, req.participant, prep.session, done, len(prep.plan), str(data),
                          str(log_path))


def _append_frames(path: Path, intervals, start: int, trial: int) -> int:
    new = intervals[start:]
    if not new:
        return start
    text = "".join(f"{trial},{v:.6f}\n" for v in new)
    header = "" if path.exists() else "trial,interval_s\n"
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (header + text).encode())
        os.fsync(fd)
    finally:
        os.close(fd)
    return start + len(new)


def _start_hand(req: SessionRequest, prep: Prepared, disp, log: dict):
    from experiment.observers import load_observer_params, make_observer
    from experiment.simulate import SimulatedHand

    params = None
    if req.observer_params is not None:
        params = load_observer_params(req.observer_params)[req.simulate]
    base = req.seed if req.seed is not None else participant_seed(req.participant)
    # The observer (its own intercepts and slopes) is the same in every session and run;
    # the trial noise differs per session and run.
    observer = make_observer(req.simulate, req.participant, np.random.default_rng([base, 0]),
                             params, design=req.design)
    run = log["run"]
    hand = SimulatedHand(observer, np.random.default_rng([base, prep.session, run]),
                         lambda: disp.frame_count, fast=req.fast,
                         early_space_probability=req.early_space_probability,
                         quit_at_trial=req.quit_at_trial)
    hand.start()
    log["simulated"] = {"observer": observer.to_dict(), "seed": [base, prep.session, run],
                        "input": "XTEST events into the X display"}
    return hand


def _one_trial(disp, row: dict, clock, hand, screenshot, out) -> dict | None:
    """Show one trial until a valid response (dict) or a confirmed quit (None)."""
    win, kb = disp.win, disp.kb
    sid = row["stimulus_id"]
    pauses: list = []
    early: list = []
    while True:  # a pause restarts the trial
        disp.reset_sliders()
        kb.clearEvents()
        onset: dict = {}

        def at_onset(onset=onset):
            onset["t"] = clock.getTime()
            kb.clock.reset()

        win.callOnFlip(at_onset)
        drop0 = win.nDroppedFrames
        hint_until = -1.0
        traces = {"gloss": [], "depth": []}
        first = True
        took_shot = False
        while True:
            disp.draw_trial(sid, hint=clock.getTime() < hint_until)
            sliders = (disp.gloss_slider, disp.depth_slider)
            if (screenshot and not took_shot and all(s.rating is not None for s in sliders)
                    and not any(s._dragging for s in sliders)):
                win.getMovieFrame(buffer="back")
                win.saveMovieFrames(screenshot)
                took_shot = True
            disp.flip()
            if first:
                first = False
                if hand is not None:
                    hand.trial(row, disp.slider_geometry())
            now = clock.getTime() - onset["t"]
            for name, s in (("gloss", disp.gloss_slider), ("depth", disp.depth_slider)):
                pos = s.markerPos
                if pos is not None and (not traces[name] or traces[name][-1][0] != pos):
                    traces[name].append((float(pos), now))
            if hand is not None and hand.error is not None:
                raise RuntimeError(f"the simulated observer failed: {hand.error!r}")
            keys = kb.getKeys(["space", "escape"], waitRelease=False)
            if any(k.name == "escape" for k in keys):
                t_pause = clock.getTime()
                if _pause(disp):
                    return None
                pauses.append((t_pause - onset["t"], clock.getTime() - onset["t"]))
                break
            if any(k.name == "space" for k in keys):
                key = next(k for k in keys if k.name == "space")
                g, d = disp.gloss_slider.rating, disp.depth_slider.rating
                if g is None or d is None:
                    early.append(float(key.rt))
                    hint_until = clock.getTime() + HINT_S
                    continue
                return {"gloss": float(g), "depth": float(d), "rt_s": float(key.rt),
                        "onset_s": float(onset["t"]),
                        "dropped": int(win.nDroppedFrames - drop0),
                        "gloss_history": [(float(r), float(t)) for r, t in
                                          disp.gloss_slider.getHistory()],
                        "depth_history": [(float(r), float(t)) for r, t in
                                          disp.depth_slider.getHistory()],
                        "gloss_trace": traces["gloss"], "depth_trace": traces["depth"],
                        "early_space_s": early, "pauses": pauses, "screenshot": took_shot}


def _pause(disp) -> bool:
    """The pause screen; True when the operator confirms quitting (Esc again)."""
    kb = disp.kb
    kb.clearEvents()
    while True:
        disp.draw_message("Paused. Your answers so far are saved.\n\nPress Esc again to quit "
                          "(run the same command later to continue where you stopped), "
                          "or space to go on.")
        disp.flip()
        keys = kb.getKeys(["space", "escape"], waitRelease=False)
        if any(k.name == "escape" for k in keys):
            return True
        if any(k.name == "space" for k in keys):
            return False


def main_run(req: SessionRequest) -> int:
    """Run a session for the command line: messages on stderr, exit status.

    Returns 0 (complete or already complete), 2 (a pre-flight or display problem: nothing was
    shown), 3 (quit by the operator; run the same command to resume).
    """
    from experiment.display import DisplayError

    try:
        res = run_session(req)
    except (PreflightError, DisplayError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if res.status == "quit":
        print(f"session {res.session} of {res.participant} paused after {res.trials_done} of "
              f"{res.trials_total} trials (saved in {res.data_file}); run the same command to "
              "continue", file=sys.stderr)
        return 3
    if res.status == "complete":
        print(f"session {res.session} of {res.participant} complete: {res.trials_total} trials "
              f"in {res.data_file}; log {res.log_file}")
    return 0

