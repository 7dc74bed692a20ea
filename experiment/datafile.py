"""Session data files: one CSV row per trial, appended and fsynced the moment it exists.

Files of one participant and session, under the data folder ``DATA_DIR``:

================================================  =================================================
``sessions/<participant>_s<session>.csv``         one row per answered trial (``SESSION_COLUMNS``)
``sliders/<participant>_s<session>.jsonl``        each trial's full slider histories (JSON lines)
``logs/<participant>_s<session>_run<k>.json``     one log per run of the app (a resume is a new run)
``logs/<participant>_s<session>_runs.jsonl``      start and end of every run (append-only)
``logs/<participant>_s<session>_run<k>_frames.*`` frame intervals of that run (CSV and a plot)
================================================  =================================================

Recorded data is never overwritten: rows are only appended (``O_APPEND``, one ``write`` per row,
then ``fsync``), and run logs take the next free run number.
"""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Self

import pandas as pd

from experiment.participants import check_participant_id

__all__ = [
    "SESSION_COLUMNS",
    "DataFileError",
    "SessionWriter",
    "app_version",
    "read_session",
    "session_path",
    "sliders_path",
]

#: Columns of a session CSV, in order. ``gloss_match`` and ``depth_match`` are raw slider
#: positions in the design's [slider.min, slider.max]; ``rt_s`` is from stimulus onset to the
#: response (s); ``onset_s`` the stimulus onset on the session clock (s, at the flip);
#: ``dropped_frames`` the frames dropped while the trial was on screen.
SESSION_COLUMNS = (
    "participant", "session", "trial", "order", "stimulus_id", "illumination", "gloss_level",
    "depth_level", "true_gloss_pct", "true_depth_cm", "gloss_match", "depth_match", "rt_s",
    "onset_s", "dropped_frames", "timestamp_utc", "app_version", "calibration_id",
)


class DataFileError(ValueError):
    """A session data file that the app must not append to as it is."""


def _name(participant: str, session: int) -> str:
    check_participant_id(participant)
    if int(session) != session or session < 1:
        raise ValueError(f"session {session!r} is not a positive integer")
    return f"{participant}_s{int(session)}"


def session_path(data_dir, participant: str, session: int) -> Path:
    """``DATA_DIR/sessions/<participant>_s<session>.csv`` (what `analysis.load` reads)."""
    return Path(data_dir) / "sessions" / f"{_name(participant, session)}.csv"


def sliders_path(data_dir, participant: str, session: int) -> Path:
    """``DATA_DIR/sliders/<participant>_s<session>.jsonl``: slider histories, one line a trial."""
    return Path(data_dir) / "sliders" / f"{_name(participant, session)}.jsonl"


@cache
def app_version() -> str:
    """The installed glossdepth version, plus the git commit when run from a checkout."""
    try:
        version = metadata.version("glossdepth")
    except metadata.PackageNotFoundError:
        version = "unknown"
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=Path(__file__).resolve().parent,
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return f"{version}+g{commit}" if commit else version


