"""Session data files: one CSV row per trial, appended and fsynced the moment it exists.

This module owns the session data formats: the column list (``SESSION_COLUMNS``), the file
names, the writer and the readers. ``analysis`` reads sessions through :func:`read_session`.

Files of one participant and session, under the data folder ``DATA_DIR``:

================================================  =================================================
``sessions/<participant>_s<session>.csv``         one row per answered trial (``SESSION_COLUMNS``)
``sliders/<participant>_s<session>.jsonl``        each trial's full slider histories (JSON lines)
``logs/<participant>_s<session>_run<k>.json``     one log per run of the app (a resume is a new run)
``logs/<participant>_s<session>_runs.jsonl``      start and end of every run (append-only)
``logs/<participant>_s<session>_run<k>_frames.*`` frame intervals of that run (CSV and a plot)
================================================  =================================================

Recorded data is never overwritten: rows are only appended (``labfiles.RecordFile``: one
``write`` per row, then ``fsync``), and run logs take the next free run number. Every
append-only file follows ``labfiles``' one torn-tail rule: a last line cut short (a crash, a
full disk) is moved to a side file ``<name>.torn-<UTC>`` when the session is next opened for
writing, and that trial is taken again. Readers that must not write (``status``, the analysis)
read up to the last whole record and warn (:class:`labfiles.TornTailWarning`).

A slider-history line is written before its CSV row (the row is the commit point), so a crash
between the two leaves a history for a trial that is taken again: a reader of the histories
keeps the last line of each trial.
"""

from __future__ import annotations

import csv
import io
import json
import subprocess
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Self

import pandas as pd

from experiment.participants import check_participant_id
from labfiles import (
    LabFileError,
    RecordFile,
    TornTailWarning,
    csv_fields_check,
    csv_record,
    csv_separator,
    decode_text,
    find_torn_tail,
    json_record,
    json_record_check,
    read_records,
    separator_message,
    utf8_records,
    write_new_file,
)

