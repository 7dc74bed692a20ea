"""Shared fixtures: a seeded RNG, the shipped design, the repository root."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from studydesign import load_design

REPO_ROOT = Path(__file__).resolve().parents[1]


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
