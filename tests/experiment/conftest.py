"""Fixtures of the session app's tests: real stimulus files, calibrations, a small design."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from studydesign import default_design_path, load_design

from .fixtures import make_calibration, make_manifest

REPO = Path(__file__).resolve().parents[2]


def _small_design_text() -> str:
    """The shipped design.toml with 2 x 2 x 3 = 12 stimuli in 2 sessions of 6 (fast tests)."""
    text = default_design_path().read_text(encoding="utf-8")
    subs = [
        (r"(\[gloss\][^\[]*?rendered_levels = )\[[^\]]*\]", r"\g<1>[4, 8]"),
        (r"(\[depth\][^\[]*?rendered_levels = )\[[^\]]*\]", r"\g<1>[3, 6, 9]"),
        (r"trials_per_session = \d+", "trials_per_session = 6"),
        (r"depth_bins_cm = \{[^}]*\}",
         "depth_bins_cm = { low = [1.2], medium = [2.4], high = [3.6] }"),
        (r"gloss_bins_pct = \{[^}]*\}", "gloss_bins_pct = { low = [30.0], high = [70.0] }"),
    ]
    for pattern, repl in subs:
        text, n = re.subn(pattern, repl, text, count=1, flags=re.DOTALL)
        assert n == 1, pattern
    return text


@pytest.fixture(scope="session")
def small_design_path(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("design") / "design.toml"
    path.write_text(_small_design_text(), encoding="utf-8")
    return path


@pytest.fixture(scope="session")
def small_design(small_design_path):
    design = load_design(small_design_path)
    assert design.n_stimuli == 12
    return design


@pytest.fixture(scope="session")
def stimuli_dir(tmp_path_factory, design) -> Path:
    """A manifest of real PNGs for every stimulus of the shipped design (read-only in tests)."""
    folder = tmp_path_factory.mktemp("stimuli")
    make_manifest(folder, design)
    return folder


@pytest.fixture
def session_files(tmp_path, stimuli_dir, design):
    """A private copy of the stimuli, a fresh calibration and an empty data folder."""
    stim = tmp_path / "stimuli"
    shutil.copytree(stimuli_dir, stim)
    cal = make_calibration(tmp_path / "cal", design)
    return {"manifest": stim / "manifest.csv", "calibration": cal, "data": tmp_path / "data",
            "root": tmp_path}


def app_env() -> dict:
    env = dict(os.environ)
    env.setdefault("HOME", str(REPO / ".home"))
    env["PYTHONPATH"] = str(REPO)
    return env


def run_app(*args, timeout=600, check_display=True) -> subprocess.CompletedProcess:
    """``python -m experiment run ARGS`` in a subprocess (the display is the test's DISPLAY)."""
    if check_display and not os.environ.get("DISPLAY"):
        pytest.fail("these tests need an X display: run pytest under xvfb-run (make test does)")
    return subprocess.run([sys.executable, "-m", "experiment", *map(str, args)], cwd=REPO,
                          check=False,
                          env=app_env(), capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def small_disk(tmp_path):
    """``small_disk(size, read_only=False)``: a real small file system (tmpfs) for a test.

    Needs root (``mount``); fails loudly when it cannot mount, rather than skipping.
    """
    import contextlib

    mounts = []

    @contextlib.contextmanager
    def mount(size: str, *, read_only: bool = False):
        point = tmp_path / f"disk{len(mounts)}"
        point.mkdir()
        opts = f"size={size}" + (",ro" if read_only else "")
        res = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(point)],
                             capture_output=True, text=True, check=False)
        if res.returncode != 0:
            pytest.fail(f"cannot mount a {size} tmpfs for this test (run the tests as root, as "
                        f"CI does): {res.stderr.strip()}")
        mounts.append(point)
        try:
            yield point
        finally:
            subprocess.run(["umount", "-l", str(point)], check=False)

    return mount
