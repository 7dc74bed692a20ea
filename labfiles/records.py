"""Append-only record files (CSV rows, JSON lines), and the one rule for a torn tail.

A record is one line ending in ``"\\n"``, written the moment it exists with a single ``write`` on
an ``O_APPEND`` descriptor, then flushed to the disk (``fsync``). Session CSVs, slider histories,
run logs, photometer readings and render manifests are such files.

A crash, a full disk or a power cut during a write can leave a *torn tail*: bytes after the last
newline, or the NUL bytes some file systems leave at the end of a file after a power cut, or
(for a reader that can check a record) a last line that is not a whole record. The rule is the
same for every append-only file, applied whenever one is opened, to read or to append:

1. detect the torn tail;
2. keep the damaged bytes in a side file beside it, ``<name>.torn-<UTC time>`` (never deleted);
3. truncate the file to its last whole record (fsynced);
4. say so: a :class:`TornTailWarning` naming the file, the line and the side file;
5. continue (the caller measures that reading again, or resumes at that trial).

Nothing whole is ever changed: only the bytes after the last whole record move, and they are kept.
A file that cannot be repaired (a read-only copy) is read up to its last whole record, with the
warning saying it was left as it is.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import os
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Self

from labfiles.atomic import fsync_dir, write_new_file
from labfiles.errors import LabFileError
from labfiles.text import (
    check_comma_separated,
    csv_separator,
    decode_text,
    separator_message,
    text_encoding,
    utf8_records,
)

__all__ = [
    "LabFileError",
    "RecordFile",
    "TornTail",
    "TornTailWarning",
    "append_csv_record",
    "csv_fields_check",
    "csv_record",
    "find_torn_tail",
    "json_record",
    "json_record_check",
    "read_csv_records",
    "read_records",
    "repair_torn_tail",
]


class TornTailWarning(UserWarning):
    """An append-only file had a torn tail; it was moved aside (see :class:`TornTail`)."""


@dataclass(frozen=True)
class TornTail:
    """What was found (and done) at the end of an append-only file.

    Attributes
    ----------
    path : Path
        The record file.
    line : int
        1-based line number of the torn record.
    offset : int
        Byte offset where the torn tail starts (the file's new length), bytes.
    n_bytes : int
        Length of the damaged tail, bytes.
    side_file : Path or None
        Where the damaged bytes were kept; None when the file could not be repaired.
    reason : str
        Why the tail is torn, in words.
    """

    path: Path
    line: int
    offset: int
    n_bytes: int
    side_file: Path | None
    reason: str

    def message(self) -> str:
        """The warning's text: the file, the line, what was done and what follows."""
        if self.side_file is None:
            done = (f"the file is read-only here, so it was left as it is and read up to line "
                    f"{self.line - 1}; copy it somewhere writable to repair it")
        else:
            done = (f"its {self.n_bytes} damaged bytes were moved to {self.side_file} and the "
                    f"file now ends at its last whole record (line {self.line - 1})")
        return (f"{self.path}: line {self.line} is torn ({self.reason}; a crash, a full disk "
                f"or a power cut during a write?): {done}. That record will be taken again.")


#: A check of one line (without its newline): True if it is a whole record.
LineCheck = Callable[[bytes], bool]


def csv_fields_check(n_fields: int) -> LineCheck:
    """A check that a CSV line parses (no open quote) into exactly ``n_fields`` fields."""

    def check(line: bytes) -> bool:
        try:
            rows = list(csv.reader(io.StringIO(line.decode("utf-8")), strict=True))
        except (csv.Error, UnicodeDecodeError):
            return False
        return len(rows) == 1 and len(rows[0]) == n_fields

    return check


def json_record_check(line: bytes) -> bool:
    """True if the line is one whole JSON value."""
    try:
        json.loads(line.decode("utf-8"))
    except (ValueError, UnicodeDecodeError):
        return False
    return True


def find_torn_tail(data: bytes, *, check: LineCheck | None = None) -> tuple[int, str] | None:
    """Where the torn tail of an append-only file's bytes starts, and why; None if whole.

    Parameters
    ----------
    data : bytes
        The whole file.
    check : callable, optional
        Applied to the last newline-terminated line (a header line is the caller's to skip:
        the check is not applied when the file holds a single line).
    """
    end = len(data.rstrip(b"\x00"))
    if end < len(data) and (end == 0 or data[end - 1:end] == b"\n"):
        return end, f"{len(data) - end} NUL bytes at the end"
    cut = data.rfind(b"\n", 0, len(data)) + 1
    if cut < len(data):
        return cut, "no newline at its end"
    if check is not None and len(data) > 0:
        start = data.rfind(b"\n", 0, len(data) - 1) + 1
        if start > 0 and not check(data[start:-1]):
            return start, "not a whole record"
    return None


def _side_file(path: Path) -> Path:
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S%fZ")
    return path.with_name(f"{path.name}.torn-{stamp}")


def repair_torn_tail(path, *, check: LineCheck | None = None,
                     repair: bool = True) -> TornTail | None:
    """Apply the torn-tail rule to ``path`` (see the module's docstring); None if it was whole.

    Parameters
    ----------
    path : str or Path
    check : callable, optional
        A whole-record check for the last line (:func:`csv_fields_check`,
        :func:`json_record_check`).
    repair : bool
        False to detect only (nothing is written).

    Warns
    -----
    TornTailWarning
        When a torn tail was found, with :meth:`TornTail.message`.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    # A reader sees a UTF-16 file's records as UTF-8 (offsets then refer to those bytes); a
    # writer, which appends UTF-8, refuses it.
    data = utf8_records(data, path, writing=repair)
    found = find_torn_tail(data, check=check)
    if found is None:
        return None
    offset, reason = found
    line = data.count(b"\n", 0, offset) + 1
    side = None
    if repair:
        try:
            side = write_new_file(_side_file(path), data[offset:])
            os.truncate(path, offset)
            fd = os.open(path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            fsync_dir(path.parent)
        except PermissionError:
            side = None
        except OSError as exc:
            if exc.errno not in (errno.EROFS, errno.EACCES):
                raise
            side = None
    torn = TornTail(path=path, line=line, offset=offset, n_bytes=len(data) - offset,
                    side_file=side, reason=reason)
    warnings.warn(torn.message(), TornTailWarning, stacklevel=2)
    return torn


def read_records(path, *, check: LineCheck | None = None, repair: bool = True) -> list[str]:
    """The whole records of an append-only file, as lines without their newline.

    The torn-tail rule is applied first (:func:`repair_torn_tail`). An absent file has no records.
    Line ends may be LF or CRLF; a BOM is dropped; a UTF-16 file is read only without ``repair``
    (:mod:`labfiles.text`).

    Raises
    ------
    LabFileError
        Not UTF-8 text (or UTF-16 with ``repair``), with the fix.
    """
    path = Path(path)
    torn = repair_torn_tail(path, check=check, repair=repair)
    try:
        data = utf8_records(path.read_bytes(), path, writing=False)
    except FileNotFoundError:
        return []
    if torn is not None and torn.side_file is None:
        data = data[:torn.offset]
    return decode_text(data, path).splitlines()


def csv_record(values: Iterable) -> str:
    """One CSV line (no line terminator) for a record of values.

    Raises
    ------
    ValueError
        If a value holds a newline or carriage return: a record is one line.
    """
    values = ["" if v is None else v for v in values]
    for v in values:
        if isinstance(v, str) and ("\n" in v or "\r" in v):
            raise ValueError(f"value {v!r} holds a line break; a record is one line "
                             "(escape it, e.g. with repr())")
    buf = io.StringIO()
    csv.writer(buf, lineterminator="").writerow(values)
    return buf.getvalue()


def json_record(obj) -> str:
    """One JSON line (no line terminator) for a record; non-JSON values go through ``str``."""
    return json.dumps(obj, default=str)


class RecordFile:
    """An append-only record file, open for appending (a context manager).

    On entering, the parent folder is made, the torn-tail rule is applied, and the header (for a
    CSV) is written if the file is new or checked if it is not. Each :meth:`append` writes one
    whole line with a single ``write`` and then ``fsync`` (unless ``sync=False``, for callers
    that call :meth:`sync` themselves, e.g. on a worker thread). A write that fails part-way
    (a full disk) is cut back to the last whole record before the error is raised.

    Parameters
    ----------
    path : str or Path
    header : str, optional
        The first line of a CSV (no newline). A file whose first line has other fields is
        refused, untouched (one re-saved with a BOM, CRLF or quoted names is the same; its
        records are then appended with its line end).
    check : callable, optional
        Whole-record check for the torn-tail rule.
    sync : bool
        fsync after every append (default).

    Raises
    ------
    LabFileError
        If an existing file has another header (a ';'- or tab-separated one is named so), or
        is UTF-16 (records are appended as UTF-8).
    OSError
        As the system raises it (a full disk is ``ENOSPC``; the message names the file).
    """

    def __init__(self, path, *, header: str | None = None, check: LineCheck | None = None,
                 sync: bool = True):
        self.path = Path(path)
        self.header = header
        self.check = check
        self.sync_each = sync
        self.fd: int | None = None
        self.torn: TornTail | None = None
        #: The line end appended records get: the existing file's (LF for a new file).
        self.newline = "\n"

    def __enter__(self) -> Self:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # The header before the torn-tail rule: a file in another form is refused untouched.
        self._check_header()
        self.torn = repair_torn_tail(self.path, check=self.check)
        new = not self.path.exists() or self.path.stat().st_size == 0
        self.fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        if new:
            if self.header is not None:
                self._write(self.header + "\n")
            os.fsync(self.fd)
            fsync_dir(self.path.parent)
        return self

    def _check_header(self) -> None:
        """Refuse an existing file whose (whole) first line is another header; take its line
        end for the records appended (CRLF after a re-save by Excel, RFC 4180's). A header that
        differs only by a BOM or by quotes around its names is the same."""
        try:
            with open(self.path, "rb") as fh:
                line = fh.readline()
        except FileNotFoundError:
            return
        if not line.endswith(b"\n") or text_encoding(line) not in ("utf-8", "utf-8-sig"):
            return  # a torn first line, or UTF-16: the torn-tail rule's (it refuses UTF-16)
        self.newline = "\r\n" if line.endswith(b"\r\n") else "\n"
        first = line.decode("utf-8-sig", errors="replace").rstrip("\r\n")
        if self.header is None or _fields(first) == _fields(self.header):
            return
        if csv_separator(first) != ",":
            raise LabFileError(separator_message(self.path, csv_separator(first)))
        raise LabFileError(
            f"{self.path} starts with {first[:200]!r}, not this file's header "
            f"{self.header!r}; it was written by something else. Move it aside or "
            "write to a new folder")

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.fd is not None:
            fd, self.fd = self.fd, None
            os.close(fd)

    def _write(self, text: str) -> None:
        data = text.encode("utf-8")
        before = os.fstat(self.fd).st_size
        try:
            written = os.write(self.fd, data)
            if written != len(data):
                raise OSError(errno.ENOSPC, f"only {written} of {len(data)} bytes written",
                              str(self.path))
        except OSError as exc:
            try:
                os.ftruncate(self.fd, before)
            except OSError:
                pass  # left for the torn-tail rule at the next open
            if exc.errno == errno.ENOSPC:
                raise OSError(errno.ENOSPC, f"the disk is full: could not append to "
                              f"{self.path} (everything before this record is kept); free "
                              "space, then run the same command again", str(self.path)) from exc
            raise

    def append(self, line: str) -> None:
        """Append one record (a line without its newline) and, by default, fsync it."""
        if self.fd is None:
            raise RuntimeError(f"{self.path}: RecordFile used outside its `with` block")
        if "\n" in line or "\r" in line:
            raise ValueError("a record is one line; this one holds a line break")
        self._write(line + self.newline)
        if self.sync_each:
            self.sync()

    def sync(self) -> None:
        """fsync what was appended."""
        if self.fd is not None:
            os.fsync(self.fd)


def _fields(line: str) -> list[str]:
    """A CSV line's fields (quotes removed)."""
    return next(csv.reader([line]), [])


def _csv_header_check(path: Path) -> LineCheck | None:
    try:
        data = utf8_records(path.read_bytes(), path, writing=False)
    except (FileNotFoundError, LabFileError):
        return None
    end = data.find(b"\n")
    if end < 0:
        return None
    header = data[:end].decode("utf-8-sig", errors="replace")
    return csv_fields_check(len(_fields(header.rstrip("\r"))))


def read_csv_records(path, *, repair: bool = True, **read_csv_kw):
    """An append-only CSV as a DataFrame, after the torn-tail rule.

    The whole-record check is the header's field count, so a last row cut short (inside or
    outside quotes) is never read as data, nor merged with a later one.

    Parameters
    ----------
    path : str or Path
    repair : bool
        Move a torn tail aside (the writer's rule); False for readers that must not write, which
        read up to the last whole record and warn.
    **read_csv_kw
        Passed to :func:`pandas.read_csv` (e.g. ``dtype``).

    Raises
    ------
    LabFileError
        Not UTF-8 text (UTF-16 is read without ``repair``), or separated by something other than
        commas (:mod:`labfiles.text`).
    """
    import pandas as pd

    path = Path(path)
    try:
        head = utf8_records(path.read_bytes(), path, writing=False).split(b"\n", 1)[0]
    except FileNotFoundError:
        head = b""
    # Before the torn-tail rule: a ';' file's rows would all look torn.
    check_comma_separated(decode_text(head, path), path)
    torn = repair_torn_tail(path, check=_csv_header_check(path), repair=repair)
    data = utf8_records(path.read_bytes(), path, writing=False)
    if torn is not None and torn.side_file is None:
        data = data[:torn.offset]
    return pd.read_csv(io.StringIO(decode_text(data, path)), **read_csv_kw)


def append_csv_record(path, columns, values) -> None:
    """Append one CSV row to an append-only file (header first if new), fsynced.

    The torn-tail rule is applied first; a file with another header is refused
    (:class:`LabFileError`).
    """
    columns = list(columns)
    with RecordFile(path, header=csv_record(columns),
                    check=csv_fields_check(len(columns))) as rec:
        rec.append(csv_record(values))
