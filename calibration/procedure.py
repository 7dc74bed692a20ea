"""The measurement procedure: patches in a PsychoPy window, one photometer reading per patch.

Order of work (``python -m calibration run``):

1. Positions in a fixed order, the centre first. At each, the experimenter aims the photometer
   at a cross and presses space (in simulation the procedure writes the aim for the fake
   instrument instead; see :mod:`calibration.fake_instrument`).
2. At each position, every (level, repeat) in an order shuffled by the recorded seed; each patch
   is shown, left ``settle_s`` to settle, measured, and the reading appended to
   ``readings.csv`` at once (flush + fsync). Rejected replies go to ``rejected.csv`` and the
   patch is measured again (at most ``max_rejects`` times).
3. A rerun with the same ``--out`` reads ``procedure.json`` (settings and seed, written once)
   and ``readings.csv`` and measures only what is missing.

Levels are drive values on the 8-bit grid (k/255), so the value recorded is exactly the value
displayed. Positions are patch centres in norm units. The centre gets all ``n_levels`` levels;
other positions get ``uniformity_levels`` evenly spaced levels (black and white included).
"""

from __future__ import annotations

import json
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import pandas as pd

from calibration.errors import BadReading, CalibrationError
from calibration.readings import (
    READINGS_COLUMNS,
    REJECTED_COLUMNS,
    append_row,
    read_readings,
    read_record_csv,
)
from calibration.record import utc_now_iso
from labfiles import atomic_write_text, write_new_file

__all__ = [
    "PATCH_LIST_FIELDS",
    "VALIDATION_COLUMNS",
    "PatchDisplay",
    "ProcedureSettings",
    "calibration_window",
    "load_or_create_settings",
    "make_schedule",
    "measure_schedule",
    "measure_validation",
    "read_validation",
    "settings_from_options",
]

VALIDATION_COLUMNS = READINGS_COLUMNS + ("target_fraction",)

#: Settings that change what is measured (the patch list, its order, or the light on the
#: screen), with the command-line option that sets each. A run resumed in a folder must keep them.
PATCH_LIST_FIELDS = {
    "calibration_id": "--calibration-id",
    "device": "--device",
    "seed": "--seed",
    "n_levels": "--levels",
    "uniformity_levels": "--uniformity-levels",
    "n_repeats": "--repeats",
    "grid": "--grid",
    "n_validation": "--validation",
    "grid_extent_norm": None,
    "patch_frac": None,
    "background_level": None,
}


@dataclass(frozen=True)
class ProcedureSettings:
    """Settings of one calibration run (saved once as ``procedure.json``).

    Attributes
    ----------
    calibration_id : str
    device : str
    seed : int
        Seeds the order of patches (recorded so a rerun resumes the same schedule).
    n_levels : int
        Levels at the centre (default 17).
    uniformity_levels : int
        Levels at the other positions.
    n_repeats : int
        Readings per (position, level).
    grid : int
        Positions per side (3: a 3 x 3 grid; 1: the centre only).
    grid_extent_norm : float
        Outermost patch centres at +-this, norm units.
    patch_frac : float
        Patch side as a fraction of the screen height.
    background_level : float
        Drive of the surround (a CRT's output depends a little on the whole picture; keep it
        like the experiment's).
    settle_s : float
        Wait after each flip before measuring, s.
    max_rejects : int
        Rejected replies tolerated per patch before the run stops.
    n_validation : int
        Fractions of the luminance range measured after correction (0: no validation).
    """

    calibration_id: str
    device: str
    seed: int
    n_levels: int = 17
    uniformity_levels: int = 5
    n_repeats: int = 2
    grid: int = 3
    grid_extent_norm: float = 0.6
    patch_frac: float = 0.2
    background_level: float = 0.5
    settle_s: float = 0.5
    max_rejects: int = 3
    n_validation: int = 9

    def __post_init__(self) -> None:
        checks = [
            (self.n_levels >= 4, "n_levels must be >= 4 (the gamma fit needs 4 levels)"),
            (2 <= self.uniformity_levels <= self.n_levels,
             "uniformity_levels must lie in 2..n_levels"),
            (self.n_repeats >= 1, "n_repeats must be >= 1"),
            (self.grid >= 1, "grid must be >= 1"),
            (0 < self.grid_extent_norm < 1, "grid_extent_norm must lie in (0, 1)"),
            (0 < self.patch_frac <= 1, "patch_frac must lie in (0, 1]"),
            (0 <= self.background_level <= 1, "background_level must lie in [0, 1]"),
            (self.settle_s >= 0, "settle_s must be >= 0"),
            (self.max_rejects >= 1, "max_rejects must be >= 1"),
            (self.n_validation == 0 or self.n_validation >= 3, "n_validation must be 0 or >= 3"),
            (self.calibration_id.replace("-", "").replace("_", "").isalnum(),
             "calibration_id may hold letters, digits, '-' and '_' only"),
        ]
        for ok, msg in checks:
            if not ok:
                raise CalibrationError(f"procedure settings: {msg} (got {self})")
        if reserved_id_problem(self.calibration_id):
            raise CalibrationError(reserved_id_problem(self.calibration_id))

    def positions(self) -> list[tuple[float, float]]:
        """Patch centres (x_norm, y_norm), the centre first, then row by row from the top."""
        if self.grid == 1:
            return [(0.0, 0.0)]
        v = np.linspace(-self.grid_extent_norm, self.grid_extent_norm, self.grid)
        pos = [(float(x), float(y)) for y in v[::-1] for x in v]
        pos.sort(key=lambda p: (p != (0.0, 0.0)))
        return pos if (0.0, 0.0) in pos else [(0.0, 0.0)] + pos

    def levels(self, n: int) -> np.ndarray:
        """``n`` drive values evenly spaced on the 8-bit grid, 0 and 1 included."""
        return np.unique(np.round(np.linspace(0, 1, n) * 255)) / 255