def read_session(path) -> pd.DataFrame:
    """Read a session CSV written by this app (an absent file reads as no rows).

    Raises
    ------
    DataFileError
        Wrong header, or a last row cut off mid-write (the file does not end in a newline).
    """
    path = Path(path)
    if not path.exists() or path.stat().st_size == 0:
        return pd.DataFrame(columns=list(SESSION_COLUMNS))
    raw = path.read_bytes()
    if not raw.endswith(b"\n"):
        raise DataFileError(
            f"{path}: the last row is incomplete (the machine lost power while writing?). Copy "
            "the file aside as a backup, delete the partial last line, then run the session again "
            "to resume at that trial"
        )
    frame = pd.read_csv(io.BytesIO(raw), dtype={"participant": str, "stimulus_id": str,
                                                "calibration_id": str, "app_version": str})
    if tuple(frame.columns) != SESSION_COLUMNS:
        raise DataFileError(
            f"{path}: columns {list(frame.columns)} are not a session file's "
            f"{list(SESSION_COLUMNS)}; it was not written by this app. Move it aside"
        )
    return frame


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class SessionWriter:
    """Append-only writer of one session's CSV and slider histories (a context manager).

    Each :meth:`append` writes one complete CSV row with a single ``write`` on an ``O_APPEND``
    file descriptor: when it returns, the row is in the kernel and survives a crash or
    ``kill -9`` of the app. It is then ``fsync``-ed to the disk (survives a power cut): at once
    (``background_fsync=False``) or on a worker thread while the app draws the next stimulus
    (``True``; the fsync of one trial always completes before the next trial is appended and
    before the file is closed, and its errors are raised there). A crash during the ``write``
    itself can at worst leave one partial last line, which :func:`read_session` detects.

    Parameters
    ----------
    data_dir : str or Path
    participant : str
    session : int
    background_fsync : bool
        Run the fsync beside the next stimulus's drawing (the session app does: the fsync of two
        files costs about half a frame, see bench/experiment_frame_cost.py).
    """

    def __init__(self, data_dir, participant: str, session: int, *,
                 background_fsync: bool = False):
        self.path = session_path(data_dir, participant, session)
        self.sliders = sliders_path(data_dir, participant, session)
        self._fd = self._sfd = None
        self._background = background_fsync
        self._pool = None
        self._pending = None

    def __enter__(self) -> Self:
        for p in (self.path, self.sliders):
            p.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists() or self.path.stat().st_size == 0
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        self._sfd = os.open(self.sliders, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        if new:
            self._write(self._fd, _csv_line(SESSION_COLUMNS))
            os.fsync(self._fd)
            _fsync_dir(self.path.parent)
            _fsync_dir(self.sliders.parent)
        if self._background:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fsync")
        return self

    def __exit__(self, *exc) -> None:
        try:
            self.wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None
            for fd in (self._fd, self._sfd):
                if fd is not None:
                    os.close(fd)
            self._fd = self._sfd = None

    def wait(self) -> None:
        """Block until the last row is on the disk (raises the fsync's error, if any)."""
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()

    @staticmethod
    def _write(fd: int, text: str) -> None:
        data = text.encode("utf-8")
        written = os.write(fd, data)
        if written != len(data):
            raise OSError(f"short write ({written} of {len(data)} bytes); is the disk full?")

    def _fsync(self) -> None:
        os.fsync(self._sfd)
        os.fsync(self._fd)

    def append(self, row: dict, sliders: dict | None = None) -> None:
        """Write one trial: its slider histories first, then its CSV row (the commit point).

        Parameters
        ----------
        row : dict
            Every name of ``SESSION_COLUMNS``.
        sliders : dict, optional
            JSON-serialisable histories, e.g. ``{"gloss": [[rating, t_s], ...], "depth": ...}``.
        """
        missing = [c for c in SESSION_COLUMNS if c not in row]
        if missing:
            raise ValueError(f"session row lacks {missing}")
        if self._fd is None:
            raise RuntimeError("SessionWriter used outside its `with` block")
        self.wait()
        if sliders is not None:
            record = {"participant": row["participant"], "session": int(row["session"]),
                      "trial": int(row["trial"]), "stimulus_id": row["stimulus_id"], **sliders}
            self._write(self._sfd, json.dumps(record) + "\n")
        self._write(self._fd, _csv_line([row[c] for c in SESSION_COLUMNS]))
        if self._pool is not None:
            self._pending = self._pool.submit(self._fsync)
        else:
            self._fsync()


def _csv_line(values) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(values)
    return buf.getvalue()


def write_json_new(path, obj) -> Path:
    """Write JSON to ``path`` atomically, refusing to replace an existing file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=2, default=str)
        fh.flush()
        os.fsync(fh.fileno())
    try:
        os.link(tmp, path)
    finally:
        os.unlink(tmp)
    return path
