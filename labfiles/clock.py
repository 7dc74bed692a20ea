"""Times read back from records are never after now.

A lab PC whose clock runs ahead stamps readings, calibrations and runs in the future; read back
on a PC with the right time they would never age (a calibration "-365.0 days old" is never
older than the 30-day limit). Every time a command reads from a record (reading timestamps,
``measured_utc``, ``created_utc``, ``--measured-utc``, a session's run history) is compared with
this PC's clock here; a few minutes ahead (:data:`FUTURE_TOLERANCE_S`: two PCs' clocks differ by
seconds to minutes without network time) is accepted.
"""

from __future__ import annotations

from datetime import UTC, datetime

__all__ = ["FUTURE_TOLERANCE_S", "future_problem"]

#: How far after this PC's clock a recorded time may lie, s (5 minutes).
FUTURE_TOLERANCE_S = 300.0


def _span(seconds: float) -> str:
    if seconds >= 2 * 86400:
        return f"{seconds / 86400:.1f} days"
    if seconds >= 2 * 3600:
        return f"{seconds / 3600:.1f} hours"
    return f"{seconds / 60:.0f} minutes"


def future_problem(t: datetime, name: str, *, now: datetime | None = None) -> str | None:
    """Why the time ``t`` cannot be true, or None.

    Parameters
    ----------
    t : datetime
        A time read from a record, with a zone.
    name : str
        What it is, for the message (e.g. ``"readings.csv: newest timestamp_utc"``).
    now : datetime or None
        This PC's time (default: the clock's, UTC).

    Returns
    -------
    str or None
        The message (what, how far ahead, the fix) when ``t`` is more than
        :data:`FUTURE_TOLERANCE_S` after ``now``; else None.
    """
    now = now or datetime.now(UTC)
    ahead = (t - now).total_seconds()
    if ahead <= FUTURE_TOLERANCE_S:
        return None
    return (f"{name} {t.astimezone(UTC):%Y-%m-%dT%H:%M:%SZ} is {_span(ahead)} after this PC's "
            f"clock ({now.astimezone(UTC):%Y-%m-%dT%H:%M:%SZ}): a time in the future never "
            "ages, so the calibration age limit could not fire. The clock of the PC that wrote "
            "it (or this one's) is wrong: set it right (`timedatectl`), then give the true time")