#: Calibration ids that mean something else: session rows answered by a simulated observer
#: carry ``simulated`` (the analysis sets them apart), the unmeasured default curve ``default``.
RESERVED_IDS = ("simulated", "default")


def reserved_id_problem(calibration_id: str) -> str | None:
    """Why a measured calibration may not be called ``calibration_id``, or None."""
    if str(calibration_id).casefold() not in RESERVED_IDS:
        return None
    return (f"calibration id {calibration_id!r} is reserved ({', '.join(RESERVED_IDS)}: "
            "simulated sessions' rows and the unmeasured default curve); pass another "
            "--calibration-id, e.g. crt-2026-11")


def make_schedule(settings: ProcedureSettings) -> pd.DataFrame:
    """Every patch to measure, in measuring order.

    Returns
    -------
    DataFrame
        Columns x_norm, y_norm, level, repeat; one row per reading.
    """
    rng = np.random.default_rng(settings.seed)
    rows = []
    for x, y in settings.positions():
        centre = (x, y) == (0.0, 0.0)
        levels = settings.levels(settings.n_levels if centre else settings.uniformity_levels)
        block = [(x, y, float(lv), r) for r in range(settings.n_repeats) for lv in levels]
        rows += [block[i] for i in rng.permutation(len(block))]
    return pd.DataFrame(rows, columns=["x_norm", "y_norm", "level", "repeat"])


def load_or_create_settings(out_dir: Path, settings: ProcedureSettings, *,
                            given=None, file_name: str = "procedure.json",
                            command: str = "run") -> ProcedureSettings:
    """The run's settings: those in ``out_dir/procedure.json`` if it exists, else ``settings``.

    The file is written once (never replaced), so a rerun resumes the same schedule.

    Parameters
    ----------
    out_dir : path
    settings : ProcedureSettings
        The settings asked for.
    given : iterable of str or None
        Names of the settings the user gave explicitly (the others are taken from the stored
        file on a resume); None: every setting of :data:`PATCH_LIST_FIELDS`.
    file_name : str
        The settings file in ``out_dir``.
    command : str
        The command, for messages.

    Raises
    ------
    CalibrationError
        If the stored settings differ from ``settings`` in a field of :data:`PATCH_LIST_FIELDS`
        that was given: the message says what the folder was started with and the fix.
    """
    path = Path(out_dir) / file_name
    if path.is_file():
        try:
            stored = ProcedureSettings(**json.loads(path.read_text()))
        except (ValueError, TypeError) as exc:
            raise CalibrationError(f"{path} is malformed ({exc}); use a new --out") from exc
        names = PATCH_LIST_FIELDS if given is None else [n for n in given
                                                         if n in PATCH_LIST_FIELDS]
        for name in names:
            want, have = getattr(settings, name), getattr(stored, name)
            if want != have:
                flag = PATCH_LIST_FIELDS[name]
                if flag is None:
                    raise CalibrationError(
                        f"{out_dir} was started with {name} = {have!r}, not {want!r} (see "
                        f"{path}); resume with the same settings or use a new --out")
                raise CalibrationError(
                    f"{out_dir} was started with {flag} {have} (not {want}; see {path}): "
                    f"run `python -m calibration {command}` again with {flag} {have}, or "
                    f"without {flag}, to resume; or use a new --out for the new settings")
        return stored
    path.parent.mkdir(parents=True, exist_ok=True)
    write_new_file(path, json.dumps(asdict(settings), indent=2) + "\n")
    return settings


