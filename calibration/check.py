"""A check run: measure a few patches against an existing calibration, without refitting.

``python -m calibration check --calibration CAL --device pr655 --port /dev/ttyUSB0 --out DIR``

1. **Warm-up.** A white patch (level 1) at the centre is read every ``interval_s`` from the
   start (switch the CRT on, then start the check) until the display is stable by
   :class:`WarmupRule`, or ``max_s`` has passed. Each reading is appended to ``DIR/warmup.csv``
   at once (:data:`calibration.readings.READINGS_COLUMNS`; ``repeat`` = index in time).
2. **Patches.** Levels at the centre and at a grid of positions, as the calibration procedure
   shows them (:func:`calibration.procedure.make_schedule`), appended to ``DIR/readings.csv``
   with the check's own ``calibration_id`` (default ``<checked id>-check-<UTC time>``).
3. **Deviation.** Each patch's mean reading against the calibration's prediction there
   (:func:`check_deviation`), in cd/m^2 and % of the prediction, passed or failed by a tolerance;
   written to ``DIR/check.json`` (and ``DIR/check_report.txt``).

A rerun with the same ``--out`` resumes (the settings are kept in ``DIR/procedure.json``); a
warm-up already found stable is not repeated. The folder is locked while a check writes into it.

``check.json``::

    {"kind": "check", "check_id", "checked_calibration_id", "checked_calibration" (path),
     "created_utc" (time of the newest reading), "passed", "tolerance": {"pct", "cd_m2"},
     "deviation": [{"x_norm", "y_norm", "level", "n", "measured_cd_m2", "predicted_cd_m2",
                    "deviation_cd_m2", "deviation_pct", "pass"}, ...],
     "warmup": {"stable", "stable_after_s", "rule": {...}, "n_readings", "last_change_pct"},
     "warnings": [...]}
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from calibration.errors import BadReading, CalibrationError
from calibration.photometers import open_photometer
from calibration.procedure import (
    PatchDisplay,
    ProcedureSettings,
    calibration_window,
    load_or_create_settings,
    measure_schedule,
)
from calibration.readings import (
    REJECTED_COLUMNS,
    append_row,
    newest_timestamp,
    parse_utc,
    read_readings,
)
from calibration.record import Calibration, load_calibration, utc_now_iso
from labfiles import FolderLock, atomic_write_text, write_new_file
from labfiles.clock import future_problem

__all__ = [
    "CHECK_DEFAULTS",
    "WarmupRule",
    "check_deviation",
    "check_report_text",
    "default_check_id",
    "measure_warmup",
    "predicted_luminance",
    "run_check",
    "warmup_stability",
]

#: The check's patches when no option is given: 5 levels x 2 repeats at the centre, 3 levels
#: (black, mid, white) x 2 repeats at the other 8 positions of a 3 x 3 grid; no validation.
CHECK_DEFAULTS = {"n_levels": 5, "uniformity_levels": 3, "n_repeats": 2, "grid": 3,
                  "n_validation": 0, "seed": 20261123}


@dataclass(frozen=True)
class WarmupRule:
    """When a warming display counts as stable.

    After each white reading at time t (s since the first), the mean of the readings in the last
    ``window_s`` (t - window_s, t] is compared with the mean of the window before it
    (t - 2 window_s, t - window_s]; the display is stable at the first t where they differ by at
    most ``tolerance_pct`` % (each window holding >= 2 readings). Comparing means of windows,
    not single readings, keeps the photometer's noise (about 0.3 % per reading) from deciding.

    Attributes
    ----------
    interval_s : float
        Time between white readings, s (lab default 10 s).
    window_s : float
        Length of each window, s (lab default 120 s).
    tolerance_pct : float
        Largest change of the window mean counted as stable, % (default 0.5 %).
    max_s : float
        Give up after this long, s (default 3600 s); the check then reports ``stable: false``
        and measures the patches anyway.
    """

    interval_s: float = 10.0
    window_s: float = 120.0
    tolerance_pct: float = 0.5
    max_s: float = 3600.0

    def __post_init__(self) -> None:
        for name in ("interval_s", "window_s", "tolerance_pct", "max_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise CalibrationError(f"warm-up rule: {name} must be a positive number of "
                                       f"{'%' if name == 'tolerance_pct' else 's'}, got {v!r}")
        if self.window_s < 2 * self.interval_s:
            raise CalibrationError(
                f"warm-up rule: window_s ({self.window_s:g} s) must hold at least 2 readings "
                f"(>= 2 x interval_s = {2 * self.interval_s:g} s)")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["text"] = (f"stable when the mean white luminance of the last {self.window_s:g} s "
                     f"differs from that of the {self.window_s:g} s before by <= "
                     f"{self.tolerance_pct:g} % (a reading every {self.interval_s:g} s, at most "
                     f"{self.max_s:g} s)")
        return d


def warmup_stability(t_s, luminance_cd_m2, rule: WarmupRule) -> tuple[float | None, float]:
    """When the display became stable by ``rule``.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Times of the white readings, s (any origin; increasing).
    luminance_cd_m2 : array_like, shape (n,)
    rule : WarmupRule

    Returns
    -------
    stable_after_s : float or None
        Time of the first reading at which the rule holds, s after the first reading; None if
        it never holds.
    last_change_pct : float or None
        The change between the last two windows, % (None while fewer than two windows exist).
    """
    t = np.asarray(t_s, float)
    lum = np.asarray(luminance_cd_m2, float)
    if t.shape != lum.shape:
        raise ValueError(f"t_s {t.shape} and luminance_cd_m2 {lum.shape} differ in shape")
    change = math.nan
    for i in range(t.size):
        last = (t > t[i] - rule.window_s) & (t <= t[i])
        prev = (t > t[i] - 2 * rule.window_s) & (t <= t[i] - rule.window_s)
        if last.sum() < 2 or prev.sum() < 2 or t[i] - t[0] < 2 * rule.window_s - rule.interval_s:
            continue
        m = lum[last].mean()
        change = 100 * abs(m - lum[prev].mean()) / m
        if change <= rule.tolerance_pct:
            return float(t[i] - t[0]), float(change)
    return None, (None if math.isnan(change) else float(change))


def _times_s(frame: pd.DataFrame) -> np.ndarray:
    t = pd.to_datetime(frame["timestamp_utc"], utc=True, format="ISO8601")
    return (t - t.min()).dt.total_seconds().to_numpy(float)


def measure_warmup(photometer, display: PatchDisplay, rule: WarmupRule, path, *,
                   check_id: str, device: str, rejected_path=None, progress=print,
                   clock=time.monotonic) -> dict:
    """Read white at the centre every ``rule.interval_s`` until stable (or ``rule.max_s``).

    Each reading is appended to ``path`` at once. Readings already in ``path`` (a resumed
    check) count: if they show the display stable, nothing is measured.

    Returns
    -------
    dict
        ``stable``, ``stable_after_s`` (s after the first warm-up reading, or None), ``rule``,
        ``n_readings``, ``last_change_pct``.
    """
    path = Path(path)
    done = read_readings(path, own_file=True).frame
    done = done[done["calibration_id"] == check_id]
    newest, _ = newest_timestamp(done)
    problem = newest and future_problem(parse_utc(newest), f"{path}: newest timestamp_utc")
    if problem:  # the resumed warm-up's times would count backwards
        raise CalibrationError(f"{problem}; or start the check in a new --out")
    t_done = _times_s(done) if len(done) else np.array([])
    stable_after, change = warmup_stability(t_done, done["luminance_cd_m2"], rule)
    result = {"rule": rule.to_dict()}
    if stable_after is not None:
        progress(f"warm-up: already stable after {stable_after:.1f} s ({path})")
        return result | {"stable": True, "stable_after_s": stable_after,
                         "n_readings": len(done), "last_change_pct": change}
    display.aim(0.0, 0.0)
    index = int(done["repeat"].max()) + 1 if len(done) else 0
    times = list(t_done)
    lums = list(done["luminance_cd_m2"].astype(float))
    # Times count from the first warm-up reading, across a resume (the pause included).
    offset = 0.0
    if len(done):
        first = pd.to_datetime(done["timestamp_utc"], utc=True, format="ISO8601").min()
        offset = (pd.Timestamp.now(tz="UTC") - first).total_seconds()
    start = clock()
    progress(f"warm-up: white at the centre every {rule.interval_s:g} s until stable "
             f"(<= {rule.tolerance_pct:g} % over {rule.window_s:g} s), at most "
             f"{rule.max_s:g} s")
    settled = False
    while True:
        # Shown again before each reading (settled once): the window stays responsive and
        # escape stops.
        display.show(0.0, 0.0, 1.0, settle=not settled)
        settled = True
        t_read = clock()
        try:
            reading = photometer.measure()
        except BadReading as exc:
            if rejected_path is not None:
                append_row(rejected_path, {
                    "calibration_id": check_id, "timestamp_utc": utc_now_iso(),
                    "device": device, "x_norm": 0.0, "y_norm": 0.0, "level": 1.0,
                    "repeat": index, "luminance_cd_m2": "", "raw_reply": exc.raw_reply,
                    "flag": exc.kind}, columns=REJECTED_COLUMNS)
        else:
            append_row(path, {"calibration_id": check_id, "timestamp_utc": utc_now_iso(),
                              "device": device, "x_norm": 0.0, "y_norm": 0.0, "level": 1.0,
                              "repeat": index, "luminance_cd_m2": reading.luminance_cd_m2,
                              "raw_reply": reading.raw_reply})
            times.append(offset + t_read - start)
            lums.append(reading.luminance_cd_m2)
            index += 1
            _check_spacing(times[len(t_done):], rule)  # this session's readings only
            stable_after, change = warmup_stability(times, lums, rule)
            if stable_after is not None:
                progress(f"warm-up: stable after {stable_after:.1f} s (change {change:.2f} %, "
                         f"{len(times)} readings in {path})")
                return result | {"stable": True, "stable_after_s": stable_after,
                                 "n_readings": len(times), "last_change_pct": change}
        if clock() - start >= rule.max_s:
            shown = "n/a" if change is None else f"{change:.2f} %"
            progress(f"warm-up: NOT stable after {rule.max_s:g} s (last change {shown}); "
                     "the patches are measured anyway: check again later")
            return result | {"stable": False, "stable_after_s": None,
                             "n_readings": len(times), "last_change_pct": change}
        time.sleep(max(0.0, rule.interval_s - (clock() - t_read)))


def _check_spacing(times: list, rule: WarmupRule) -> None:
    """Stop if readings come too slowly for the rule's windows to hold two each."""
    if len(times) < 4:
        return
    spacing = float(np.median(np.diff(times[-4:])))
    if spacing > rule.window_s / 2:
        raise CalibrationError(
            f"warm-up readings come every {spacing:.2f} s (the instrument's measuring time), "
            f"too slowly for {rule.window_s:g}-s windows of >= 2 readings; pass "
            f"--warmup-window-s {math.ceil(4 * spacing):g} or more. The readings so far are "
            "kept; rerun to resume")


