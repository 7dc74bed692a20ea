"""Pre-flight checks: everything that can be wrong is found before a window opens.

Each check raises :class:`PreflightError` with a message that names the input, what is wrong and
the fix. None of them opens a window or imports ``psychopy.visual`` (which needs a display);
:func:`check_screen` asks the X server directly.
"""

from __future__ import annotations

import errno
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from calibration import Calibration, CalibrationError, load_calibration
from experiment.participants import check_participant_id
from labfiles import temporary_path
from stimuli import ManifestError, load_manifest, verify_manifest
from studydesign import StudyDesign

__all__ = [
    "PreflightError",
    "SessionStimuli",
    "check_calibration",
    "check_data_folder",
    "check_keyboard_libraries",
    "check_monitor_profile",
    "check_participant",
    "check_screen",
    "check_screenshot",
    "check_session_number",
    "check_stimuli",
]

#: Refresh rates further apart than this (relative) make a calibration not match the design's CRT.
_REFRESH_TOLERANCE = 0.05
#: Free space a session needs in the data folder (rows, slider histories, frame logs and plots
#: of a long session take a few MB).
MIN_FREE_MB = 20.0
#: PNG colour types the session shows (PIL modes): 8-bit grey, as ``stimuli`` writes, or RGB.
_PNG_MODES = ("L", "RGB")


class PreflightError(ValueError):
    """A session cannot start: the message says what to fix."""


def check_participant(participant: str) -> str:
    try:
        return check_participant_id(participant)
    except ValueError as exc:
        raise PreflightError(str(exc)) from exc


def check_session_number(design: StudyDesign, session) -> int:
    """``session`` as an int in 1..design.sessions.n_sessions."""
    n = design.sessions.n_sessions
    try:
        value = int(session)
    except (TypeError, ValueError):
        value = None
    if value is None or str(session).strip() != str(value) or not 1 <= value <= n:
        raise PreflightError(f"session {session!r} is not valid; the design has sessions 1-{n}")
    return value


def check_data_folder(data_dir) -> Path:
    """The data folder exists (or can be made), can be written, and has room for a session.

    Returns
    -------
    Path
        The folder, absolute.

    Raises
    ------
    PreflightError
        It cannot be made or written (read-only, no permission), or its disk has less than
        ``MIN_FREE_MB`` free.
    """
    folder = Path(data_dir).absolute()
    probe = temporary_path(folder / "write-test")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise PreflightError(f"the disk holding the data folder {folder} is full; free "
                                 "space, then run the same command again") from None
        why = ("is on a read-only file system" if exc.errno == errno.EROFS
               else f"cannot be written ({exc.strerror})")
        raise PreflightError(
            f"the data folder {folder} {why}; nothing was recorded. Give a writable folder with "
            "--data (or fix its permissions)") from None
    free_mb = shutil.disk_usage(folder).free / 1e6
    if free_mb < MIN_FREE_MB:
        raise PreflightError(
            f"the disk holding the data folder {folder} has {free_mb:.1f} MB free, less than the "
            f"{MIN_FREE_MB:g} MB a session may write; free space (or use another --data)")
    return folder


def check_screenshot(path) -> Path | None:
    """A ``--screenshot`` goes into an existing, writable folder, as a PNG.

    Raises
    ------
    PreflightError
        The folder is missing or not writable, or the name does not end in ``.png``.
    """
    if path is None:
        return None
    path = Path(path).absolute()
    if path.suffix.lower() != ".png":
        raise PreflightError(f"--screenshot {path}: the screenshot is a PNG; end its name in "
                             "'.png'")
    if not path.parent.is_dir():
        raise PreflightError(f"--screenshot {path}: the folder {path.parent} does not exist; "
                             "create it first or choose another path")
    if not os.access(path.parent, os.W_OK):
        raise PreflightError(f"--screenshot {path}: the folder {path.parent} is not writable")
    return path


@dataclass(frozen=True)
class SessionStimuli:
    """The verified stimuli of one session.

    Attributes
    ----------
    manifest_path : Path
    frame : DataFrame
        One row per stimulus id: ``stimulus_id``, ``png`` (absolute path), ``image_width_cm``,
        ``width_px``, ``height_px``, ``calibration_id`` (the calibration the PNG was gamma-corrected
        for), ``calibration_sha256`` (its file's SHA-256; empty where the manifest records
        none), ``png_sha256``.
    """

    manifest_path: Path
    frame: pd.DataFrame

    @property
    def calibration_ids(self) -> list[str]:
        return sorted(set(self.frame["calibration_id"].astype(str)))


