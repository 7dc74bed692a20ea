"""The calibration result: one frozen record, saved as ``calibration.json``.

Stimuli take their gamma correction from :meth:`Calibration.drive_for_fraction`; the display
layer of the sim-to-real diagnosis compares :meth:`Calibration.luminance_for_drive` with the
simulated CRT and the raw readings.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from calibration.errors import CalibrationError
from calibration.gamma import (
    GAMMA_MODELS,
    GammaFit,
    gamma_drive_for_luminance,
    gamma_luminance,
)
from calibration.readings import parse_utc
from calibration.uniformity import UniformityMap
from labfiles import atomic_write_text
from labfiles.clock import future_problem

__all__ = [
    "DEFAULT_CRT",
    "SCHEMA_VERSION",
    "Calibration",
    "default_calibration",
    "load_calibration",
    "save_calibration",
    "utc_now_iso",
]

SCHEMA_VERSION = 1

#: The default CRT curve used before any measurement (documented in protocol.md section 3):
#: a typical 17-inch CRT (visible width 32 cm of its 4:3 picture), black 0.5 cd/m^2 (emitted
#: black plus reflected room light), white 100 cd/m^2, gamma 2.2, PsychoPy's eq. 4 with b = 0.
DEFAULT_CRT = {
    "width_cm": 32.0,
    "black_cd_m2": 0.5,
    "white_cd_m2": 100.0,
    "gamma": 2.2,
}


def utc_now_iso() -> str:
    """Current UTC time as ``YYYY-MM-DDTHH:MM:SS.ffffffZ``."""
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


@dataclass(frozen=True)
class Calibration:
    """A display calibration: geometry, the chosen gamma model, uniformity, provenance.

    Attributes
    ----------
    calibration_id : str
        Identifier (also written in every readings row); ``"default"`` for the default curve.
    created_utc : str
        When this record was written (the fit was made), ISO 8601 UTC. A refit of old readings
        gets a new ``created_utc`` but keeps ``measured_utc``.
    measured_utc : str or None
        When the newest reading the fit used was taken, ISO 8601 UTC: the calibration's age
        (:meth:`age_days`) counts from here. None in records written before it existed and
        for readings without times; the age then counts from ``created_utc``.
    device : str
        Photometer (``"pr655"``, ``"pr650"``, ``"ls100"``) or ``"none"`` for the default.
    monitor_name : str
        Name of the PsychoPy Monitor profile written with it.
    resolution_px : tuple[int, int]
        Width, height in pixels.
    width_cm : float
        Visible width of the picture, cm.
    distance_cm : float
        Viewing distance, cm.
    refresh_hz : float
        Refresh rate measured by the procedure (the nominal one where it could not be measured;
        then ``warnings`` says so).
    gamma_model : str
        Chosen model (:data:`calibration.gamma.GAMMA_MODELS`).
    gamma_params : dict[str, float]
        Its parameters.
    min_luminance_cd_m2, max_luminance_cd_m2 : float
        The model's luminance at drive 0 and 1 (screen centre).
    fits : tuple[GammaFit, ...]
        Every model fitted, with residuals and held-out errors.
    uniformity : UniformityMap or None
        Relative luminance and correction gain over the screen.
    validation_max_deviation_pct : float or None
        Largest deviation of the gamma-corrected validation readings from linear luminance, in %
        of the luminance range.
    warnings : tuple[str, ...]
        Everything the report flags (non-monotonic curve, rejected readings, assumed refresh).
    instrument : dict
        Port, serial settings and the instrument's identification, as recorded.
    readings_file : str
        The readings CSV the fit used (relative to the calibration folder).
    schema_version : int
    """

    calibration_id: str
    created_utc: str
    device: str
    monitor_name: str
    resolution_px: tuple
    width_cm: float
    distance_cm: float
    refresh_hz: float
    gamma_model: str
    gamma_params: dict
    min_luminance_cd_m2: float
    max_luminance_cd_m2: float
    fits: tuple = ()
    uniformity: UniformityMap | None = None
    validation_max_deviation_pct: float | None = None
    warnings: tuple = ()
    instrument: dict = field(default_factory=dict)
    readings_file: str = ""
    measured_utc: str | None = None
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        if self.gamma_model not in GAMMA_MODELS:
            raise CalibrationError(
                f"gamma_model {self.gamma_model!r} is unknown; use one of {sorted(GAMMA_MODELS)}"
            )
        missing = [p for p in GAMMA_MODELS[self.gamma_model] if p not in self.gamma_params]
        if missing:
            raise CalibrationError(f"gamma_params lack {missing} for model {self.gamma_model!r}")
        if len(self.resolution_px) != 2 or min(self.resolution_px) <= 0:
            raise CalibrationError(
                f"resolution_px must be (width, height) > 0, got {self.resolution_px}"
            )
        for name in ("width_cm", "distance_cm", "refresh_hz"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise CalibrationError(f"{name} must be a positive number, got {v!r}")
        if not self.max_luminance_cd_m2 > self.min_luminance_cd_m2:
            raise CalibrationError(
                f"max_luminance_cd_m2 ({self.max_luminance_cd_m2}) must exceed "
                f"min_luminance_cd_m2 ({self.min_luminance_cd_m2}); the fit is unusable"
            )
        for name in ("created_utc", "measured_utc"):
            text = getattr(self, name)
            if text is None:
                continue
            problem = future_problem(parse_utc(text, name),
                                     f"calibration {self.calibration_id!r}: {name}")
            if problem:
                raise CalibrationError(
                    f"{problem} (refit the readings with their true time into a new folder: "
                    "`python -m calibration fit READINGS.csv --measured-utc TIME --out NEW`)")

    # --- the display model -------------------------------------------------------------------
    def luminance_for_drive(self, drive) -> np.ndarray:
        """Luminance (cd/m^2, screen centre) the display produces at drive values in [0, 1]."""
        return gamma_luminance(drive, model=self.gamma_model, params=self.gamma_params)

    def drive_for_fraction(self, fraction) -> np.ndarray:
        """Inverse gamma: the drive that gives a fraction of the display's luminance range.

        Parameters
        ----------
        fraction : array_like
            Wanted luminance as a fraction of [min_luminance_cd_m2, max_luminance_cd_m2];
            values outside [0, 1] are clipped.

        Returns
        -------
        ndarray
            Drive values in [0, 1] (multiply by 255 for 8-bit values); 0 maps to 0, 1 to 1.
        """
        f = np.clip(np.asarray(fraction, dtype=float), 0.0, 1.0)
        lum = self.min_luminance_cd_m2 + f * (self.max_luminance_cd_m2 - self.min_luminance_cd_m2)
        drive = gamma_drive_for_luminance(lum, model=self.gamma_model, params=self.gamma_params)
        return np.where(f >= 1.0, 1.0, np.where(f <= 0.0, 0.0, drive))

    @property
    def age_from_utc(self) -> str:
        """The time the age counts from: ``measured_utc``, or ``created_utc`` without it."""
        return self.measured_utc if self.measured_utc is not None else self.created_utc

    def age_days(self, now: datetime | None = None) -> float:
        """Days since the newest reading was taken (``measured_utc``; ``created_utc`` in
        records without it). ``now`` defaults to the current UTC time.

        A refit never makes a calibration younger: only a new measurement does.
        """
        now = now or datetime.now(UTC)
        if now.tzinfo is None:
            raise CalibrationError("now must carry a time zone (use datetime.now(timezone.utc))")
        return (now - parse_utc(self.age_from_utc)).total_seconds() / 86400.0

    @property
    def display_model(self) -> dict:
        """What a stimulus's gamma correction depends on: ``gamma_model``, ``gamma_params``,
        ``min_luminance_cd_m2``, ``max_luminance_cd_m2`` (recorded by a session; described by
        :func:`display_model_words`)."""
        return {"gamma_model": self.gamma_model, "gamma_params": dict(self.gamma_params),
                "min_luminance_cd_m2": self.min_luminance_cd_m2,
                "max_luminance_cd_m2": self.max_luminance_cd_m2}

    @property
    def chosen_fit(self) -> GammaFit | None:
        """The :class:`GammaFit` of the chosen model, if the fits were recorded."""
        return next((f for f in self.fits if f.model == self.gamma_model), None)

    # --- JSON ----------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = asdict(self)
        d["resolution_px"] = list(self.resolution_px)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False)

    @classmethod
    def from_dict(cls, d: dict) -> Calibration:
        if not isinstance(d, dict):
            raise CalibrationError(f"calibration must be a JSON object, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise CalibrationError(f"calibration has unknown key(s) {unknown}")
        try:
            kw = dict(d)
            kw["resolution_px"] = tuple(int(v) for v in d["resolution_px"])
            kw["gamma_params"] = {k: float(v) for k, v in d["gamma_params"].items()}
            kw["fits"] = tuple(GammaFit.from_dict(f) for f in d.get("fits", ()))
            u = d.get("uniformity")
            kw["uniformity"] = None if u is None else UniformityMap.from_dict(u)
            kw["warnings"] = tuple(str(w) for w in d.get("warnings", ()))
            for name in ("width_cm", "distance_cm", "refresh_hz", "min_luminance_cd_m2",
                         "max_luminance_cd_m2"):
                kw[name] = float(d[name])
            return cls(**kw)
        except KeyError as exc:
            raise CalibrationError(f"calibration lacks key {exc.args[0]!r}") from exc
        except (TypeError, AttributeError, ValueError) as exc:
            if isinstance(exc, CalibrationError):
                raise
            raise CalibrationError(f"calibration is malformed ({exc})") from exc


def display_model_words(model: dict) -> str:
    """A :attr:`Calibration.display_model` in words, e.g. ``"black 0.50, white 95.0 cd/m^2,
    offset_power gamma 2.40"`` (a model without a ``gamma`` parameter is named alone)."""
    gamma = model.get("gamma_params", {}).get("gamma")
    curve = model.get("gamma_model", "?") + ("" if gamma is None else f" gamma {gamma:.2f}")
    return (f"black {model.get('min_luminance_cd_m2', float('nan')):.2f}, white "
            f"{model.get('max_luminance_cd_m2', float('nan')):.1f} cd/m^2, {curve}")