def settings_from_options(options: dict, out_dir, *, file_name: str = "procedure.json",
                          defaults: dict) -> tuple[ProcedureSettings, list[str]]:
    """Settings from command-line options, filled from a stored run to resume, else defaults.

    Parameters
    ----------
    options : dict
        Field name -> value; None for an option not given.
    defaults : dict
        Field name -> value for a new run.

    Returns
    -------
    (ProcedureSettings, list of the names given)
    """
    given = [k for k, v in options.items() if v is not None]
    path = Path(out_dir) / file_name
    base = dict(defaults)
    if path.is_file():
        try:
            base |= {k: v for k, v in json.loads(path.read_text()).items()
                     if k in {f.name for f in fields(ProcedureSettings)}}
        except ValueError as exc:
            raise CalibrationError(f"{path} is malformed ({exc}); use a new --out") from exc
    kw = base | {k: v for k, v in options.items() if v is not None}
    return ProcedureSettings(**kw), given


@contextmanager
def calibration_window(*, fullscr: bool = True, size_px=None, screen: int = 0):
    """A PsychoPy window in pixel units, closed on exit.

    Parameters
    ----------
    fullscr : bool
        Full screen (the lab: the CRT, in the design's mode); the window then has the
        screen's size.
    size_px : (int, int) or None
        Requested size.
    """
    from psychopy import logging, visual

    logging.console.setLevel(logging.ERROR)
    win = visual.Window(size=tuple(size_px) if size_px else (800, 600), fullscr=fullscr,
                        units="pix", color=(-1, -1, -1), colorSpace="rgb", allowGUI=False,
                        screen=screen, checkTiming=False, winType="pyglet")
    try:
        yield win
    finally:
        win.close()


class PatchDisplay:
    """Draws calibration patches and aiming targets in a PsychoPy window.

    Parameters
    ----------
    win : psychopy.visual.Window
        In pixel units.
    settings : ProcedureSettings
    sim_aim : path or None
        Simulation only: where to write the photometer's aim for the fake instrument, instead
        of asking the experimenter to move the photometer.
    """

    def __init__(self, win, settings: ProcedureSettings, sim_aim=None):
        from psychopy import visual

        self.win = win
        self.settings = settings
        self.sim_aim = Path(sim_aim) if sim_aim else None
        self.width_px, self.height_px = (int(v) for v in win.size)
        side = settings.patch_frac * self.height_px
        self._patch = visual.Rect(win, width=side, height=side, lineColor=None,
                                  colorSpace="rgb", units="pix")
        self._cross = visual.ShapeStim(
            win, vertices="cross", size=side / 3, fillColor=(1, -1, -1), lineColor=None,
            units="pix")
        self._text = visual.TextStim(win, text="", height=self.height_px / 30, units="pix",
                                     pos=(0, -0.42 * self.height_px), color=(1, 1, 1))

    def to_pix(self, x_norm: float, y_norm: float) -> tuple[float, float]:
        """Norm units -> window pixels (origin at the centre, y up)."""
        return x_norm * self.width_px / 2, y_norm * self.height_px / 2

    def _background(self) -> None:
        self.win.color = [2 * self.settings.background_level - 1] * 3

    def aim(self, x_norm: float, y_norm: float) -> None:
        """Ask for the photometer at a position (in simulation: write the aim file)."""
        from psychopy import event

        self._background()
        self._cross.pos = self.to_pix(x_norm, y_norm)
        if self.sim_aim is not None:
            x_px = round((x_norm + 1) / 2 * self.width_px)
            y_px = round((1 - y_norm) / 2 * self.height_px)
            atomic_write_text(self.sim_aim, json.dumps({"x_px": x_px, "y_px": y_px}))
            return
        self._text.text = ("Aim the photometer at the red cross and focus it, then press space "
                           "(escape stops; readings so far are kept)")
        event.clearEvents()
        while True:
            self._cross.draw()
            self._text.draw()
            self.win.flip()
            keys = event.getKeys(["space", "escape"])
            if "escape" in keys:
                raise CalibrationError("stopped by the experimenter; rerun to resume")
            if "space" in keys:
                return

    def show(self, x_norm: float, y_norm: float, level: float, *, settle: bool = True) -> None:
        """Show one patch and wait for it to settle (``settle=False``: the same patch again,
        already settled)."""
        from psychopy import event

        self._background()
        self._patch.pos = self.to_pix(x_norm, y_norm)
        self._patch.fillColor = [2 * level - 1] * 3
        self._patch.draw()
        self.win.flip()
        if event.getKeys(["escape"]):
            raise CalibrationError("stopped by the experimenter; rerun to resume")
        if settle:
            time.sleep(self.settings.settle_s)


