"""Konica Minolta LS-100 / LS-110 through PsychoPy's driver (psychopy-minolta).

The plugin's ``LS100`` class opens the port at the LS-100's settings (4800 baud, 7 data bits,
even parity, 2 stop bits) and sets absolute mode (``MDS,04``, reply ``OK00``); we use it for
that and its framing (``sendMessage``, CR LF); on a pseudo-terminal it gets a port that tolerates the pty's refusal of
7E2 (:mod:`calibration.photometers.ptyserial`). We parse the ``MES`` reply ourselves: the plugin's
``measure()`` returns -1 for any error and looks up error replies in a table that raises
KeyError on an unlisted one. Reply ``OK00,  95.23`` (cd/m^2); ``ER10`` is "measuring range
over" (saturated).
"""

from __future__ import annotations

import os

from calibration.errors import BadReading
from calibration.photometers.base import NoReply, Photometer, Reading, check_luminance, not_found
from calibration.photometers.ptyserial import pty_tolerant_serial_in

__all__ = ["LS100Photometer"]

# Error replies of the LS-100 (PsychoPy's table, from the instrument's manual).
ERRORS = {
    "ER00": "unknown command",
    "ER01": "setting error",
    "ER11": "memory value error",
    "ER10": "measuring range over",
    "ER19": "display range over",
    "ER20": "EEPROM error (the photometer needs repair)",
    "ER30": "photometer battery exhausted",
}


class LS100Photometer(Photometer):
    """LS-100 over serial; see the module docstring for the commands."""

    device = "ls100"
    max_cd_m2 = 299_900.0

    def __init__(self, port: str, *, timeout_s: float = 10.0, retries: int = 2):
        super().__init__(port, timeout_s=timeout_s, retries=retries)
        if not os.path.exists(port):
            raise not_found(self.device, port, "no such device")
        from psychopy_minolta import minolta

        # On the simulated instrument's pty the port must tolerate 7E2 (see ptyserial.py).
        with pty_tolerant_serial_in(minolta, port):
            self._drv = minolta.LS100(port, maxAttempts=1)
        if not self._drv.OK:
            com = getattr(self._drv, "com", None)
            if com:
                com.close()
            raise not_found(self.device, port, "no OK reply to MDS,04")
        self.identity = "LS-100"

    def _measure_once(self) -> Reading:
        reply = self._drv.sendMessage("MES", timeout=self.timeout_s)
        if not reply.endswith("\n"):
            raise NoReply(reply.strip("\r\n"))
        raw = reply.strip("\r\n")
        code = raw.split(",")[0].strip()
        if code.startswith("ER"):
            kind = "saturated" if code == "ER10" else "error"
            what = ERRORS.get(code, "unlisted error")
            raise BadReading(f"{self.device}: {code} {what}, reply {raw!r}", kind=kind,
                             raw_reply=raw)
        if not code.startswith("OK") or "," not in raw:
            raise BadReading(f"{self.device}: garbled reply {raw!r}", kind="garbled",
                             raw_reply=raw)
        value = raw.split(",", 1)[1].strip()
        return Reading(check_luminance(value, raw, device=self.device,
                                       max_cd_m2=self.max_cd_m2), raw)

    def info(self) -> dict:
        return super().info() | {"serial": "4800 7E2", "driver": "psychopy_minolta.LS100"}

    def close(self) -> None:
        com = getattr(self._drv, "com", None)
        if com and com.is_open:
            com.close()
