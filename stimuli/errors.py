"""Errors of the stimuli package (all ``ValueError`` subclasses, so callers can catch them alike)."""

from __future__ import annotations

__all__ = [
    "ClusterError",
    "GlossTableError",
    "IlluminationError",
    "MitsubaSetupError",
    "StimuliError",
]


class StimuliError(ValueError):
    """Base class: bad input to the stimulus pipeline; the message names the input and the fix."""


class MitsubaSetupError(StimuliError):
    """Mitsuba or its LLVM back end cannot be used (wrong libLLVM, missing variant, failed smoke test)."""


class IlluminationError(StimuliError):
    """A light probe (HDR environment map) is missing, unreadable or holds NaN/Inf/negative radiance."""


class GlossTableError(StimuliError):
    """A gloss table (gloss % -> Ward parameters) is missing or malformed."""


class ClusterError(ValueError):
    """A cluster option or a run on a cluster that cannot go on; the message names the fix."""
