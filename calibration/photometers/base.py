"""What every photometer driver shares: the reading record, retries and reply checks."""

from __future__ import annotations

import math
import termios
from dataclasses import dataclass

import serial

from calibration.errors import BadReading, PhotometerError, PhotometerNotFound, PhotometerTimeout
from calibration.ports import available_ports

__all__ = ["NoReply", "Photometer", "Reading", "check_luminance", "not_found"]


@dataclass(frozen=True)
class Reading:
    """One accepted photometer reading.

    Attributes
    ----------
    luminance_cd_m2 : float
        Luminance, cd/m^2.
    raw_reply : str
        The instrument's reply the value was parsed from, line ends stripped.
    """

    luminance_cd_m2: float
    raw_reply: str


class NoReply(Exception):
    """No complete reply line within the timeout (``partial`` holds what did arrive)."""

    def __init__(self, partial: str):
        super().__init__(partial)
        self.partial = partial


def not_found(device: str, port: str, why: str) -> PhotometerNotFound:
    """The error for a port where no photometer answers, listing the ports the system reports."""
    ports = available_ports()
    listing = ", ".join(p["device"] for p in ports) if ports else "none"
    return PhotometerNotFound(
        f"no {device} answers on port {port!r} ({why}); serial ports found: {listing}. "
        "Check the cable and power, that the instrument is switched on (PR-6xx: connect within "
        "a few seconds of switching on; LS-100: hold F while switching on), and pass --port "
        "(`python -m calibration ports` lists them)."
    )


def check_luminance(value_text: str, raw: str, *, device: str, max_cd_m2: float) -> float:
    """Parse a luminance field and check it lies in the instrument's range.

    Raises
    ------
    BadReading
        ``kind="garbled"`` if it is not a number, ``"out_of_range"`` if it is negative, not
        finite or above ``max_cd_m2``.
    """
    try:
        value = float(value_text)
    except (TypeError, ValueError):
        raise BadReading(f"{device}: garbled reply {raw!r}", kind="garbled", raw_reply=raw)
    if not math.isfinite(value) or value < 0 or value > max_cd_m2:
        raise BadReading(
            f"{device}: luminance {value} cd/m^2 outside the instrument's range "
            f"[0, {max_cd_m2:g}] in reply {raw!r}",
            kind="out_of_range",
            raw_reply=raw,
        )
    return value


class Photometer:
    """Base of the drivers: a resource with a lifetime, used as a context manager.

    Subclasses implement ``_measure_once()`` (raise :class:`NoReply` on a timeout,
    :class:`~calibration.errors.BadReading` for a reply that must not be used) and ``close()``.

    Parameters
    ----------
    port : str
        Serial device path (``/dev/ttyUSB0``; a pseudo-terminal for the fake instrument).
    timeout_s : float
        Seconds to wait for each reply line.
    retries : int
        Further attempts after a timeout before :class:`PhotometerTimeout` is raised.
    """

    device = "photometer"
    #: Largest luminance the instrument reports, cd/m^2.
    max_cd_m2 = 1e5

    def __init__(self, port: str, *, timeout_s: float = 30.0, retries: int = 2):
        if retries < 0 or timeout_s <= 0:
            raise ValueError("retries must be >= 0 and timeout_s > 0")
        self.port = port
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.identity = ""

    def measure(self) -> Reading:
        """Make one measurement; retry after timeouts, at most ``retries`` times.

        Raises
        ------
        PhotometerTimeout
            If no attempt got a complete reply; the message quotes the last raw reply.
        BadReading
            If the reply is garbled, out of range or saturated (never retried here: the
            procedure records it as rejected and measures the patch again).
        """
        last = ""
        for _attempt in range(self.retries + 1):
            try:
                return self._measure_once()
            except NoReply as exc:
                last = exc.partial
            except (serial.SerialException, OSError, termios.error) as exc:
                raise PhotometerError(
                    f"{self.device} on {self.port}: serial line lost ({exc}); readings so far "
                    "are kept: reconnect the instrument and rerun the same command to resume"
                ) from exc
        raise PhotometerTimeout(
            f"{self.device} on {self.port}: no complete reply after {self.retries + 1} "
            f"attempt(s) of {self.timeout_s:g} s; last raw reply {last!r}. Check the cable and "
            "that the instrument is in remote mode; dim patches need a longer --timeout-s.",
            last_reply=last,
        )

    def _measure_once(self) -> Reading:  # pragma: no cover - abstract
        raise NotImplementedError

    def info(self) -> dict:
        """Port, serial settings and identity, for the calibration record."""
        return {"device": self.device, "port": self.port, "identity": self.identity,
                "timeout_s": self.timeout_s, "retries": self.retries}

    def close(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