def _measure_patch(photometer, display, settings, row, path, rejected_path, extra=None) -> dict:
    """Show one patch and read it; rejected replies are recorded and the patch remeasured."""
    base = {"calibration_id": settings.calibration_id, "device": settings.device,
            "x_norm": row["x_norm"], "y_norm": row["y_norm"], "level": row["level"],
            "repeat": int(row["repeat"])} | (extra or {})
    for _ in range(settings.max_rejects):
        display.show(row["x_norm"], row["y_norm"], row["level"])
        try:
            reading = photometer.measure()
        except BadReading as exc:
            append_row(rejected_path, base | {"timestamp_utc": utc_now_iso(),
                                              "luminance_cd_m2": "",
                                              "raw_reply": exc.raw_reply, "flag": exc.kind},
                       columns=REJECTED_COLUMNS)
            last = exc
            continue
        out = base | {"timestamp_utc": utc_now_iso(), "luminance_cd_m2": reading.luminance_cd_m2,
                      "raw_reply": reading.raw_reply}
        append_row(path, out, columns=READINGS_COLUMNS + tuple(extra or ()))
        return out
    raise CalibrationError(
        f"patch level {row['level']:.4f} at ({row['x_norm']}, {row['y_norm']}) was rejected "
        f"{settings.max_rejects} times ({last.kind}; last raw reply {last.raw_reply!r}); "
        "saturated: add a neutral-density filter or lower the white level; garbled: check the "
        "cable. Readings so far are kept; rerun to resume."
    )


def measure_schedule(photometer, display: PatchDisplay, settings: ProcedureSettings,
                     out_dir: Path, *, progress=print) -> pd.DataFrame:
    """Measure every patch of :func:`make_schedule` not yet in ``out_dir/readings.csv``.

    Returns
    -------
    DataFrame
        All readings of this calibration (earlier runs included).
    """
    out_dir = Path(out_dir)
    path, rejected = out_dir / "readings.csv", out_dir / "rejected.csv"
    schedule = make_schedule(settings)
    table = read_readings(path, own_file=True)
    for message in table.torn:
        progress(f"warning: {message}")
    done = table.frame[table.frame["calibration_id"] == settings.calibration_id]
    key = ["x_norm", "y_norm", "level", "repeat"]
    have = {tuple(np.round(r, 6)) for r in done[key].to_numpy(float)}
    todo = schedule[[tuple(np.round(r, 6)) not in have for r in schedule[key].to_numpy(float)]]
    progress(f"{settings.calibration_id}: {len(schedule) - len(todo)} of {len(schedule)} "
             f"readings already in {path}; measuring {len(todo)}")
    aimed = None
    for i, (_, row) in enumerate(todo.iterrows(), 1):
        if (row["x_norm"], row["y_norm"]) != aimed:
            aimed = (row["x_norm"], row["y_norm"])
            display.aim(*aimed)
        r = _measure_patch(photometer, display, settings, row, path, rejected)
        if i % 10 == 0 or i == len(todo):
            progress(f"  {i}/{len(todo)}: level {r['level']:.3f} at ({r['x_norm']:+.2f}, "
                     f"{r['y_norm']:+.2f}) -> {r['luminance_cd_m2']:.3f} cd/m^2")
    return read_readings(path, own_file=True).frame


def measure_validation(photometer, display: PatchDisplay, settings: ProcedureSettings,
                       calibration, out_dir: Path, *, progress=print) -> pd.DataFrame:
    """Measure gamma-corrected patches at the centre: fractions of the range, evenly spaced.

    Each row of ``validation.csv`` holds the drive used (``level``, from
    ``calibration.drive_for_fraction``) and its ``target_fraction``.
    """
    out_dir = Path(out_dir)
    path = out_dir / "validation.csv"
    fractions = np.linspace(0, 1, settings.n_validation)
    done = read_validation(path)
    have = set(np.round(done["target_fraction"].astype(float), 6)) if len(done) else set()
    display.aim(0.0, 0.0)
    for f in fractions:
        if round(float(f), 6) in have:
            continue
        drive = float(np.round(calibration.drive_for_fraction(f) * 255) / 255)
        row = {"x_norm": 0.0, "y_norm": 0.0, "level": drive, "repeat": 0}
        _measure_patch(photometer, display, settings, row, path, out_dir / "rejected.csv",
                       extra={"target_fraction": float(f)})
    progress(f"validation: {len(fractions)} corrected patches in {path}")
    frame = read_validation(path)
    return frame[frame["calibration_id"] == settings.calibration_id]


def read_validation(path) -> pd.DataFrame:
    """``validation.csv`` (torn-tail rule applied) with numeric columns; unusable rows dropped."""
    frame = read_record_csv(path, VALIDATION_COLUMNS)
    for c in ("x_norm", "y_norm", "level", "luminance_cd_m2", "target_fraction"):
        frame[c] = pd.to_numeric(frame[c], errors="coerce")
    return frame.dropna(subset=["level", "luminance_cd_m2", "target_fraction"]
                        ).reset_index(drop=True)