def predicted_luminance(cal: Calibration, level, x_norm, y_norm) -> np.ndarray:
    """Luminance the calibration predicts at drive ``level`` and a position, cd/m^2.

    Light above black scales with the uniformity map's relative luminance there
    (``min(relative) / gain``); without a map the screen is taken as uniform.
    """
    lum = np.asarray(cal.luminance_for_drive(np.asarray(level, float)), float)
    if cal.uniformity is None:
        return lum
    rel0 = float(np.min(np.asarray(cal.uniformity.relative, float)))
    rel = rel0 / np.asarray(cal.uniformity.gain_at(x_norm, y_norm), float)
    return cal.min_luminance_cd_m2 + (lum - cal.min_luminance_cd_m2) * rel


def check_deviation(readings: pd.DataFrame, cal: Calibration, *, tolerance_pct: float,
                    tolerance_cd_m2: float) -> list[dict]:
    """Per patch: the mean reading against the calibration's prediction.

    Parameters
    ----------
    readings : DataFrame
        Columns x_norm, y_norm, level, luminance_cd_m2.
    cal : Calibration
    tolerance_pct : float
        A patch passes if its deviation is within this % of the prediction ...
    tolerance_cd_m2 : float
        ... or within this many cd/m^2 (for the darkest patches, where a % of a small
        luminance is below the photometer's resolution).

    Returns
    -------
    list of dict
        One per (x_norm, y_norm, level), sorted: ``n``, ``measured_cd_m2`` (mean),
        ``predicted_cd_m2``, ``deviation_cd_m2`` (measured - predicted), ``deviation_pct``
        (% of predicted), ``pass``.
    """
    out = []
    for (x, y, level), grp in readings.groupby(["x_norm", "y_norm", "level"], sort=True):
        measured = float(grp["luminance_cd_m2"].astype(float).mean())
        pred = float(np.ravel(predicted_luminance(cal, level, x, y))[0])
        dev = measured - pred
        pct = 100 * dev / pred if pred > 0 else math.inf
        out.append({"x_norm": float(x), "y_norm": float(y), "level": float(level),
                    "n": len(grp), "measured_cd_m2": measured, "predicted_cd_m2": pred,
                    "deviation_cd_m2": dev, "deviation_pct": pct,
                    "pass": bool(abs(pct) <= tolerance_pct or abs(dev) <= tolerance_cd_m2)})
    return out


