"""Participant ids: validated once where they enter."""

from __future__ import annotations

import re

__all__ = ["PARTICIPANT_PATTERN", "check_participant_id"]

PARTICIPANT_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,32}")


def check_participant_id(participant: str) -> str:
    """Return ``participant`` if it is a valid id, else raise ``ValueError`` naming the fix.

    Ids are used in file names, so only letters, digits, '-' and '_' (1-32 characters) are allowed.
    """
    if not isinstance(participant, str) or not PARTICIPANT_PATTERN.fullmatch(participant):
        raise ValueError(
            f"participant id {participant!r} is not valid; use 1-32 letters, digits, '-' or '_' "
            "(e.g. 'P01')"
        )
    return participant
