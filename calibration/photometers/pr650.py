"""PhotoResearch PR-650: a small driver of our own.

PsychoPy's ``psychopy_photoresearch.PR650.measure()`` calls ``time.clock()``, removed in
Python 3.8, so it crashes on every measurement; and where a reply carries a low-light code it
returns 0 cd/m^2 silently. This driver speaks the same protocol (as PsychoPy's and
Psychtoolbox's PR-650 code do): 9600 8N1; ``b1`` (backlight, reply ``000``) to check the
instrument answers; ``s01,,,,,,01,1`` (measurement set-up); ``m0`` (measure and hold, reply
``000``); ``d2`` (reply ``QQ,U,X.XXXe+ee,Y.YYYe+ee,Z.ZZZe+ee``, Y in cd/m^2).
"""

from __future__ import annotations

import os
import termios
import time

import serial

from calibration.errors import BadReading, PhotometerError
from calibration.photometers.base import NoReply, Photometer, Reading, check_luminance, not_found
from calibration.photometers.pr655 import check_pr_status

__all__ = ["PR650Photometer"]


class PR650Photometer(Photometer):
    """PR-650 over serial; see the module docstring for the commands."""

    device = "pr650"
    max_cd_m2 = 1e5

    def __init__(self, port: str, *, timeout_s: float = 30.0, retries: int = 2):
        super().__init__(port, timeout_s=timeout_s, retries=retries)
        if not os.path.exists(port):
            raise not_found(self.device, port, "no such device")
        try:
            self._com = serial.Serial(port, baudrate=9600, bytesize=8, parity="N", stopbits=1,
                                      timeout=min(self.timeout_s, 2.0))
        except serial.SerialException as exc:
            raise not_found(self.device, port, f"cannot open: {exc}") from exc
        time.sleep(0.1)  # the PR-650 needs a moment after the port opens
        reply = self._send("b1", timeout_s=min(self.timeout_s, 2.0))
        if reply.strip() != "000":
            self._com.close()
            raise not_found(self.device, port, f"reply to b1 was {reply!r}, expected '000'")
        self._send("s01,,,,,,01,1", timeout_s=min(self.timeout_s, 2.0))
        self.identity = "PR-650"

    def _send(self, command: str, *, timeout_s: float) -> str:
        """Write a command line and read one reply line (may be partial on timeout)."""
        try:
            self._com.reset_input_buffer()
            self._com.write((command + "\n").encode("ascii"))
            self._com.flush()
            self._com.timeout = timeout_s
            return self._com.readline().decode("ascii", errors="replace")
        except (serial.SerialException, OSError, termios.error) as exc:
            raise PhotometerError(
                f"{self.device} on {self.port}: serial line lost during {command!r} ({exc}); "
                "readings so far are kept; reconnect and rerun to resume"
            ) from exc

    def _measure_once(self) -> Reading:
        reply = self._send("m0", timeout_s=self.timeout_s)
        if not reply.endswith("\n"):
            raise NoReply(reply.strip("\r\n"))
        check_pr_status(reply.strip().split(",")[0], reply.strip(), device=self.device)
        reply = self._send("d2", timeout_s=self.timeout_s)
        if not reply.endswith("\n"):
            raise NoReply(reply.strip("\r\n"))
        raw = reply.strip("\r\n")
        fields = raw.split(",")
        check_pr_status(fields[0], raw, device=self.device)
        if len(fields) != 5:
            raise BadReading(f"{self.device}: garbled reply {raw!r}", kind="garbled",
                             raw_reply=raw)
        lum = check_luminance(fields[3], raw, device=self.device, max_cd_m2=self.max_cd_m2)
        return Reading(lum, raw)

    def info(self) -> dict:
        return super().info() | {"serial": "9600 8N1", "driver": "calibration.photometers.pr650"}

    def close(self) -> None:
        if self._com.is_open:
            self._com.close()
