"""The one error of the lab's data files."""

from __future__ import annotations

__all__ = ["LabFileError"]


class LabFileError(ValueError):
    """A data file that cannot be used as it is (the message names the file and the fix)."""
