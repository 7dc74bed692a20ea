"""Atomic file writes: a temporary file beside the target, fsync, then ``os.replace``.

Every whole file the project writes (calibrations, reports, plans, EXR and PNG images, tables,
meshes) goes through here, so a reader never finds a half-written file under a target's name: an
interrupted write (Ctrl-C, kill, full disk) leaves at most a hidden ``.<stem>.tmp-<pid>-<hex>
<suffix>`` file beside it (:data:`TEMPORARY_GLOB`), which the writer removes when it can.

Files get the permissions any program's new file gets, ``0o666`` less the process umask, so a file
the lab shares is readable by the lab's other accounts (``tempfile.mkstemp`` would give ``0o600``).

Written by hand: the standard library has no replace-with-fsync helper, and the pattern is a few
lines.
"""

from __future__ import annotations

import errno
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

__all__ = [
    "TEMPORARY_GLOB",
    "atomic_open",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "fsync_dir",
    "keep_owner_access",
    "new_file_mode",
    "temporary_path",
    "write_new_file",
]

#: Glob matching the temporary files left by an interrupted write.
TEMPORARY_GLOB = ".*.tmp-*"


def new_file_mode() -> int:
    """The mode a new file gets under the current umask (``0o666 & ~umask``).

    Read from ``/proc/self/status`` where it exists (no change to the process state); elsewhere
    by setting and restoring the umask.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def keep_owner_access() -> int | None:
    """Clear the owner's bits from a umask that denies the owner reading or writing new files.

    With ``umask 0477`` (or 0277) every record would be written unreadable (or unwritable) by
    the account that wrote it: a session could not resume, a calibration folder not be refitted.
    Such a umask is changed for this process (only the owner's bits), with a warning naming the
    fix. Called once when :mod:`labfiles` is imported.

    Returns
    -------
    int or None
        The umask found, when it was changed; else None.
    """
    mask = os.umask(0o022)
    os.umask(mask)
    if not mask & 0o600:
        return None
    os.umask(mask & ~0o700)
    import warnings

    warnings.warn(f"the umask {mask:04o} denies you reading or writing the files you write; this "
                  f"program uses {mask & ~0o700:04o} instead. Set `umask 022` (or 002 for files "
                  "the lab's group shares) in the account's shell profile", stacklevel=2)
    return mask


def temporary_path(path: str | os.PathLike) -> Path:
    """A fresh temporary name for a write to ``path`` (hidden, same folder, same suffix)."""
    path = Path(path)
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}-{secrets.token_hex(3)}{path.suffix}")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(folder: str | os.PathLike) -> None:
    """fsync a folder, so that a file created or renamed in it survives a power cut."""
    _fsync(Path(folder))


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write; on success fsync it and move it onto ``path``.

    For writers that take a file name (OpenEXR, numpy's savez, matplotlib's savefig). If the block
    raises, the temporary file is removed and ``path`` is left as it was.
    """
    path = Path(path)
    tmp = temporary_path(path)
    try:
        yield tmp
        os.chmod(tmp, new_file_mode())
        _fsync(tmp)
        os.replace(tmp, path)
        fsync_dir(path.parent)  # the rename itself survives a power cut
    except OSError as exc:
        raise _about_target(exc, tmp, path) from None
    finally:
        _remove(tmp)


@contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb", **open_kw) -> Iterator[IO]:
    """Open a temporary file for writing; on success flush, fsync and move it onto ``path``.

    ``mode`` and ``open_kw`` go to :func:`open` (e.g. ``"w", newline="", encoding="utf-8"``).
    """
    with atomic_path(path) as tmp, open(tmp, mode, **open_kw) as fh:
        yield fh
        fh.flush()


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically; returns ``path``."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def write_new_file(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write a file that must not exist yet, atomically (a hard link refuses to replace).

    Raises
    ------
    FileExistsError
        If ``path`` exists: a record is never overwritten.
    """
    path = Path(path)
    if isinstance(data, str):
        data = data.encode("utf-8")
    tmp = temporary_path(path)
    try:
        tmp.write_bytes(data)
        os.chmod(tmp, new_file_mode())
        _fsync(tmp)
        try:
            os.link(tmp, path)
        except FileExistsError:
            raise FileExistsError(errno.EEXIST, f"{path} exists already and is never "
                                  "overwritten; choose another name", str(path)) from None
        fsync_dir(path.parent)
    except OSError as exc:
        raise _about_target(exc, tmp, path) from None
    finally:
        _remove(tmp)
    return path


def _remove(tmp: Path) -> None:
    """Remove a temporary file if it is there; a failure here must not hide the write's own
    error (on a read-only disk the unlink fails too)."""
    try:
        tmp.unlink()
    except OSError:
        pass


def _about_target(exc: OSError, tmp: Path, path: Path) -> OSError:
    """The error of a write to the temporary file (or a write that names no file: a full disk),
    told about the file the user asked for."""
    if exc.filename not in (str(tmp), tmp, None):
        return exc
    return type(exc)(exc.errno, exc.strerror, str(path))
