"""The gap diagnosis's one error class."""

from __future__ import annotations

__all__ = ["GapError"]


class GapError(ValueError):
    """Bad input to the sim-to-real gap diagnosis."""
