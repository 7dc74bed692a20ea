"""A run's log: what a session's run recorded besides its rows (``DATA_DIR/logs``).

Each run ``k`` of a session writes, beside its rows:

* ``<stem>_run<k>_frames.csv``: every frame interval, appended after each trial's row (created,
  header only, before the run's start event, so that a run in the history always has one);
* ``<stem>_run<k>.json``: the run's log (versions, inputs, calibration and its age, screen,
  frame-interval statistics, dropped frames, response -> next onset latency, each trial), and
  ``<stem>_run<k>_frames.png``, its frame intervals plotted, written when the run ends.

A run killed before its log (``kill -9``, a power cut) of a session it completed gets a log
recovered from what it left (:func:`recover_run_logs`: its start event, rows and frames file),
marked as such, and the end event it lacked, the next time its command runs.
"""

from __future__ import annotations

import json
import os
import platform
import re
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from experiment.datafile import app_version, append_run_event, write_run_log
from labfiles import RecordFile, atomic_path

__all__ = ["DROP_FACTOR", "FRAMES_HEADER", "FrameLog", "check_refresh", "finish_log",
           "frames_path", "now_utc", "plot_frames", "recover_run_logs", "run_logs",
           "run_numbers_on_disk", "start_log", "stats_ms", "unended_last_run", "versions"]

#: A frame interval longer than this many nominal frames counts as dropped.
DROP_FACTOR = 1.5
#: Header of a run's frame-interval CSV.
FRAMES_HEADER = "trial,interval_s"


def frames_path(logs: Path, stem: str, run: int) -> Path:
    """``logs/<stem>_run<run>_frames.csv``: the run's frame intervals."""
    return Path(logs) / f"{stem}_run{run}_frames.csv"


def run_logs(data_dir, stem: str) -> list[tuple[int, dict]]:
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


def run_numbers_on_disk(logs: Path, stem: str) -> set[int]:
    """The run numbers ``k`` of every file ``logs/<stem>_run<k>...`` (a log, a frames file or
    plot, a torn tail moved aside): a run killed before its log leaves its frames file."""
    found = set()
    for path in logs.glob(f"{stem}_run*"):
        match = re.match(rf"{re.escape(stem)}_run(\d+)(?!\d)", path.name)
        if match:
            found.add(int(match.group(1)))
    return found


def now_utc() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def stats_ms(values) -> dict:
    v = np.asarray(values, dtype=float) * 1000.0
    if v.size == 0:
        return {"n": 0}
    return {"n": int(v.size), "mean_ms": float(v.mean()), "sd_ms": float(v.std(ddof=0)),
            "median_ms": float(np.median(v)), "p95_ms": float(np.percentile(v, 95)),
            "max_ms": float(v.max()), "min_ms": float(v.min())}


def versions() -> dict:
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


def plot_frames(intervals_s, frame_s: float, threshold_s: float, path: Path, title: str):
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


def start_log(prep, data: Path, run: int) -> dict:
    """The run's log as it starts (``prep``: the session's ``Prepared``)."""
    req, cal = prep.request, prep.calibration
    frame_s = 1.0 / cal.refresh_hz
    return {
        "participant": req.participant, "session": prep.session, "run": run,
        "started_utc": now_utc(), "data_file": str(data), "design": req.design.source,
        "manifest": str(prep.stimuli.manifest_path), "calibration": str(req.calibration),
        "calibration_id": cal.calibration_id, "calibration_age_days": cal.age_days(),
        "calibration_warnings": list(cal.warnings), "screen_px": list(prep.screen_px),
        "fullscr": req.fullscr, "fast": req.fast, "warnings": list(prep.warnings),
        "inputs": dict(prep.inputs),
        "first_trial": int(prep.todo["trial"].iloc[0]), "trials_total": len(prep.plan),
        "frame_s_calibrated": frame_s, "dropped_frame_threshold_s": DROP_FACTOR * frame_s,
    }


def check_refresh(win, cal, log: dict, out) -> None:
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


class FrameLog:
    """The run's frame intervals, appended after every trial (``*_run<k>_frames.csv``)."""

    def __init__(self, path: Path):
        self.file = RecordFile(path, header=FRAMES_HEADER, sync=False)
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


def finish_log(log: dict, status: str, win, trials_log: list, hand, logs: Path, stem: str,
                run: int, out) -> Path | None:
    """Complete and write the run's log and frame plot; returns the log's path.

    A failure to write (a full disk) is reported through ``out`` and returns None, so that the
    error that ended the run is the one raised.
    """
    frame_s = log["frame_s_calibrated"]
    log["finished_utc"] = now_utc()
    log["status"] = status
    intervals = list(win.frameIntervals)
    log["frame_intervals"] = stats_ms(intervals)
    log["dropped_frames"] = int(win.nDroppedFrames)
    latencies = [t["response_to_next_onset_s"] for t in trials_log
                 if "response_to_next_onset_s" in t]
    log["response_to_next_onset"] = stats_ms(latencies)
    log["trials_this_run"] = len(trials_log)
    log["trials"] = trials_log
    if hand is not None:
        log["simulated"]["intended"] = {str(k): v for k, v in hand.intended.items()}
        if hand.error is not None:
            log["simulated"]["error"] = repr(hand.error)
    try:
        if intervals:
            plot_frames(intervals, frame_s, DROP_FACTOR * frame_s,
                         logs / f"{stem}_run{run}_frames.png",
                         f"{stem} run {run}: {len(intervals)} frames, "
                         f"{win.nDroppedFrames} dropped")
        return write_run_log(logs / f"{stem}_run{run}.json", log)
    except OSError as exc:
        out(f"warning: the run's log {logs / f'{stem}_run{run}.json'} was not written ({exc})")
        return None