def default_check_id(checked_id: str, now: datetime | None = None) -> str:
    """``<checked id>-check-<UTC time>``."""
    now = now or datetime.now(UTC)
    return f"{checked_id}-check-{now.strftime('%Y%m%dT%H%M%SZ')}"


def check_report_text(result: dict) -> str:
    """A plain-text summary of ``check.json``."""
    w = result["warmup"]
    tol = result["tolerance"]
    lines = [
        (f"Check {result['check_id']} of calibration {result['checked_calibration_id']} "
        f"({result['checked_calibration']}), readings up to {result['created_utc']}"),
        ("warm-up: stable after "
         f"{w['stable_after_s']:.1f} s" if w["stable"] else
         f"warm-up: NOT stable within {w['rule']['max_s']:g} s") + f" ({w['rule']['text']})",
        "",
        (f"patch (x, y, level)      n  measured  predicted  deviation (cd/m^2, %)   "
        f"tolerance {tol['pct']:g} % or {tol['cd_m2']:g} cd/m^2"),
    ]
    for d in result["deviation"]:
        lines.append(f"  ({d['x_norm']:+.2f}, {d['y_norm']:+.2f}, {d['level']:.3f})  {d['n']:3d}"
                     f"  {d['measured_cd_m2']:8.3f}  {d['predicted_cd_m2']:9.3f}  "
                     f"{d['deviation_cd_m2']:+8.3f}  {d['deviation_pct']:+7.2f} %  "
                     f"{'pass' if d['pass'] else 'FAIL'}")
    n_fail = sum(not d["pass"] for d in result["deviation"])
    lines += ["", "result: " + ("PASS (every patch within tolerance)" if result["passed"] else
                                f"FAIL ({n_fail} patch(es) outside tolerance: recalibrate)")]
    lines += [f"warning: {w}" for w in result["warnings"]]
    return "\n".join(lines) + "\n"


