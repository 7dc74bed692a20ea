"""Atomic file writes: a temporary file beside the target, fsync, then ``os.replace``.

Every file the package writes (EXR, PNG, gloss tables, meshes, contact sheets, the gloss fit's
outputs) goes through here, so a reader never finds a half-written file under a target's name:
an interrupted write (Ctrl-C, kill, full disk) leaves at most a hidden
``.<stem>.tmp-<pid><suffix>`` file beside it, which a resumed render removes. Written by hand:
the standard library has no replace-with-fsync helper, and the pattern is a few lines.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

__all__ = ["TEMPORARY_GLOB", "atomic_open", "atomic_path", "temporary_path"]

#: Glob matching the temporary files left by an interrupted write.
TEMPORARY_GLOB = ".*.tmp-*"


def temporary_path(path: str | os.PathLike) -> Path:
    """The temporary name a write to ``path`` uses (hidden, same folder, same suffix)."""
    path = Path(path)
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write; on success fsync it and move it onto ``path``.

    For writers that take a file name (OpenEXR, numpy's savez). If the block raises, the
    temporary file is removed and ``path`` is left as it was.
    """
    path = Path(path)
    tmp = temporary_path(path)
    try:
        yield tmp
        _fsync(tmp)
        os.replace(tmp, path)
        _fsync(path.parent)  # the rename itself survives a power cut
    finally:
        if tmp.exists():
            tmp.unlink()


@contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb", **open_kw) -> Iterator[IO]:
    """Open a temporary file for writing; on success flush, fsync and move it onto ``path``.

    ``mode`` and ``open_kw`` go to :func:`open` (e.g. ``"w", newline="", encoding="utf-8"``).
    """
    with atomic_path(path) as tmp, open(tmp, mode, **open_kw) as fh:
        yield fh
        fh.flush()
