"""The calibration package's exceptions: one small hierarchy, all ``ValueError`` subclasses."""

from __future__ import annotations

__all__ = [
    "BadReading",
    "CalibrationError",
    "PhotometerError",
    "PhotometerNotFound",
    "PhotometerTimeout",
]


class CalibrationError(ValueError):
    """Bad input to the calibration (a file, a parameter, a reading) and what to do instead."""


class PhotometerError(CalibrationError):
    """The photometer could not be used (port, protocol or reply)."""


class PhotometerNotFound(PhotometerError):
    """No photometer answers on the port; the message lists the ports the system reports."""


class PhotometerTimeout(PhotometerError):
    """The photometer did not reply within the retries; the message quotes the last raw reply."""

    def __init__(self, message: str, *, last_reply: str = ""):
        super().__init__(message)
        self.last_reply = last_reply


class BadReading(PhotometerError):
    """A reply that must not be used: garbled, out of range or saturated.

    Attributes
    ----------
    kind : {"garbled", "out_of_range", "saturated", "error"}
        Why the reading is rejected.
    raw_reply : str
        The instrument's reply as received.
    """

    def __init__(self, message: str, *, kind: str, raw_reply: str):
        super().__init__(message)
        self.kind = kind
        self.raw_reply = raw_reply
