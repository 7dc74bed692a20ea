"""Which stimuli a participant's earlier sessions were shown, checked before a later one.

A session's first run records a SHA-256 over its ``stimulus_id:png_sha256`` lines
(:func:`experiment.session.session_inputs`). The same digest, computed from this run's manifest
for an earlier session's stimuli, says whether the manifest still holds the images that session
showed. It does not when the set was re-rendered: with the same calibration that is a mistake
(refused, naming the manifest the earlier session used); after a new calibration it is how the
protocol keeps the gamma correction right, and is said on stderr and in the run's log. A new
calibration is a file of other content (its SHA-256), whatever its id: a recalibration saved
under the old id is said as one under a new id is, with both fits.
"""

from __future__ import annotations

import hashlib
import warnings
from pathlib import Path

import pandas as pd

from experiment.checks import PreflightError, SessionStimuli
from experiment.datafile import DataFileError, read_run_events, runs_path, session_path

__all__ = ["calibration_words", "check_earlier_sessions", "check_same_inputs", "session_inputs",
           "stimuli_digest"]


def stimuli_digest(stimulus_ids, png_sha256) -> str:
    """SHA-256 of the sorted ``stimulus_id:png_sha256`` lines (one session's images)."""
    lines = sorted(f"{i}:{h}" for i, h in zip(stimulus_ids, png_sha256))
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def calibration_words(inputs: dict) -> str:
    """A session's calibration as its inputs record it: the file, its SHA-256 and (in records
    that hold it) the fit, e.g. ``"/lab/cal/calibration.json, SHA-256 1f2e...; black 0.50,
    white 95.0 cd/m^2, offset_power gamma 2.40"``."""
    from calibration import display_model_words

    sha = str(inputs.get("calibration_sha256") or "?")
    fit = inputs.get("calibration_fit")
    return (f"{inputs.get('calibration')}, SHA-256 {sha[:12]}..."
            + (f"; {display_model_words(fit)}" if isinstance(fit, dict) else ""))