def _same_checked_calibration(out_dir: Path, cal: Calibration, cal_path: Path) -> None:
    """Record which calibration a check folder checks (once); refuse a resume against another."""
    path = out_dir / "checked.json"
    if path.is_file():
        stored = json.loads(path.read_text(encoding="utf-8"))
        if stored.get("checked_calibration_id") != cal.calibration_id:
            raise CalibrationError(
                f"{out_dir} checks calibration {stored.get('checked_calibration_id')!r} "
                f"({stored.get('checked_calibration')}), not {cal.calibration_id!r}; resume with "
                "that --calibration or use a new --out")
        return
    write_new_file(path, json.dumps({"checked_calibration_id": cal.calibration_id,
                                     "checked_calibration": str(cal_path.resolve())}) + "\n")


def _refuse_calibration_folder(out_dir: Path, cal: Calibration, cal_path: Path,
                               settings: ProcedureSettings) -> None:
    """A check measures its own patches: its folder is never a calibration's folder (whose
    readings it would "resume" and score against their own fit), nor its id the checked one's.

    Raises
    ------
    CalibrationError
        ``out_dir`` is the checked calibration's folder, holds a calibration (or a calibration
        run's readings without ``checked.json``), or the check's id is the checked one's.
    """
    def what_to_type():
        return (f"give the check a folder of its own, e.g. --out "
                f"{cal_path.parent.parent / (cal_path.parent.name + '-check')}")

    same = out_dir.exists() and out_dir.resolve() == cal_path.parent.resolve()
    if same or (out_dir / "calibration.json").exists():
        raise CalibrationError(
            f"--out {out_dir} is a calibration's folder: a check there would score the "
            f"calibration's own readings against their own fit instead of measuring; "
            f"{what_to_type()}")
    if (out_dir / "run_meta.json").exists() or ((out_dir / "procedure.json").exists()
                                                and not (out_dir / "checked.json").exists()):
        raise CalibrationError(
            f"--out {out_dir} holds a calibration run's readings (run_meta.json or "
            f"procedure.json without checked.json), not a check's; {what_to_type()}")
    if settings.calibration_id == cal.calibration_id:
        raise CalibrationError(
            f"the check's id {settings.calibration_id!r} is the checked calibration's: its "
            "readings would be taken for the calibration's own; leave --calibration-id out "
            "(default <checked id>-check-<UTC time>) or give another id")


