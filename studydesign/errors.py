"""The error a study design raises, and the one check every section uses."""

from __future__ import annotations

__all__ = ["DesignError", "require"]


class DesignError(ValueError):
    """A design file is missing, malformed, or inconsistent."""


def require(condition: bool, message: str) -> None:
    """Raise :class:`DesignError` with ``message`` (the key and the fix) unless ``condition``."""
    if not condition:
        raise DesignError(message)
