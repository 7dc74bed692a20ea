"""Fixtures for the gloss-fit tests: small synthetic photo sets, rendered once per session."""

from __future__ import annotations

import pytest

from stimuli.glossfit import synth_photo_set

#: Gloss levels of the small test sets (a low, a middle and a high one would cost a third more).
LEVELS = (50.0, 100.0)


@pytest.fixture(scope="session")
def ward_photos(tmp_path_factory):
    """Photos of Ward spheres with known parameters, no camera effects (recovery tests)."""
    return synth_photo_set(tmp_path_factory.mktemp("ward") / "set", LEVELS, material="ward",
                           effects={}, seed=1)


@pytest.fixture(scope="session")
def rich_photos(tmp_path_factory):
    """Clear-coat (roughplastic) photos with every default camera effect."""
    return synth_photo_set(tmp_path_factory.mktemp("rich") / "set", LEVELS, material="rich",
                           seed=2)


@pytest.fixture(scope="session")
def ward_fit(ward_photos, tmp_path_factory, design):
    """The basis fit of the Ward photos (the default method)."""
    from stimuli.glossfit import fit_gloss

    return fit_gloss(ward_photos, tmp_path_factory.mktemp("fit") / "out",
                     design.gloss.physical_pct)
