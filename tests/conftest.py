"""Shared fixtures: a seeded RNG, the shipped design, the repository root, a local SLURM."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest

from studydesign import load_design

REPO_ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    """Ctrl-C reaches the processes the tests start. A script that runs the suite as a
    background job of a non-interactive shell (``( make test & )``) starts it with SIGINT
    ignored, which every child inherits: the tests that send Ctrl-C then saw their runs go on
    to the end (exit 0; seven failed so on 2026-11-28). Python's own handler is put back, as
    a terminal starts it, so the children start with the default again."""
    import signal

    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def rng() -> np.random.Generator:
    """A fresh generator with a fixed seed, so every test is reproducible."""
    return np.random.default_rng(20261122)


@pytest.fixture(scope="session")
def design():
    """The shipped study design."""
    return load_design()


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture(scope="session")
def slurm():
    """A SLURM controller and node on this machine (:mod:`tests.slurm_processes`), idle; its
    jobs cancelled and its daemons stopped by their pid files afterwards. Where it cannot be
    started (slurm-wlm or munge not installed, a daemon that dies), the test fails, naming
    why: the batch-cluster path is never skipped silently."""
    from tests.slurm_processes import SlurmError, local_slurm

    with contextlib.ExitStack() as stack:
        try:
            cluster, problem = stack.enter_context(local_slurm()), None
        except SlurmError as exc:
            cluster, problem = None, str(exc)
        if problem:
            pytest.fail(f"SLURM could not be started on this machine: {problem}", pytrace=False)
        yield cluster


def pytest_terminal_summary(terminalreporter):
    """Say loudly when the GPU comparison (tests/stimuli/test_gpu.py) was collected but could
    not run. Here, not in tests/stimuli/conftest.py: under pytest-xdist (make test) the
    controller that writes the summary loads only the root conftest."""
    not_run = [r for r in terminalreporter.stats.get("skipped", [])
               if "gpu" in getattr(r, "keywords", {}) and "NOT RUN" in str(r.longrepr)]
    if not_run:
        terminalreporter.write_sep("!", f"GPU CHECK NOT RUN ({len(not_run)} test marked gpu "
                                   "skipped: no CUDA GPU); run `pytest -m gpu tests/stimuli` on a "
                                   "GPU machine", red=True, bold=True)
    # The SLURM tests' own record (jobs submitted, one cancelled, all finished: the controller's
    # log), shown for passed tests too so that CI's log holds it (issue 39); failures show it
    # anyway.
    for report in terminalreporter.stats.get("passed", []):
        if "slurm" not in getattr(report, "keywords", {}) or report.when != "call":
            continue
        for title, text in report.sections:
            if "stdout" in title:
                terminalreporter.write_sep("-", f"{report.nodeid}: what SLURM did")
                terminalreporter.write_line(text.rstrip())
