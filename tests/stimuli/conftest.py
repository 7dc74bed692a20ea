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