def _first_start(data_dir, participant: str, session: int, run_logs) -> dict | None:
    """The first recorded start of a session (``_runs.jsonl``, else its run logs), or None."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a torn tail is the session's own run to report
        try:
            events = read_run_events(runs_path(data_dir, participant, session))
        except DataFileError:
            events = []
    events = events + [{"event": "start", **log["inputs"]} for log in run_logs if "inputs" in log]
    return next((e for e in events if e.get("event") == "start" and "stimuli_sha256" in e), None)


def check_earlier_sessions(manifest: pd.DataFrame, plan: pd.DataFrame, session: int,
                           inputs: dict, *, data_dir, participant: str, run_logs,
                           notes: list) -> None:
    """Refuse a manifest whose images of an earlier session differ from those it showed while
    the calibration is the same file; note it when the calibration changed between sessions.

    Parameters
    ----------
    manifest : DataFrame
        This run's manifest (``stimulus_id``, ``png_sha256``).
    plan : DataFrame
        The participant's whole plan (``session``, ``stimulus_id``).
    session : int
        This session's number; sessions 1 .. session-1 are checked.
    inputs : dict
        This run's :func:`experiment.session.session_inputs`.
    run_logs : callable
        ``run_logs(session) -> list of dict``: that session's run logs.
    notes : list
        Warnings of the pre-flight (appended to).
    """
    sha = dict(zip(manifest["stimulus_id"], manifest["png_sha256"]))
    for earlier in range(1, session):
        first = _first_start(data_dir, participant, earlier, run_logs(earlier))
        ids = list(plan.loc[plan["session"] == earlier, "stimulus_id"])
        if first is None and session_path(data_dir, participant, earlier).exists():
            notes.append(f"session {earlier} of {participant} has no record of the images it "
                         f"showed ({runs_path(data_dir, participant, earlier).name} and its run "
                         "logs are missing): this run cannot check that --stimuli holds the same "
                         f"render; pass the manifest session {earlier} used")
        if first is None:
            continue
        same_file = first.get("calibration_sha256") == inputs["calibration_sha256"]
        recalibrated = not same_file and first.get("calibration_sha256") is not None
        said = (f"session {earlier} of {participant} used calibration "
                f"{first.get('calibration_id')!r} ({calibration_words(first)}), this run "
                f"{inputs['calibration_id']!r} ({calibration_words(inputs)})")
        if recalibrated and first.get("calibration_id") == inputs["calibration_id"]:
            said += ": another file under the same id (the display was recalibrated)"
        if (not all(i in sha for i in ids)
                or stimuli_digest(ids, [sha[i] for i in ids]) == first["stimuli_sha256"]):
            if recalibrated:  # the same images (or some not in this manifest): still said
                notes.append(f"{said}; the participant's sessions were shown under two "
                             "calibrations of the display")
            continue
        what = (f"session {earlier} of {participant} was shown the images of "
                f"{first.get('manifest')}; this run's manifest {inputs['manifest']} holds other "
                f"images for those stimuli (re-rendered)")
        if same_file:
            raise PreflightError(
                f"{what}, with the same calibration: a participant's sessions show one rendered "
                f"set. Pass --stimuli {Path(str(first.get('manifest')))} (restore its images if "
                "they were replaced)")
        notes.append(f"{what} for the new calibration {inputs['calibration_id']!r} ({said}): "
                     "the participant's sessions show two renders of the set")


def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def session_inputs(stim: SessionStimuli, calibration_path, cal) -> dict:
    """What a session's data depend on, as checksums: recorded at its first run.

    Returns
    -------
    dict
        ``calibration`` (absolute path), ``calibration_id``, ``calibration_sha256`` (of the
        file), ``calibration_fit`` (its :attr:`calibration.Calibration.display_model`: a later
        session names what changed), ``manifest`` (absolute path) and ``stimuli_sha256``:
        SHA-256 of this session's
        ``stimulus_id:png_sha256`` lines, sorted (so rows the manifest gains later for other
        stimuli do not count, but any change to one of this session's images does).
    """
    cal_file = Path(calibration_path)
    cal_file = cal_file / "calibration.json" if cal_file.is_dir() else cal_file
    lines = sorted(f"{i}:{h}" for i, h in zip(stim.frame["stimulus_id"], stim.frame["png_sha256"]))
    return {"calibration": str(cal_file.resolve()), "calibration_id": cal.calibration_id,
            "calibration_sha256": _sha256(cal_file), "calibration_fit": cal.display_model,
            "manifest": str(Path(stim.manifest_path).resolve()),
            "stimuli_sha256": hashlib.sha256("\n".join(lines).encode()).hexdigest()}


def check_same_inputs(inputs: dict, done: pd.DataFrame, events: list[dict], path: Path) -> None:
    """A resumed session must use the calibration and stimuli it started with.

    Raises
    ------
    PreflightError
        Another calibration (by id in the recorded rows, or by checksum in the run log) or other
        stimulus images than the first run's; the message names the files to use.
    """
    if done.empty:
        return
    ids = sorted(set(done["calibration_id"].astype(str)) - {inputs["calibration_id"]})
    first = next((e for e in events if e.get("event") == "start" and "calibration_sha256" in e),
                 None)
    if ids:
        used = f" ({first['calibration']})" if first else ""
        raise PreflightError(
            f"{path}: the {len(done)} trials recorded so far used calibration {ids}{used}, this "
            f"run calibration {inputs['calibration_id']!r} ({inputs['calibration']}); a session "
            "is finished with the calibration it started with. Pass that calibration with "
            "--calibration (or start the participant's data anew in another data folder)")
    if first is None:
        return
    if first["calibration_sha256"] != inputs["calibration_sha256"]:
        raise PreflightError(
            f"{path}: this session started with calibration file {first['calibration']} "
            f"(SHA-256 {first['calibration_sha256'][:12]}...), this run has {inputs['calibration']} "
            f"(SHA-256 {inputs['calibration_sha256'][:12]}...), which differs although its id is "
            "the same; pass the first file with --calibration")
    if first["stimuli_sha256"] != inputs["stimuli_sha256"]:
        raise PreflightError(
            f"{path}: this session started with the stimuli of {first['manifest']}; the images "
            f"this run would show ({inputs['manifest']}) are not the same (other checksums, e.g. "
            "re-rendered or another size). Pass the first manifest with --stimuli (restore its "
            "images if they were replaced)")