def check_stimuli(manifest, plan_rows: pd.DataFrame, *,
                  every_stimulus=None) -> SessionStimuli:
    """Check the manifest holds every stimulus of ``plan_rows``, present and unchanged.

    Parameters
    ----------
    manifest : path-like
        ``manifest.csv`` written by ``python -m stimuli render`` (or its folder).
    plan_rows : DataFrame
        The session's plan rows (``stimulus_id`` and the design levels).
    every_stimulus : sequence of str, optional
        Stimulus ids checked as well (checksums, every PNG decoded): the app passes those of
        all the participant's sessions, so that an image damaged or replaced is found before
        the first session rather than at the start of a later one (where the participant would
        see a re-rendered set). Default: the session's only.

    Raises
    ------
    PreflightError
        Manifest missing or malformed; a stimulus absent, its PNG missing or changed since
        rendering (SHA-256); a manifest row whose levels disagree with the design; a bad
        ``image_width_cm``.
    """
    if manifest is None:
        raise PreflightError(
            "no stimulus manifest given; pass --stimuli DIR/manifest.csv (written by "
            "`python -m stimuli render --set experiment --out DIR`)"
        )
    ids = list(plan_rows["stimulus_id"])
    checked = list(dict.fromkeys([*ids, *(every_stimulus if every_stimulus is not None else [])]))
    whose = "this session's" if len(checked) == len(ids) else "the participant's"
    try:
        frame = load_manifest(manifest)
        problems = verify_manifest(manifest, kinds=("png",), stimulus_ids=checked)
    except ManifestError as exc:
        raise PreflightError(str(exc)) from exc
    if problems:
        more = f" (and {len(problems) - 10} more)" if len(problems) > 10 else ""
        raise PreflightError(
            f"stimulus manifest {frame.attrs['manifest_path']}: {len(problems)} problem(s) with "
            f"{whose} stimuli{more}:\n  " + "\n  ".join(problems[:10])
        )
    path = Path(frame.attrs["manifest_path"])
    rows = frame.set_index("stimulus_id").loc[ids].reset_index()
    problems = _decode_problems(path, frame.set_index("stimulus_id").loc[checked].reset_index())
    if problems:
        more = f" (and {len(problems) - 10} more)" if len(problems) > 10 else ""
        raise PreflightError(
            f"stimulus manifest {path}: {len(problems)} of {whose} images do not decode as the "
            f"manifest says{more}:\n  " + "\n  ".join(problems[:10]))
    for col in ("illumination", "gloss_level", "depth_level", "true_gloss_pct", "true_depth_cm"):
        a, b = rows[col].to_numpy(), plan_rows[col].to_numpy()
        same = a == b if col == "illumination" else np.isclose(a.astype(float), b.astype(float))
        if not np.all(same):
            i = int(np.flatnonzero(~same)[0])
            raise PreflightError(
                f"stimulus manifest {path}: {ids[i]} has {col} = {a[i]!r} but the design says "
                f"{b[i]!r}; the stimuli were rendered for another design. Re-render them"
            )
    width = pd.to_numeric(rows["image_width_cm"], errors="coerce").to_numpy()
    if not np.all(np.isfinite(width) & (width > 0)):
        i = int(np.flatnonzero(~(np.isfinite(width) & (width > 0)))[0])
        raise PreflightError(f"stimulus manifest {path}: {ids[i]} has image_width_cm = "
                             f"{rows['image_width_cm'].iloc[i]!r}; it must be a positive size in cm")
    _check_one_size(path, frame.set_index("stimulus_id").loc[checked].reset_index())
    out = pd.DataFrame({
        "stimulus_id": ids,
        "png": [str((path.parent / str(p)).resolve()) for p in rows["png_path"]],
        "image_width_cm": width,
        "width_px": rows["width_px"].astype(int).to_numpy(),
        "height_px": rows["height_px"].astype(int).to_numpy(),
        "calibration_id": rows["calibration_id"].astype(str).to_numpy(),
        "calibration_sha256": rows["calibration_sha256"].astype(str).to_numpy(),
        "png_sha256": rows["png_sha256"].to_numpy(),
    })
    return SessionStimuli(manifest_path=path, frame=out)