__all__ = [
    "SESSION_COLUMNS",
    "SIMULATED_CALIBRATION_ID",
    "DataFileError",
    "SessionWriter",
    "app_version",
    "append_run_event",
    "read_run_events",
    "read_session",
    "read_slider_histories",
    "runs_path",
    "session_path",
    "simulated_app_version",
    "simulated_rows",
    "sliders_path",
    "unended_runs",
    "write_run_log",
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
_HEADER = csv_record(SESSION_COLUMNS)
#: A whole session row: it parses into exactly the session's columns.
_ROW_CHECK = csv_fields_check(len(SESSION_COLUMNS))


#: The ``calibration_id`` of sessions simulated without the app (``python -m experiment
#: simulate``): no display was involved.
SIMULATED_CALIBRATION_ID = "simulated"
#: ``app_version`` tags of rows answered by a simulated observer: through the app's window
#: (``run --simulate``, the real calibration's id) or without the app (``simulate_dataset``).
_SIMULATED_TAGS = (" simulated:", " simulate_dataset:")


def simulated_app_version(kind: str, *, through_app: bool) -> str:
    """The ``app_version`` of a row answered by a simulated observer of ``kind``: the version,
    then ``simulated:<kind>`` (``run --simulate``) or ``simulate_dataset:<kind>``."""
    return f"{app_version()}{_SIMULATED_TAGS[0 if through_app else 1]}{kind}"


def simulated_rows(frame: pd.DataFrame) -> pd.Series:
    """Which session rows a simulated observer answered (bool, aligned with ``frame``): its
    ``app_version`` says so (:func:`simulated_app_version`) or its ``calibration_id`` is
    ``SIMULATED_CALIBRATION_ID``. Such rows are not a participant's, wherever they are."""
    version = frame["app_version"].fillna("").astype(str)
    tagged = pd.Series(False, index=frame.index)
    for tag in _SIMULATED_TAGS:
        tagged |= version.str.contains(tag, regex=False)
    return tagged | (frame["calibration_id"].fillna("").astype(str) == SIMULATED_CALIBRATION_ID)


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


def runs_path(data_dir, participant: str, session: int) -> Path:
    """``DATA_DIR/logs/<participant>_s<session>_runs.jsonl``: start and end of every run."""
    return Path(data_dir) / "logs" / f"{_name(participant, session)}_runs.jsonl"


def _whole_records(path: Path, check: Callable[[bytes], bool], *, repair: bool) -> bytes:
    """The bytes of ``path`` up to its last whole record (the torn-tail rule; see the module).

    With ``repair`` the torn tail is moved aside (``labfiles.repair_torn_tail``); without, the
    file is not touched and a :class:`~labfiles.TornTailWarning` says what the next run does.
    """
    if repair:
        lines = read_records(path, check=check)
        return "".join(line + "\n" for line in lines).encode("utf-8")
    try:
        data = utf8_records(path.read_bytes(), path, writing=False)
    except FileNotFoundError:
        return b""
    found = find_torn_tail(data, check=check)
    if found is None:
        return data
    offset, reason = found
    line = data.count(b"\n", 0, offset) + 1
    warnings.warn(
        f"{path}: line {line} is torn ({reason}; a crash or a full disk during a write?): read "
        f"up to line {line - 1}; the next run of this session moves the {len(data) - offset} "
        "damaged bytes to a side file and takes that record again", TornTailWarning,
        stacklevel=3)
    return data[:offset]


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


def read_session(path, *, repair: bool = False) -> pd.DataFrame:
    """Read a session CSV written by this app (an absent file reads as no rows).

    The torn-tail rule applies (see the module): a last row cut short is left out, with a
    :class:`labfiles.TornTailWarning`; with ``repair`` it is also moved to a side file (the app
    does so, holding the session's lock, before it appends).

    Parameters
    ----------
    path : str or Path
    repair : bool
        Move a torn last row aside (only the app's run, which holds the session's lock).

    Returns
    -------
    DataFrame
        ``SESSION_COLUMNS``, one row per recorded trial.

    Raises
    ------
    DataFileError
        Wrong header (another separator than commas is named), a row in the middle of the file
        with a wrong number of fields, or not UTF-8/UTF-16 text (a UTF-16 file is read, but
        not with ``repair``): the message names the fix.

    Notes
    -----
    Files other tools re-save read as the app's own (:mod:`labfiles.text`): CRLF line ends, a
    BOM, quoted fields, UTF-16.
    """
    path = Path(path)
    try:
        text = decode_text(_whole_records(path, _ROW_CHECK, repair=repair), path)
    except LabFileError as exc:
        raise DataFileError(str(exc)) from None
    if not text:
        return pd.DataFrame(columns=list(SESSION_COLUMNS))
    # Parsed as RFC 4180 (CRLF line ends, quoted fields: Excel, R, MATLAB re-save it so).
    reader = csv.reader(io.StringIO(text, newline=""))
    header = next(_rows(reader, path), [])
    if header != list(SESSION_COLUMNS):
        _refuse_header(path, header)
    for row in _rows(reader, path):
        if len(row) != len(SESSION_COLUMNS):
            raise DataFileError(
                f"{path}: line {reader.line_num} is not a whole session row "
                f"({len(SESSION_COLUMNS)} fields); the file was edited or damaged. Keep a copy, "
                "then ask the study lead (the trials after it were recorded and are kept)"
            )
    return pd.read_csv(io.StringIO(text), dtype={"participant": str, "stimulus_id": str,
                                                 "calibration_id": str, "app_version": str})


def _rows(reader, path: Path):
    """The rows of a ``csv.reader``, a parse error as a :class:`DataFileError`."""
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise DataFileError(
                f"{path}: line {reader.line_num} is not CSV ({exc}); the file was edited or "
                "damaged. Keep a copy, then ask the study lead") from None
        yield row


def _refuse_header(path: Path, header: list[str]) -> None:
    """Raise the :class:`DataFileError` for a session CSV with another header: its separator
    when it is not a comma, else the columns missing and unexpected."""
    sep = csv_separator(",".join(header))
    if sep != ",":
        raise DataFileError(separator_message(path, sep))
    missing = [c for c in SESSION_COLUMNS if c not in header]
    extra = [c for c in header if c not in SESSION_COLUMNS]
    raise DataFileError(
        f"{path}: wrong columns (missing {missing}, unexpected {extra}, or out of order); "
        f"a session CSV has exactly {list(SESSION_COLUMNS)}. It was not written by this "
        "app: move it aside"
    )


def read_run_events(path, *, repair: bool = False) -> list[dict]:
    """The records of a JSON-lines file such as a ``*_runs.jsonl`` run log (torn-tail rule as
    :func:`read_session`)."""
    path = Path(path)
    raw = _whole_records(path, json_record_check, repair=repair)
    events = []
    for number, line in enumerate(raw.decode("utf-8-sig", errors="replace").splitlines(),
                                  start=1):
        if not line.strip():
            continue
        try:
            events.append(json.loads(line))
        except ValueError:
            raise DataFileError(
                f"{path}: line {number} is not a JSON record; the file was edited or damaged. "
                "Move it aside (keep it) and run again"
            ) from None
    return events


def read_slider_histories(path, *, repair: bool = False) -> list[dict]:
    """The trials of a slider-histories file, the last line of each trial (a trial taken again
    after a crash between its history and its row has two); torn-tail rule as
    :func:`read_session`."""
    by_trial = {}
    for record in read_run_events(path, repair=repair):
        by_trial[int(record["trial"])] = record
    return [by_trial[t] for t in sorted(by_trial)]


def append_run_event(path, event: dict) -> None:
    """Append one event (a JSON line, fsynced) to a ``*_runs.jsonl`` run log."""
    with RecordFile(path, check=json_record_check) as records:
        records.append(json_record(event))


def write_run_log(path, log: dict) -> Path:
    """Write a run's log (JSON) atomically; an existing log is never replaced."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_new_file(path, json.dumps(log, indent=2, default=str))


class SessionWriter:
    """Append-only writer of one session's CSV and slider histories (a context manager).

    Both files are ``labfiles.RecordFile``s: opening applies the torn-tail rule (what it moved
    aside is in :attr:`torn`), and each :meth:`append` writes one complete line with a single
    ``write``; when it returns, the row is in the kernel and survives a crash or ``kill -9``. It
    is then ``fsync``-ed (survives a power cut): at once (``background_fsync=False``) or on a
    worker thread while the app draws the next stimulus (``True``; the fsync of one trial always
    completes before the next trial is appended and before the file is closed, and its errors
    are raised there). A write that fails part-way (a full disk) is cut back to the last whole
    record and raises ``OSError`` (``ENOSPC`` names the file).

    Parameters
    ----------
    data_dir : str or Path
    participant : str
    session : int
    background_fsync : bool
        Run the fsync beside the next stimulus's drawing (the session app does: the fsync of two
        files costs about half a frame, see bench/experiment_frame_cost.py).
    sliders : bool
        Open the slider-histories file too (the app); ``False`` for rows without histories
        (simulated sessions), which then leave no empty histories file.

    Raises
    ------
    labfiles.LabFileError
        The session CSV starts with another header.
    """

    def __init__(self, data_dir, participant: str, session: int, *,
                 background_fsync: bool = False, sliders: bool = True):
        self.path = session_path(data_dir, participant, session)
        self.sliders = sliders_path(data_dir, participant, session)
        self._rows = RecordFile(self.path, header=_HEADER, check=_ROW_CHECK, sync=False)
        self._histories = (RecordFile(self.sliders, check=json_record_check, sync=False)
                           if sliders else None)
        self._background = background_fsync
        self._pool = None
        self._pending = None
        self.torn: list = []

    def __enter__(self) -> Self:
        if self._histories is not None:
            self._histories.__enter__()
        try:
            self._rows.__enter__()
        except BaseException:
            if self._histories is not None:
                self._histories.close()
            raise
        files = (self._rows, self._histories)
        self.torn = [f.torn for f in files if f is not None and f.torn is not None]
        if self._background:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fsync")
        return self

    def __exit__(self, *exc) -> None:
        try:
            self.wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None
            self._rows.close()
            if self._histories is not None:
                self._histories.close()

    def wait(self) -> None:
        """Block until the last row is on the disk (raises the fsync's error, if any)."""
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()

    def _fsync(self) -> None:
        if self._histories is not None:
            self._histories.sync()
        self._rows.sync()

    def append(self, row: dict, sliders: dict | None = None) -> None:
        """Write one trial: its slider histories first, then its CSV row (the commit point).

        Parameters
        ----------
        row : dict
            Every name of ``SESSION_COLUMNS``.
        sliders : dict, optional
            JSON-serialisable histories, e.g. ``{"gloss": [[rating, t_s], ...], "depth": ...}``.
        """
        self._check(row)
        self.wait()
        if sliders is not None:
            if self._histories is None:
                raise ValueError("this SessionWriter was opened with sliders=False")
            record = {"participant": row["participant"], "session": int(row["session"]),
                      "trial": int(row["trial"]), "stimulus_id": row["stimulus_id"], **sliders}
            self._histories.append(json_record(record))
        self._rows.append(csv_record([row[c] for c in SESSION_COLUMNS]))
        if self._pool is not None:
            self._pending = self._pool.submit(self._fsync)
        else:
            self._fsync()

    def extend(self, rows) -> None:
        """Write many trials without slider histories (simulated sessions): each row is one
        ``write`` as in :meth:`append`, and the file is fsynced once at the end.

        Parameters
        ----------
        rows : iterable of dict
            Each with every name of ``SESSION_COLUMNS``.
        """
        self.wait()
        for row in rows:
            self._check(row)
            self._rows.append(csv_record([row[c] for c in SESSION_COLUMNS]))
        self._fsync()

    def _check(self, row: dict) -> None:
        missing = [c for c in SESSION_COLUMNS if c not in row]
        if missing:
            raise ValueError(f"session row lacks {missing}")
        if self._rows.fd is None:
            raise RuntimeError("SessionWriter used outside its `with` block")


def unended_runs(events: list[dict]) -> dict[int, int]:
    """The runs of a run history that started and have no end event (killed, or the PC lost
    power): ``{run: first_trial}``."""
    started = {e.get("run"): e.get("first_trial") for e in events if e.get("event") == "start"}
    for e in events:
        if "trials_this_run" in e:
            started.pop(e.get("run"), None)
    return started
