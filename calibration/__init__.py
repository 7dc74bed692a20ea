"""Display calibration: photometers over serial, gamma and uniformity, PsychoPy monitor profiles.

Public API
----------
available_ports
"""

from calibration.ports import available_ports

__all__ = ["available_ports"]