def _check_one_size(path: Path, rows: pd.DataFrame) -> None:
    """Every stimulus of a participant is shown at one physical size: a row whose
    ``image_width_cm`` differs from the others' median by more than 1 % (a row edited, or
    rendered for another screen) is refused before any session, naming it."""
    width = pd.to_numeric(rows["image_width_cm"], errors="coerce").to_numpy(float)
    ok = np.isfinite(width) & (width > 0)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        raise PreflightError(f"stimulus manifest {path}: {rows['stimulus_id'].iloc[i]} has "
                             f"image_width_cm = {rows['image_width_cm'].iloc[i]!r}; it must be a "
                             "positive size in cm: re-render it")
    median = float(np.median(width))
    off = np.abs(width / median - 1) > 0.01
    if off.any():
        i = int(np.flatnonzero(off)[0])
        raise PreflightError(
            f"stimulus manifest {path}: {rows['stimulus_id'].iloc[i]} is {width[i]:g} cm wide, "
            f"the other stimuli {median:g} cm ({int(off.sum())} of {len(width)} differ): every "
            "stimulus is shown at one size; re-render the set (python -m stimuli render) or "
            "restore the manifest")


def _decode_problems(manifest_path: Path, rows: pd.DataFrame) -> list[str]:
    """Decode every PNG; compare its size with the manifest's and its colour type with the
    session's (8-bit grey or RGB, one type for all): one message per problem."""
    from PIL import Image

    problems, modes = [], {}
    for row in rows.itertuples(index=False):
        png = manifest_path.parent / str(row.png_path)
        try:
            with Image.open(png) as im:
                im.load()
                fmt, size, mode = im.format, im.size, im.mode
        except (OSError, SyntaxError, ValueError) as exc:
            problems.append(f"{row.stimulus_id}: {png} does not decode ({exc}); re-render it")
            continue
        want = (int(row.width_px), int(row.height_px))
        if fmt != "PNG":
            problems.append(f"{row.stimulus_id}: {png} is a {fmt} file, not a PNG; re-render it")
        elif size != want:
            problems.append(f"{row.stimulus_id}: {png} decodes to {size[0]}x{size[1]} px, the "
                            f"manifest says {want[0]}x{want[1]}; re-render it")
        elif mode not in _PNG_MODES:
            problems.append(f"{row.stimulus_id}: {png} has colour type {mode!r}; the session "
                            "shows 8-bit grey ('L') or RGB PNGs. Re-render it")
        else:
            modes.setdefault(mode, []).append(row.stimulus_id)
    if len(modes) > 1:
        few = min(modes, key=lambda m: len(modes[m]))
        problems.append(f"{modes[few][:5]} are {few!r} PNGs but the session's other stimuli "
                        f"are {sorted(set(modes) - {few})}; one colour type for all. Re-render "
                        "them")
    return problems


def check_calibration(path, design: StudyDesign, *, max_age_days: float) -> Calibration:
    """Load the calibration and check it is recent and describes the design's CRT.

    Raises
    ------
    PreflightError
        No path; file missing or invalid; older than ``max_age_days``; resolution, viewing
        distance or refresh rate different from the design's display.
    """
    if path is None:
        raise PreflightError(
            "no calibration given; pass --calibration DIR/calibration.json (written by "
            "`python -m calibration run`)"
        )
    try:
        cal = load_calibration(path)
    except CalibrationError as exc:
        raise PreflightError(str(exc)) from exc
    age = cal.age_days()
    if age > max_age_days:
        raise PreflightError(
            f"calibration {path} ({cal.calibration_id}, measured "
            f"{cal.measured_utc or cal.created_utc}) is {age:.1f} days old, more than the allowed {max_age_days:g}; recalibrate the CRT "
            "(`python -m calibration run`) or raise --max-calibration-age-days if you are sure"
        )
    disp = design.display
    if tuple(cal.resolution_px) != tuple(disp.resolution_px):
        raise PreflightError(
            f"calibration {path} was made at {cal.resolution_px[0]}x{cal.resolution_px[1]} px, "
            f"but the design's CRT runs at {disp.resolution_px[0]}x{disp.resolution_px[1]}; "
            "calibrate the CRT at the design's resolution"
        )
    if not np.isclose(cal.distance_cm, disp.viewing_distance_cm):
        raise PreflightError(
            f"calibration {path} assumes a viewing distance of {cal.distance_cm:g} cm, the design "
            f"{disp.viewing_distance_cm:g} cm; fix the chin rest and recalibrate with that distance"
        )
    if abs(cal.refresh_hz / disp.nominal_refresh_hz - 1) > _REFRESH_TOLERANCE:
        raise PreflightError(
            f"calibration {path} measured {cal.refresh_hz:.1f} Hz, the design's CRT runs at "
            f"{disp.nominal_refresh_hz:g} Hz; set the refresh rate and recalibrate"
        )
    return cal


