"""Fixtures for the stimuli tests: Mitsuba set up once per session (LLVM variant)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")


@pytest.fixture(scope="session")
def mitsuba_variant():
    """The LLVM variant, selected and smoke-tested once (as a render worker does)."""
    from stimuli import setup_mitsuba

    return setup_mitsuba()


def pytest_terminal_summary(terminalreporter):
    """Say loudly when the GPU comparison was collected but could not run."""
    not_run = [r for r in terminalreporter.stats.get("skipped", [])
               if "gpu" in getattr(r, "keywords", {}) and "NOT RUN" in str(r.longrepr)]
    if not_run:
        terminalreporter.write_sep("!", f"GPU CHECK NOT RUN ({len(not_run)} test marked gpu "
                                   "skipped: no CUDA GPU); run `pytest -m gpu tests/stimuli` on a "
                                   "GPU machine", red=True, bold=True)
