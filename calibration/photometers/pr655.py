"""PhotoResearch PR-655 / PR-670 through PsychoPy's driver (psychopy-photoresearch).

The plugin's ``PR655`` class opens the port (9600 8N1), enters remote mode (``PHOTO``, reply
`` REMOTE MODE``) and reads the model (``D111``); we use it for that and for its message framing
(``sendMessage``). We do not use its ``measure()``: it ignores the status code of the reply (an
error reply becomes an IndexError or a wrong number) and reads the spectrum with ``readlines()``,
which always waits a full timeout. Instead: ``M0`` (measure, reply ``qqqqq``) then ``D3``
(reply ``qqqqq,U,Y,u,v``; Y in cd/m^2), status checked.
"""

from __future__ import annotations

import os

from calibration.errors import BadReading
from calibration.photometers.base import NoReply, Photometer, Reading, check_luminance, not_found

__all__ = ["PR655Photometer", "check_pr_status"]

# Status codes the drivers of PsychoPy and Psychtoolbox read as "light too low" (PR-650/655).
LOW_LIGHT = {-1, 10, 18}


def check_pr_status(status_text: str, raw: str, *, device: str) -> None:
    """Raise :class:`BadReading` unless a PR-6xx status field is 0.

    Low-light codes (-1, 10, 18) are ``out_of_range``; 19 (what the fake instrument sends for
    an overload) is ``saturated``; any other non-zero code is ``error``; text that is not an
    integer is ``garbled``.
    """
    try:
        code = int(status_text)
    except (TypeError, ValueError):
        raise BadReading(f"{device}: garbled reply {raw!r}", kind="garbled", raw_reply=raw)
    if code == 0:
        return
    if code in LOW_LIGHT:
        kind, what = "out_of_range", "light too low for the instrument"
    elif code == 19:
        kind, what = "saturated", "light overload (saturated)"
    else:
        kind, what = "error", f"instrument error code {code}"
    raise BadReading(f"{device}: {what}, reply {raw!r}", kind=kind, raw_reply=raw)


def _line(reply: str) -> str:
    if not reply.endswith("\n"):
        raise NoReply(reply.strip("\r\n"))
    return reply.strip("\r\n")


class PR655Photometer(Photometer):
    """PR-655/PR-670 over serial; see the module docstring for the commands."""

    device = "pr655"
    max_cd_m2 = 1e5

    def __init__(self, port: str, *, timeout_s: float = 30.0, retries: int = 2):
        super().__init__(port, timeout_s=timeout_s, retries=retries)
        if not os.path.exists(port):
            raise not_found(self.device, port, "no such device")
        from psychopy_photoresearch.pr import PR655

        self._drv = PR655(port)
        if not self._drv.OK or not self._drv.type:
            com = getattr(self._drv, "com", None)
            if com:
                com.close()
            raise not_found(self.device, port, "no reply to PHOTO/D111")
        self.identity = self._drv.type

    def _measure_once(self) -> Reading:
        status = _line(self._drv.sendMessage("M0", timeout=self.timeout_s))
        check_pr_status(status.split(",")[0], status, device=self.device)
        raw = _line(self._drv.sendMessage("D3", timeout=self.timeout_s))
        fields = raw.split(",")
        check_pr_status(fields[0], raw, device=self.device)
        if len(fields) != 5:
            raise BadReading(f"{self.device}: garbled reply {raw!r}", kind="garbled",
                             raw_reply=raw)
        lum = check_luminance(fields[2], raw, device=self.device, max_cd_m2=self.max_cd_m2)
        return Reading(lum, raw)

    def info(self) -> dict:
        return super().info() | {"serial": "9600 8N1", "driver": "psychopy_photoresearch.PR655"}

    def close(self) -> None:
        com = getattr(self._drv, "com", None)
        if com and com.is_open:
            try:
                self._drv.endRemoteMode()
            except OSError:
                pass  # unplugged: nothing to tell the instrument
            com.close()
