"""Participant ids: validated once where they enter."""

from __future__ import annotations

import re
from pathlib import Path

__all__ = [
    "PARTICIPANT_PATTERN",
    "case_twins",
    "check_new_participant",
    "check_participant_id",
    "recorded_participants",
]

PARTICIPANT_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,32}")

#: The files that name a participant in a data folder: folder, pattern whose group 1 is the id.
_RECORDS = (("plans", re.compile(r"(.+)_plan\.csv")),
            ("sessions", re.compile(r"(.+)_s\d+\.csv")),
            ("sliders", re.compile(r"(.+)_s\d+\.jsonl")),
            ("logs", re.compile(r"(.+)_s\d+_runs\.jsonl")))


def check_participant_id(participant: str) -> str:
    """Return ``participant`` if it is a valid id, else raise ``ValueError`` naming the fix.

    Ids are used in file names, so only letters, digits, '-' and '_' (1-32 characters) are allowed.
    """
    if not isinstance(participant, str) or not PARTICIPANT_PATTERN.fullmatch(participant):
        if isinstance(participant, str) and PARTICIPANT_PATTERN.fullmatch(participant.strip()):
            raise ValueError(f"participant id {participant!r} has spaces around it; type "
                             f"--participant {participant.strip()}")
        raise ValueError(
            f"participant id {participant!r} is not valid; use 1-32 letters, digits, '-' or '_' "
            "(e.g. 'P01')"
        )
    return participant


def recorded_participants(data_dir) -> dict[str, Path]:
    """The participant ids a data folder holds files of: id -> one of its files."""
    found: dict[str, Path] = {}
    for sub, pattern in _RECORDS:
        folder = Path(data_dir) / sub
        if not folder.is_dir():
            continue
        for path in sorted(folder.iterdir()):
            m = pattern.fullmatch(path.name)
            if m and PARTICIPANT_PATTERN.fullmatch(m.group(1)):
                found.setdefault(m.group(1), path)
    return found


def case_twins(participant: str, data_dir) -> dict[str, Path]:
    """Recorded participants whose id differs from ``participant`` only in case: id -> a file."""
    key = check_participant_id(participant).casefold()
    return {other: path for other, path in recorded_participants(data_dir).items()
            if other != participant and other.casefold() == key}


def check_new_participant(participant: str, data_dir) -> None:
    """Refuse a new id that differs from a recorded participant's only in case.

    ``p01`` after ``P01`` would get its own plan, and its session 2 would show stimuli P01 has
    seen; on a case-insensitive disk (macOS, Windows shares) both would write the same files.

    Raises
    ------
    ValueError
        Naming the recorded id, its file, and the option to type.
    """
    if participant in recorded_participants(data_dir):
        return  # recorded already (twins made before this check are noted, not refused)
    for other, path in case_twins(participant, data_dir).items():
        raise ValueError(
            f"participant id {participant!r} differs only in case from {other!r}, who has "
            f"files in {Path(data_dir).absolute()} ({path}); to continue that participant "
            f"type --participant {other}; a new participant needs an id that differs in more "
            "than case")
