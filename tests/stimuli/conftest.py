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


@pytest.fixture(scope="session")
def sun_probe():
    """A maker of small synthetic light probes: a sky brightening toward the zenith
    (``sky + 0.5 cos^2(theta / 2)``) and a sun of height ``peak`` and spread ``width`` (rad^2)
    60 degrees from the zenith, ``h`` x 2h pixels; grey."""
    import numpy as np

    from stimuli.illumination import LightProbe

    def make(sky: float, peak: float, width: float, h: int = 32):
        theta = (np.arange(h) + 0.5) / h * np.pi
        phi = (np.arange(2 * h) + 0.5) / (2 * h) * 2 * np.pi
        t, p = np.meshgrid(theta, phi, indexing="ij")
        y = sky + 0.5 * np.cos(t / 2) ** 2 + peak * np.exp(-((t - np.radians(60)) ** 2
                                                             + (p - np.pi) ** 2) / width)
        return LightProbe(name="sun", path="", sha256="sun",
                          rgb=np.repeat(y[..., None], 3, axis=2).astype(np.float32),
                          rotation_deg=0.0, scale=1.0)
    return make
