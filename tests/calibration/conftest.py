"""Fixtures for the calibration tests: the simulated photometer, in-process or as a process."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from calibration.crt import SimulatedCRT
from calibration.fake_instrument import ConstantScreen, FakePhotometer, parse_faults

REPO_ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def fake_photometer():
    """Factory: an in-process fake instrument showing a constant drive; closed at teardown."""
    made = []

    def make(device, *, drive=1.0, faults=(), crt=None, seed=5, x_norm=0.0, y_norm=0.0):
        fake = FakePhotometer(device, crt or SimulatedCRT(), ConstantScreen(drive, x_norm, y_norm),
                              np.random.default_rng(seed), faults=parse_faults(faults),
                              measure_s=0.0)
        made.append(fake.start())
        return fake

    yield make
    for f in made:
        f.close()


def _need_display():
    if not os.environ.get("DISPLAY"):
        pytest.fail("no X display: run the tests under xvfb-run (make test does)")


@contextmanager
def fake_process(tmp_path: Path, device: str, faults=(), seed: int = 7, display=None):
    """``python -m calibration fake-photometer`` as a process; yields (port, aim_file, proc).

    ``display``: a TOML file with the simulated CRT's ``[crt]`` table (default: the shipped one).
    """
    _need_display()
    port_file = tmp_path / f"port-{time.monotonic_ns()}"
    aim = tmp_path / "aim.json"
    cmd = [sys.executable, "-m", "calibration", "fake-photometer", "--device", device,
           "--aim", str(aim), "--port-file", str(port_file), "--seed", str(seed),
           "--measure-s", "0.0"]
    for f in faults:
        cmd += ["--fault", f]
    if display is not None:
        cmd += ["--display", str(display)]
    proc = subprocess.Popen(cmd, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        for _ in range(300):
            if port_file.exists() and port_file.read_text().strip():
                break
            if proc.poll() is not None:
                pytest.fail(f"fake photometer exited: {proc.stderr.read()}")
            time.sleep(0.05)
        else:
            pytest.fail("fake photometer did not print its port within 15 s")
        yield port_file.read_text().strip(), aim, proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(timeout=10)


def interrupt_after(args, readings: Path, n_lines: int) -> tuple[int, str]:
    """Start ``python -m calibration ARGS``, send Ctrl-C (SIGINT) once ``readings`` holds
    ``n_lines`` lines, and return (exit code, stderr)."""
    import signal

    proc = subprocess.Popen([sys.executable, "-m", "calibration", *map(str, args)],
                            cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if readings.exists() and len(readings.read_text().splitlines()) >= n_lines:
            break
        assert proc.poll() is None, proc.stderr.read()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    return proc.returncode, err


def run_cli(args, *, timeout=240, **kw):
    """``python -m calibration ARGS`` from the repository root."""
    return subprocess.run([sys.executable, "-m", "calibration", *map(str, args)], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=timeout, check=False, **kw)


@pytest.fixture
def cli(capsys):
    """``python -m calibration ARGS`` run in this process: the command's own code (``main``),
    without a new interpreter's start-up. Returns a CompletedProcess (returncode, stdout,
    stderr). For commands that open no window."""
    from calibration.__main__ import main

    def run(args):
        args = [str(a) for a in args]
        capsys.readouterr()
        rc = main(args)
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(args, rc, out, err)

    return run


@pytest.fixture
def fake_proc(tmp_path):
    """Factory for :func:`fake_process` bound to the test's tmp_path."""
    return lambda device, faults=(), seed=7, display=None: fake_process(tmp_path, device, faults,
                                                                        seed, display)