def unended_last_run(events: list[dict], total: int) -> tuple[int, int] | None:
    """``(run, first_trial)`` of the last run of a session's history (of ``total`` trials)
    when it started and has no end event (killed, or the PC lost power), else None."""
    from experiment.datafile import unended_runs

    starts = [e for e in events if e.get("event") == "start" and isinstance(e.get("run"), int)
              and isinstance(e.get("first_trial"), int)]
    if not starts:
        return None
    last = max(starts, key=lambda e: e["run"])
    unended = unended_runs(events)
    if last["run"] not in unended or last["first_trial"] > total:
        return None
    return last["run"], last["first_trial"]


def recover_run_logs(events_path: Path, rows: pd.DataFrame, *, data_file: Path,
                     total: int) -> tuple[Path, bool] | None:
    """Write the log and end event a complete session's last run never wrote.

    The run that answered the session's last trial and was then killed (``kill -9``, a power
    cut, a signal from before :func:`experiment.signals.run_ending`) leaves its rows, its frames
    file and a start event with no end. Its log ``<stem>_run<k>.json`` is written from those
    (status ``complete``, ``recovered`` saying when and from what; versions other than the
    rows' ``app_version`` are not known), and an end event is appended to the run history.
    An existing log is never replaced; the caller holds the session's lock.

    Parameters
    ----------
    events_path : Path
        The session's run history ``logs/<stem>_runs.jsonl``.
    rows : DataFrame
        The session CSV's rows (all ``total`` trials).

    Returns
    -------
    (Path, bool) or None
        The run's log and whether it was written now (False: it existed, only the end event
        was missing); None when nothing was missing.
    """
    from experiment.datafile import read_run_events

    events = read_run_events(events_path)
    last = unended_last_run(events, total)
    if last is None or len(rows) < total:
        return None
    run, first = last
    logs = Path(events_path).parent
    stem = Path(data_file).stem
    mine = rows[rows["trial"].astype(int) >= first]
    log_path = logs / f"{stem}_run{run}.json"
    start = next(e for e in events if e.get("event") == "start" and e.get("run") == run)
    written = not log_path.exists()
    if written:
        write_run_log(log_path, _recovered_log(start, mine, data_file, frames_path(logs, stem,
                                                                                   run), total))
    append_run_event(events_path, {
        "event": "complete", "run": run, "utc": now_utc(), "trials_this_run": len(mine),
        "recovered": "the run ended without its end event; recorded by a later run of its "
                     f"command (pid {os.getpid()})",
        "last_answer_utc": str(mine["timestamp_utc"].iloc[-1]) if len(mine) else None})
    return log_path, written


def _recovered_log(start: dict, mine: pd.DataFrame, data_file: Path, frames: Path,
                   total: int) -> dict:
    """A run log rebuilt from the run's start event, its rows and its frames file."""
    from labfiles import LabFileError, read_csv_records

    try:
        intervals = pd.to_numeric(read_csv_records(frames, repair=False)["interval_s"],
                                  errors="coerce").dropna().to_numpy()
    except (OSError, LabFileError, KeyError, ValueError):
        intervals = np.array([])
    inputs = {k: v for k, v in start.items() if k not in ("event", "run", "utc", "pid",
                                                          "first_trial")}
    trials = [{"trial": int(r["trial"]), "onset_s": float(r["onset_s"]), "rt_s": float(r["rt_s"]),
               "dropped_frames": int(r["dropped_frames"])} for r in mine.to_dict("records")]
    return {
        "participant": str(mine["participant"].iloc[0]), "session": int(mine["session"].iloc[0]),
        "run": start["run"], "status": "complete",
        "recovered": {"utc": now_utc(), "from": [str(data_file), str(frames),
                                                    "the run history's start event"], "why": "the run ended after its last answer "
                      "without writing its log (killed, or the PC lost power); versions, "
                      "screen and refresh rate were not recorded"},
        "started_utc": start.get("utc"), "finished_utc": str(mine["timestamp_utc"].iloc[-1]),
        "data_file": str(data_file), "inputs": inputs,
        "calibration": inputs.get("calibration"),
        "calibration_id": str(mine["calibration_id"].iloc[0]),
        "calibration_age_days": _calibration_age_days(inputs.get("calibration"),
                                                      start.get("utc")),
        "versions": {"app_version": sorted(set(mine["app_version"].astype(str)))},
        "first_trial": start.get("first_trial"), "trials_total": total,
        "trials_this_run": len(trials), "frame_intervals": stats_ms(intervals),
        "frames_file": str(frames),
        "dropped_frames": int(pd.to_numeric(mine["dropped_frames"]).sum()), "trials": trials}


def _calibration_age_days(path, started_utc) -> float | None:
    """The calibration's age when the run started, if its file still reads, else None."""
    from calibration import CalibrationError, load_calibration
    from calibration.readings import parse_utc

    try:
        return load_calibration(path).age_days(parse_utc(started_utc))
    except (CalibrationError, OSError, TypeError, ValueError):
        return None
