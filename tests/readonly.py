"""A real read-only folder for tests: a read-only tmpfs (root ignores file modes, so chmod
cannot make one). Needs root, as CI runs; fails loudly when it cannot mount."""

from __future__ import annotations

import contextlib
import subprocess
from pathlib import Path

import pytest


@contextlib.contextmanager
def read_only_folder(parent: Path):
    """Yield an empty folder under ``parent`` on a read-only file system."""
    point = Path(parent) / "read-only"
    point.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k,ro", "tmpfs", str(point)],
                         capture_output=True, text=True, check=False)
    if res.returncode != 0:
        pytest.fail(f"cannot mount a read-only tmpfs for this test (run the tests as root, as "
                    f"CI does): {res.stderr.strip()}")
    try:
        yield point
    finally:
        subprocess.run(["umount", "-l", str(point)], check=False)
