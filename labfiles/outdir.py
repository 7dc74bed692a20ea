"""Output folders and failed writes, said in one line at a command line's edge.

A command that will write into ``--out`` checks the folder before it starts work
(:func:`prepare_out_dir`): a read-only disk, a folder it may not write, or a ``--out`` that names
an existing file is refused in one line that names the path and what to type instead, rather
than a Python traceback after minutes of fitting. A write that fails later (a full disk, a
folder made read-only meanwhile) is turned into the same kind of line by :func:`write_error_line`.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

from labfiles.records import LabFileError

__all__ = ["OutDirError", "prepare_out_dir", "write_error_line"]

_CANNOT_WRITE = (errno.EROFS, errno.EACCES, errno.EPERM)
_FULL = (errno.ENOSPC, errno.EDQUOT)


class OutDirError(LabFileError):
    """An output folder that cannot be written (the message names the path and the fix)."""


def write_error_line(exc: OSError, *, option: str = "--out", target=None) -> str:
    """One line for a failed write: what could not be written, why, and what to do.

    Parameters
    ----------
    exc : OSError
        The error the write raised.
    option : str
        The command-line option that chose where to write (named in the fix).
    target : path, optional
        What the command was writing, when ``exc`` names no file.
    """
    where = exc.filename or target or "the output"
    why = exc.strerror or str(exc)
    if exc.errno in _CANNOT_WRITE:
        return (f"cannot write {where} ({why}); nothing was written there: give {option} a "
                "place on a writable disk")
    if exc.errno in _FULL:
        return (f"the disk is full: could not write {where}; free space (df -h), then run the "
                "same command again")
    if exc.errno in (errno.EEXIST, errno.ENOTDIR):
        return (f"cannot create {where}: a file is in the way ({why}): give {option} a new "
                "folder name")
    if exc.errno == errno.EISDIR:
        return f"{option} {where} is a folder: pass {option} a file name"
    if exc.errno == errno.ENOENT:
        folder = Path(str(where))
        folder = folder.parent if folder.suffix else folder  # a file's name: its folder
        return (f"{folder}: no such folder: create it first (mkdir -p {folder}) or give "
                f"{option} an existing folder")
    return f"cannot write {where} ({why}); pass {option} another place"


def prepare_out_dir(path, *, option: str = "--out") -> Path:
    """Create the output folder ``path`` (and its parents) and check a file can be written in it.

    Call before any long work, so that a bad ``--out`` costs seconds, not a finished fit.

    Raises
    ------
    OutDirError
        With a one-line message naming ``path`` and the fix (see :func:`write_error_line`).
    """
    if not str(path).strip():
        raise OutDirError(f"{option} is empty: give it a folder name (an empty name would write "
                          "into the current folder)")
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutDirError(f"{option} {path} is a file, not a folder: pass {option} a new folder "
                          "name (the file is left as it is)")
    probe = path / f".write-test-{os.getpid()}"
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        if exc.filename == str(probe):  # name the folder, not the probe
            exc = type(exc)(exc.errno, exc.strerror, str(path))
        raise OutDirError(write_error_line(exc, option=option, target=path)) from None
    return path