def run_check(calibration_path, *, device: str, port: str, out_dir,
              settings: ProcedureSettings, rule: WarmupRule, tolerance_pct: float = 3.0,
              tolerance_cd_m2: float = 0.05, timeout_s: float = 30.0, retries: int = 2,
              fullscr: bool = True, sim_aim=None, given=None, progress=print) -> dict:
    """Warm-up, patches and deviation against ``calibration_path``; writes ``out_dir``.

    Parameters
    ----------
    calibration_path : path
        ``calibration.json`` or its folder.
    settings : ProcedureSettings
        The patches (``calibration_id`` is the check's id); a resumed check keeps its stored
        ones (``given``: see :func:`calibration.procedure.load_or_create_settings`).
    rule : WarmupRule
    tolerance_pct, tolerance_cd_m2 : float
        Pass/fail tolerance of a patch (:func:`check_deviation`).

    Returns
    -------
    dict
        The content of ``check.json``.

    Raises
    ------
    CalibrationError
        Unreadable calibration, photometer problems (readings so far are kept), or a folder
        locked by another run.
    """
    if not (tolerance_pct > 0 and tolerance_cd_m2 >= 0):
        raise CalibrationError("--tolerance-pct must be > 0 and --tolerance-cd-m2 >= 0")
    cal_path = Path(calibration_path)
    cal = load_calibration(cal_path)
    if cal_path.is_dir():
        cal_path = cal_path / "calibration.json"
    out_dir = Path(out_dir)
    _refuse_calibration_folder(out_dir, cal, cal_path, settings)
    with FolderLock(out_dir, what="check folder"):
        _same_checked_calibration(out_dir, cal, cal_path)
        settings = load_or_create_settings(out_dir, settings, given=given, command="check")
        _refuse_calibration_folder(out_dir, cal, cal_path, settings)
        with open_photometer(device, port, timeout_s=timeout_s, retries=retries) as phot, \
                calibration_window(fullscr=fullscr, size_px=cal.resolution_px) as win:
            display = PatchDisplay(win, settings, sim_aim=sim_aim)
            warmup = measure_warmup(phot, display, rule, out_dir / "warmup.csv",
                                    check_id=settings.calibration_id, device=device,
                                    rejected_path=out_dir / "rejected.csv", progress=progress)
            measure_schedule(phot, display, settings, out_dir, progress=progress)
        readings = read_readings(out_dir / "readings.csv", own_file=True).frame
        readings = readings[readings["calibration_id"] == settings.calibration_id]
        warm = read_readings(out_dir / "warmup.csv", own_file=True).frame
        newest, _ = newest_timestamp(pd.concat([readings, warm]))
        warn = []
        if cal.uniformity is None and (readings[["x_norm", "y_norm"]] != 0).any(axis=None):
            warn.append("the calibration has no uniformity map: off-centre patches are "
                        "predicted as if the screen were uniform")
        if not warmup["stable"]:
            warn.append(f"the display was not stable after {rule.max_s:g} s of warm-up")
        deviation = check_deviation(readings, cal, tolerance_pct=tolerance_pct,
                                    tolerance_cd_m2=tolerance_cd_m2)
        result = {
            "kind": "check",
            "check_id": settings.calibration_id,
            "checked_calibration_id": cal.calibration_id,
            "checked_calibration": str(cal_path.resolve()),
            "created_utc": newest,
            "device": device,
            "instrument": phot.info(),
            "passed": all(d["pass"] for d in deviation),
            "tolerance": {"pct": tolerance_pct, "cd_m2": tolerance_cd_m2},
            "deviation": deviation,
            "warmup": warmup,
            "readings_file": "readings.csv",
            "warmup_file": "warmup.csv",
            "warnings": warn,
        }
        atomic_write_text(out_dir / "check.json", json.dumps(result, indent=2) + "\n")
        atomic_write_text(out_dir / "check_report.txt", check_report_text(result))
    progress(check_report_text(result))
    return result