def load_calibration(path) -> Calibration:
    """Read a ``calibration.json``.

    Raises
    ------
    CalibrationError
        If the file is missing, not JSON, or not a valid calibration (the message names the
        path and the problem).
    """
    path = Path(path)
    if path.is_dir():
        path = path / "calibration.json"
    if not path.is_file():
        raise CalibrationError(
            f"calibration file {path} not found; run `python -m calibration run` or use "
            "calibration.default_calibration(design)"
        )
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"calibration file {path} is not valid JSON ({exc})") from exc
    try:
        return Calibration.from_dict(d)
    except CalibrationError as exc:
        raise CalibrationError(f"calibration file {path}: {exc}") from exc


def save_calibration(cal: Calibration, path) -> Path:
    """Write ``cal`` as JSON atomically, with the umask's permissions (:mod:`labfiles`).

    Returns the path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(path, cal.to_json() + "\n")


def default_calibration(design) -> Calibration:
    """The default CRT curve, so stimuli can be rendered before any measurement.

    Numbers (:data:`DEFAULT_CRT`, protocol.md section 3): PsychoPy eq. 4 with a = 0.5 cd/m^2,
    b = 0, k = (100 - 0.5)^(1/2.2), gamma = 2.2 (so white is 100 cd/m^2), visible width 32 cm,
    the design's resolution, viewing distance and nominal refresh rate; no uniformity map.

    Parameters
    ----------
    design : studydesign.StudyDesign
    """
    c = DEFAULT_CRT
    g = c["gamma"]
    params = {"a": c["black_cd_m2"], "b": 0.0,
              "k": (c["white_cd_m2"] - c["black_cd_m2"]) ** (1 / g), "gamma": g}
    return Calibration(
        calibration_id="default",
        created_utc="1970-01-01T00:00:00Z",
        device="none",
        monitor_name="glossdepth-default",
        resolution_px=tuple(design.display.resolution_px),
        width_cm=c["width_cm"],
        distance_cm=design.display.viewing_distance_cm,
        refresh_hz=design.display.nominal_refresh_hz,
        gamma_model="offset_power",
        gamma_params=params,
        min_luminance_cd_m2=float(gamma_luminance(0.0, model="offset_power", params=params)),
        max_luminance_cd_m2=float(gamma_luminance(1.0, model="offset_power", params=params)),
        warnings=("default curve, not measured: calibrate the display before a session",),
    )