def check_screen(design: StudyDesign, *, fullscr: bool, display_name: str | None = None):
    """Ask the X server for the screen size and check the session window fits the design.

    A full-screen session needs the screen at exactly the design's resolution (set the CRT's
    mode first); a windowed one (tests, demos) needs a screen at least that large.

    Returns
    -------
    (int, int)
        The screen's width and height in pixels.

    Raises
    ------
    PreflightError
        No X display, or a screen of the wrong size.
    """
    from Xlib import display as xdisplay
    from Xlib.error import DisplayError

    name = display_name or os.environ.get("DISPLAY")
    if not name:
        raise PreflightError(
            "no X display (DISPLAY is not set); run the session at the lab computer's desktop, "
            "or under `xvfb-run -a -s \"-screen 0 1280x1024x24\"` for a simulated run"
        )
    try:
        d = xdisplay.Display(name)
    except (DisplayError, OSError) as exc:
        raise PreflightError(f"cannot connect to X display {name!r} ({exc})") from exc
    try:
        screen = d.screen()
        size = (int(screen.width_in_pixels), int(screen.height_in_pixels))
    finally:
        d.close()
    want = tuple(design.display.resolution_px)
    if fullscr and size != want:
        raise PreflightError(
            f"the screen is {size[0]}x{size[1]} px but the design's CRT runs at "
            f"{want[0]}x{want[1]}; set the display mode (e.g. `xrandr -s {want[0]}x{want[1]}`)"
        )
    if size[0] < want[0] or size[1] < want[1]:
        raise PreflightError(
            f"the screen is {size[0]}x{size[1]} px, smaller than the design's "
            f"{want[0]}x{want[1]} window; use a larger screen or the CRT at its design mode"
        )
    return size


def check_keyboard_libraries() -> None:
    """psychtoolbox's keyboard needs libasound2 and libjack; without them PsychoPy silently falls
    back to its ``event`` keyboard, which never matches keys in PsychoPy 2026.2.

    Raises
    ------
    PreflightError
        A library is missing or psychtoolbox cannot be imported.
    """
    import ctypes.util

    missing = [pkg for lib, pkg in (("asound", "libasound2"), ("jack", "libjack-jackd2-0"))
               if ctypes.util.find_library(lib) is None]
    if missing:
        raise PreflightError(
            f"the keyboard needs {missing} (psychtoolbox's key queue); install them "
            f"(`apt-get install {' '.join(missing)}`, or `make system-deps`)"
        )
    try:
        import psychtoolbox  # noqa: F401
    except ImportError as exc:
        raise PreflightError(
            f"psychtoolbox does not load ({exc}); the keyboard would fall back to PsychoPy's "
            "'event' backend, which loses key presses. Reinstall the venv (`make venv`)"
        ) from exc


def check_monitor_profile(calibration_path, cal: Calibration) -> Path | None:
    """The PsychoPy monitor profile saved with the calibration must describe the same display.

    ``python -m calibration run`` writes ``<calibration folder>/monitors/<monitor_name>.json``; the
    app builds its monitor from ``calibration.json`` and checks the two agree (width, distance,
    resolution). A calibration without a saved profile (e.g. the default curve) is accepted.

    Returns
    -------
    Path or None
        The profile checked, if there is one.

    Raises
    ------
    PreflightError
        The profile lacks this calibration or disagrees with it.
    """
    import json

    folder = Path(calibration_path)
    folder = folder if folder.is_dir() else folder.parent
    path = folder / "monitors" / f"{cal.monitor_name}.json"
    if not path.is_file():
        return None
    try:
        entry = json.loads(path.read_text(encoding="utf-8")).get(cal.calibration_id)
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError) as exc:
        raise PreflightError(f"monitor profile {path} is not a PsychoPy profile ({exc})") from exc
    if entry is None:
        raise PreflightError(
            f"monitor profile {path} has no calibration {cal.calibration_id!r}; the calibration "
            "folder was mixed up. Use the calibration.json written with this profile"
        )
    got = (float(entry["width"]), float(entry["distance"]), tuple(entry["sizePix"]))
    want = (cal.width_cm, cal.distance_cm, tuple(cal.resolution_px))
    if not (np.isclose(got[0], want[0]) and np.isclose(got[1], want[1]) and got[2] == want[2]):
        raise PreflightError(
            f"monitor profile {path} says width {got[0]:g} cm, distance {got[1]:g} cm, "
            f"{got[2][0]}x{got[2][1]} px, but {calibration_path} says {want[0]:g} cm, "
            f"{want[1]:g} cm, {want[2][0]}x{want[2][1]} px; recalibrate (or restore the pair)"
        )
    return path
