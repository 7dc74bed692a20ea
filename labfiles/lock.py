"""An exclusive lock on a folder that one run writes into (``flock`` on a lock file).

The kernel releases the lock when the process ends, however it ends (``kill -9`` too), so a
stale lock file never blocks a later run. The file records who holds it, for the message the
next run prints.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
from datetime import UTC, datetime
from pathlib import Path
from typing import Self

from labfiles.records import LabFileError

__all__ = ["FolderLock", "FolderLocked"]


class FolderLocked(LabFileError):
    """Another run holds the lock on the folder."""


class FolderLock:
    """Hold ``folder/name`` with an exclusive, non-blocking ``flock`` (a context manager).

    Parameters
    ----------
    folder : str or Path
        Made if missing.
    name : str
        The lock file's name in the folder.
    what : str
        What the folder is, for the message ("calibration folder", "session P01 s1").

    Raises
    ------
    FolderLocked
        If another process holds it; the message names the holder's pid, host and start time.
    """

    def __init__(self, folder, name: str = ".lock", *, what: str = "folder"):
        self.folder = Path(folder)
        self.path = self.folder / name
        self.what = what
        self.fd: int | None = None

    def __enter__(self) -> Self:
        self.folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = json.loads(os.pread(fd, 4096, 0) or b"{}")
            except ValueError:
                holder = {}
            os.close(fd)
            who = ", ".join(f"{k} {holder[k]}" for k in ("pid", "host", "since") if k in holder)
            raise FolderLocked(
                f"the {self.what} {self.folder} is in use by another run ({who or 'unknown'}; "
                f"lock {self.path}); wait for it to finish or stop it, then run again") from None
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "since": datetime.now(UTC).isoformat(timespec="seconds")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        self.fd = fd
        return self

    def __exit__(self, *exc) -> None:
        if self.fd is not None:
            fd, self.fd = self.fd, None
            os.close(fd)
