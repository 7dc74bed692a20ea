"""Display calibration: photometers over serial, gamma and uniformity, PsychoPy monitor profiles.

Public API
----------
The names below are what code outside the package uses (the experiment, the stimuli, the gap
diagnosis, the benchmarks). Everything else is imported from its module: ``calibration.readings``
(``read_readings``, ``ReadingsTable``, ``REQUIRED_COLUMNS``: another tool's readings file, every
row accounted for; ``parse_utc``: the one rule for a recorded ISO 8601 time), ``calibration.noise`` (``NoiseModel``, ``fit_noise``: photometer noise
SD^2 = a^2 + (b L)^2 and the meter's floor), ``calibration.gamma`` (``GAMMA_MODELS``),
``calibration.crt`` (``default_crt_path``), ``calibration.uniformity`` (``UniformityMap``),
``calibration.ports`` (``available_ports``).

Calibration, load_calibration, save_calibration, default_calibration, display_model_words
    The calibration record (``calibration.json``); ``Calibration.drive_for_fraction`` is the
    inverse gamma used by stimuli tone mapping; ``Calibration.display_model`` what that inverse
    depends on (a session records it), ``display_model_words`` says it in words.
SimulatedCRT, load_crt
    The simulated display the fake photometer measures (parameters in ``crt.toml``).
GammaFit, fit_gamma, fit_gamma_models, choose_gamma_model, gamma_luminance,
gamma_drive_for_luminance
    Gamma models (PsychoPy eq. 1, 2 and 4, the extended power function, Psychtoolbox's sigmoid,
    Weibull and crtPolyLinear, a monotone spline), fitted by maximum likelihood with censored
    floor readings, chosen by held-out error (one-standard-error rule), misfits flagged.
fit_uniformity
    Spatial uniformity and correction gains (a ``calibration.uniformity.UniformityMap``).
READINGS_COLUMNS, load_readings
    Columns of ``readings.csv``; its usable readings.
CalibrationError, PhotometerError, PhotometerNotFound, PhotometerTimeout, BadReading
    Errors (all ``ValueError`` subclasses).
"""

from calibration.crt import SimulatedCRT, load_crt
from calibration.errors import (
    BadReading,
    CalibrationError,
    PhotometerError,
    PhotometerNotFound,
    PhotometerTimeout,
)
from calibration.gamma import (
    GammaFit,
    choose_gamma_model,
    fit_gamma,
    fit_gamma_models,
    gamma_drive_for_luminance,
    gamma_luminance,
)
from calibration.readings import READINGS_COLUMNS, load_readings
from calibration.record import (
    DEFAULT_CRT,
    Calibration,
    default_calibration,
    display_model_words,
    load_calibration,
    save_calibration,
)
from calibration.uniformity import fit_uniformity

__all__ = [
    "DEFAULT_CRT",
    "READINGS_COLUMNS",
    "BadReading",
    "Calibration",
    "CalibrationError",
    "GammaFit",
    "PhotometerError",
    "PhotometerNotFound",
    "PhotometerTimeout",
    "SimulatedCRT",
    "choose_gamma_model",
    "default_calibration",
    "display_model_words",
    "fit_gamma",
    "fit_gamma_models",
    "fit_uniformity",
    "gamma_drive_for_luminance",
    "gamma_luminance",
    "load_calibration",
    "load_crt",
    "load_readings",
    "save_calibration",
]
