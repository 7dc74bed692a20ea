"""Display calibration: photometers over serial, gamma and uniformity, PsychoPy monitor profiles.

Public API
----------
Calibration, load_calibration, save_calibration, default_calibration
    The calibration record (``calibration.json``); ``Calibration.drive_for_fraction`` is the
    inverse gamma used by stimuli tone mapping.
SimulatedCRT, load_crt
    The simulated display the fake photometer measures (parameters in ``crt.toml``).
GammaFit, fit_gamma, fit_gamma_models, choose_gamma_model, gamma_luminance,
gamma_drive_for_luminance
    Gamma models (PsychoPy eq. 1, 2 and 4, the extended power function, Psychtoolbox's sigmoid,
    Weibull and crtPolyLinear, a monotone spline), fitted by maximum likelihood with censored
    floor readings, chosen by held-out error (one-standard-error rule), misfits flagged.
NoiseModel, fit_noise
    Photometer noise SD^2 = a^2 + (b L)^2 from repeated readings (or the documented default),
    and the meter's floor.
UniformityMap, fit_uniformity
    Spatial uniformity and correction gains.
READINGS_COLUMNS, REQUIRED_COLUMNS, load_readings, read_readings, ReadingsTable
    Columns of ``readings.csv`` and of another tool's readings file; readers that report every
    row they cannot use.
CalibrationError, PhotometerError, PhotometerNotFound, PhotometerTimeout, BadReading
    Errors (all ``ValueError`` subclasses).
available_ports
    Serial ports the system reports.
"""

from calibration.crt import SimulatedCRT, default_crt_path, load_crt
from calibration.errors import (
    BadReading,
    CalibrationError,
    PhotometerError,
    PhotometerNotFound,
    PhotometerTimeout,
)
from calibration.gamma import (
    GAMMA_MODELS,
    GammaFit,
    choose_gamma_model,
    fit_gamma,
    fit_gamma_models,
    gamma_drive_for_luminance,
    gamma_luminance,
)
from calibration.noise import NoiseModel, fit_noise
from calibration.ports import available_ports
from calibration.readings import (
    READINGS_COLUMNS,
    REQUIRED_COLUMNS,
    ReadingsTable,
    load_readings,
    read_readings,
)
from calibration.record import (
    DEFAULT_CRT,
    Calibration,
    default_calibration,
    load_calibration,
    save_calibration,
)
from calibration.uniformity import UniformityMap, fit_uniformity

__all__ = [
    "DEFAULT_CRT",
    "GAMMA_MODELS",
    "READINGS_COLUMNS",
    "REQUIRED_COLUMNS",
    "BadReading",
    "Calibration",
    "CalibrationError",
    "GammaFit",
    "NoiseModel",
    "PhotometerError",
    "PhotometerNotFound",
    "PhotometerTimeout",
    "ReadingsTable",
    "SimulatedCRT",
    "UniformityMap",
    "available_ports",
    "choose_gamma_model",
    "default_calibration",
    "default_crt_path",
    "fit_gamma",
    "fit_gamma_models",
    "fit_noise",
    "fit_uniformity",
    "gamma_drive_for_luminance",
    "gamma_luminance",
    "load_calibration",
    "load_crt",
    "load_readings",
    "read_readings",
    "save_calibration",
]
