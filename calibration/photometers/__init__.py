"""Photometer drivers: PR-655/PR-670 and LS-100 through PsychoPy's plugins, PR-650 our own.

>>> with open_photometer("pr655", "/dev/ttyUSB0") as phot:   # doctest: +SKIP
...     reading = phot.measure()
"""

from __future__ import annotations

from calibration.errors import CalibrationError
from calibration.photometers.base import Photometer, Reading
from calibration.photometers.ls100 import LS100Photometer
from calibration.photometers.pr650 import PR650Photometer
from calibration.photometers.pr655 import PR655Photometer

__all__ = ["DEVICES", "Photometer", "Reading", "open_photometer"]

DEVICES = {"pr655": PR655Photometer, "pr650": PR650Photometer, "ls100": LS100Photometer}


def open_photometer(device: str, port: str, **kwargs) -> Photometer:
    """Open a photometer by name (``pr655``, ``pr650``, ``ls100``); use it in a ``with``.

    Raises
    ------
    CalibrationError
        For an unknown device; :class:`~calibration.errors.PhotometerNotFound` (listing the
        system's serial ports) when nothing answers on ``port``.
    """
    if device not in DEVICES:
        raise CalibrationError(f"device {device!r} is unknown; use one of {sorted(DEVICES)}")
    return DEVICES[device](port, **kwargs)
