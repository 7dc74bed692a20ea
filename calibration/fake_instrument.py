"""A simulated photometer on a pseudo-terminal, speaking the real instrument's serial protocol.

``python -m calibration fake-photometer --device pr655 --display crt.toml`` opens a
pseudo-terminal (``os.openpty``), prints the port path, and answers the instrument's commands
by measuring a :class:`~calibration.crt.SimulatedCRT`. The drivers talk to it exactly as to the
instrument: only the port path differs from the lab.

What the simulated photometer sees
----------------------------------
*The drive level* is read from the real screen: the pixels of the X display (Xvfb in tests and
the demo) under the photometer's spot, averaged over R, G, B and a 5 x 5 pixel spot, divided by
255. So the procedure's PsychoPy window must really show the patch for the reading to be right.

*Where the photometer points* is, in the lab, where the experimenter has put it. In simulation
the procedure plays the experimenter's hand: run with ``--sim-aim FILE`` it writes the spot's
screen pixel position as JSON (``{"x_px": .., "y_px": ..}``) to FILE each time it asks for the
photometer to be moved; the fake, started with ``--aim FILE``, reads it at each measurement.
That file is the only side channel; without it the fake points at the screen centre. The spot's
position on the X screen gives the CRT model's (x_norm, y_norm): the X screen is the CRT.

Protocols (replies end in CR LF)
--------------------------------
========  ====================  =========================================================
device    command               reply
========  ====================  =========================================================
pr655     ``PHOTO``             `` REMOTE MODE`` (other commands are ignored before it)
          ``D111`` / ``D110``   ``00000,PR-655`` / ``00000,<serial number>``
          ``M0``                measure; ``qqqqq`` (status, 00000 = OK)
          ``D1``..``D4``        ``qqqqq,0,Y,x,y`` / ``X,Y,Z`` / ``Y,u',v'`` / ``Y,CCT,dev``
          ``D5``                ``qqqqq,0,peak,int,int`` then 101 lines ``nm,W/sr/m2/nm``
          ``Q``                 leave remote mode (no line end)
pr650     ``b1``, ``s...``      ``000``
          ``m0``                measure; ``000`` (status)
          ``d2``                ``QQ,0,X.XXXe+ee,Y.YYYe+ee,Z.ZZZe+ee``
ls100     ``MDS,04``, ``CLE``   ``OK00``
          ``MES``               ``OK00,   95.23`` (4 significant digits); ``ER10`` over range
========  ====================  =========================================================

Status codes: 0 OK; 19 for an overload (saturated). The LS-100's line is 4800 baud, 7 data
bits, even parity, 2 stop bits. A Linux pseudo-terminal silently drops CS7 and PARENB from its
settings (it keeps the baud rate and CSTOPB), so this side checks what it can (4800 baud, two
stop bits: a mismatch gives garbage, as on a real line) and masks every byte to 7 bits.

Faults (``--fault KIND:WHEN``, WHEN a measurement number, ``N-M``, a comma list, or ``all``;
measurements are counted from 1 at each measure command):
``timeout`` (half a reply line, then silence), ``garbled`` (unparsable bytes), ``out_of_range``
(a negative luminance), ``saturated`` (overload status / ``ER10``), ``unplug`` (the line is
closed before the reply, and the fake exits).
"""

from __future__ import annotations

import json
import math
import os
import select
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.crt import SimulatedCRT
from calibration.errors import CalibrationError

__all__ = [
    "FAULT_KINDS",
    "ConstantScreen",
    "FakePhotometer",
    "Faults",
    "X11Screen",
    "parse_faults",
]

FAULT_KINDS = ("timeout", "garbled", "out_of_range", "saturated", "unplug")
DEVICES = ("pr655", "pr650", "ls100")
# A CRT's white (x, y) as the fake reports it (9300 K, typical of a CRT's factory setting).
_WHITE_XY = (0.2848, 0.2932)


@dataclass(frozen=True)
class Faults:
    """Which measurements (1-based) get which fault; ``"all"`` in a set means every one."""

    schedule: dict = field(default_factory=dict)

    def kind_for(self, n: int) -> str | None:
        for kind in FAULT_KINDS:
            when = self.schedule.get(kind, ())
            if "all" in when or n in when:
                return kind
        return None


def parse_faults(specs) -> Faults:
    """Parse ``["timeout:2,5", "unplug:10", "garbled:3-4", "saturated:all"]``.

    Raises
    ------
    CalibrationError
        For an unknown kind or a malformed WHEN.
    """
    schedule: dict = {}
    for spec in specs or ():
        kind, _, when = spec.partition(":")
        if kind not in FAULT_KINDS or not when:
            raise CalibrationError(
                f"fault {spec!r}: write KIND:WHEN with KIND one of {list(FAULT_KINDS)} and WHEN "
                "a measurement number, N-M, a comma list or 'all' (e.g. timeout:3)"
            )
        items = schedule.setdefault(kind, set())
        for part in when.split(","):
            try:
                if part == "all":
                    items.add("all")
                elif "-" in part:
                    lo, hi = (int(v) for v in part.split("-"))
                    items.update(range(lo, hi + 1))
                else:
                    items.add(int(part))
            except ValueError as exc:
                raise CalibrationError(f"fault {spec!r}: {part!r} is not N, N-M or all") from exc
    return Faults(schedule)


class ConstantScreen:
    """A screen that shows one drive level everywhere (for tests of the drivers alone)."""

    def __init__(self, drive: float = 1.0, x_norm: float = 0.0, y_norm: float = 0.0):
        self.drive, self.x_norm, self.y_norm = drive, x_norm, y_norm

    def sample(self) -> tuple[float, float, float]:
        """(drive in [0, 1], x_norm, y_norm) under the photometer."""
        return self.drive, self.x_norm, self.y_norm


class X11Screen:
    """The X display's pixels under the photometer's spot.

    Parameters
    ----------
    aim_file : path or None
        JSON ``{"x_px": .., "y_px": ..}`` (screen pixels, origin top left) written by the
        procedure in simulation; ``None`` or a missing file: the screen centre.
    display : str or None
        X display name (default ``$DISPLAY``).
    spot_px : int
        Side of the square spot averaged, pixels.
    """

    def __init__(self, aim_file=None, display: str | None = None, spot_px: int = 5):
        from Xlib import display as xdisplay

        try:
            self._dpy = xdisplay.Display(display)
        except Exception as exc:  # Xlib raises its own error classes for a missing display
            raise CalibrationError(
                f"cannot open X display {display or os.environ.get('DISPLAY')!r} ({exc}); run "
                "the fake photometer under the same X server as the procedure (xvfb-run)"
            ) from exc
        self._screen = self._dpy.screen()
        self.width_px = self._screen.width_in_pixels
        self.height_px = self._screen.height_in_pixels
        self.aim_file = Path(aim_file) if aim_file else None
        self.spot_px = spot_px

    def aim(self) -> tuple[int, int]:
        """Screen pixel the photometer points at."""
        if self.aim_file is not None and self.aim_file.is_file():
            try:
                d = json.loads(self.aim_file.read_text())
                return int(d["x_px"]), int(d["y_px"])
            except (ValueError, KeyError, TypeError):
                pass  # being rewritten: keep the centre for this reading
        return self.width_px // 2, self.height_px // 2

    def sample(self) -> tuple[float, float, float]:
        from Xlib import X

        x, y = self.aim()
        h = self.spot_px // 2
        x0 = min(max(x - h, 0), self.width_px - self.spot_px)
        y0 = min(max(y - h, 0), self.height_px - self.spot_px)
        img = self._screen.root.get_image(x0, y0, self.spot_px, self.spot_px, X.ZPixmap,
                                          0xFFFFFFFF)
        px = np.frombuffer(img.data, dtype=np.uint8).reshape(-1, 4)[:, :3]
        drive = float(px.mean()) / 255.0
        x_norm = 2 * (x + 0.5) / self.width_px - 1
        y_norm = 1 - 2 * (y + 0.5) / self.height_px
        return drive, x_norm, y_norm

    def close(self) -> None:
        self._dpy.close()


def _four_digits(v: float) -> str:
    """LS-100 style: 4 significant digits, fixed point."""
    if v <= 0:
        return "0.000"
    d = max(0, 3 - math.floor(math.log10(v)))
    return f"{v:.{d}f}"


class FakePhotometer:
    """The simulated instrument: a pseudo-terminal served from a thread.

    Use as a context manager; ``port`` is the path the driver opens.

    Parameters
    ----------
    device : {"pr655", "pr650", "ls100"}
    crt : SimulatedCRT
    screen : ConstantScreen or X11Screen
        Where the drive level and position under the photometer come from.
    rng : numpy.random.Generator
        Measurement noise.
    faults : Faults
    measure_s : float
        Seconds a measurement takes (the instrument's integration time).
    """

    def __init__(self, device: str, crt: SimulatedCRT, screen, rng: np.random.Generator, *,
                 faults: Faults | None = None, measure_s: float = 0.05):
        if device not in DEVICES:
            raise CalibrationError(f"device {device!r} is unknown; use one of {list(DEVICES)}")
        self.device = device
        self.crt = crt
        self.screen = screen
        self.rng = rng
        self.faults = faults or Faults()
        self.measure_s = measure_s
        self.n_measurements = 0
        self.unplugged = threading.Event()
        self.log: list[tuple[str, str]] = []
        # The simulated display is switched on at the first measurement (its warm-up counts from
        # there), not when the fake starts: a slow start of the program under test must not let
        # the display warm up unseen.
        self._t0: float | None = None
        self._remote = device != "pr655"
        self._last: dict | None = None
        self._stop = threading.Event()
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._serve, name=f"fake-{device}", daemon=True)

    # --- lifetime ------------------------------------------------------------------------------
    def start(self) -> FakePhotometer:
        self._thread.start()
        return self

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        self._close_fds()

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self._master = self._slave = -1

    def wait(self) -> None:
        """Block until closed or unplugged (the command line's main loop)."""
        while not self._stop.is_set() and not self.unplugged.is_set():
            time.sleep(0.1)

    # --- the line ------------------------------------------------------------------------------
    def _line_ok(self) -> bool:
        """LS-100: the client's settings must be 4800 baud and 2 stop bits (see module doc)."""
        if self.device != "ls100":
            return True
        attrs = termios.tcgetattr(self._slave)
        return attrs[5] == termios.B4800 and bool(attrs[2] & termios.CSTOPB)

    def _write(self, text: str, *, end: str = "\r\n") -> None:
        data = (text + end).encode("ascii")
        if not self._line_ok():
            data = bytes((b * 37 + 11) & 0xFF for b in data)  # a baud mismatch: garbage
        os.write(self._master, data)

    def _serve(self) -> None:
        buf = ""
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(self._master, 1024)
            except OSError:
                return
            if self.device == "ls100":
                data = bytes(b & 0x7F for b in data)
            buf += data.decode("ascii", errors="replace")
            if self.device == "pr655" and self._remote and buf == "Q":
                self._remote, buf = False, ""
                continue
            while True:
                cut = [i for i in (buf.find("\n"), buf.find("\r")) if i >= 0]
                if not cut:
                    break
                line, buf = buf[: min(cut)].strip(), buf[min(cut) + 1:]
                if line:
                    self.log.append(("in", line))
                    self._handle(line)
                    if self.unplugged.is_set():
                        return

    # --- measuring -----------------------------------------------------------------------------
    def _measure(self) -> str | None:
        """Take a measurement; returns the fault kind for it (or None)."""
        self.n_measurements += 1
        fault = self.faults.kind_for(self.n_measurements)
        if fault == "unplug":
            self.unplugged.set()
            self._close_fds()
            return fault
        time.sleep(self.measure_s)
        drive, x_norm, y_norm = self.screen.sample()
        if self._t0 is None:
            self._t0 = time.monotonic()
        t_s = time.monotonic() - self._t0
        lum = float(self.crt.luminance(drive, x_norm, y_norm, t_s, self.rng))
        if fault == "out_of_range":
            lum = -abs(lum) - 1.0
        self._last = {"Y": lum, "status": 19 if fault == "saturated" else 0}
        return fault

    def _xyz(self) -> tuple[float, float, float]:
        x, y = _WHITE_XY
        Y = self._last["Y"]
        return x / y * Y, Y, (1 - x - y) / y * Y

    def _handle(self, line: str) -> None:
        getattr(self, f"_handle_{self.device}")(line)

    def _timeout(self, reply: str) -> None:
        # Half a reply, then silence: the driver's readline times out holding a partial line.
        os.write(self._master, reply[: max(1, len(reply) // 2)].encode("ascii"))

    def _handle_pr655(self, line: str) -> None:
        cmd = line.upper()
        if not self._remote:
            if cmd == "PHOTO":
                self._remote = True
                self._write(" REMOTE MODE")
            return
        if cmd == "D111":
            return self._write("00000,PR-655")
        if cmd == "D110":
            return self._write("00000,65500042")
        if cmd.startswith("M"):
            fault = self._measure()
            if fault == "unplug":
                return None
            status = f"{self._last['status']:05d}"
            return self._timeout(status + "\r\n") if fault == "timeout" else self._write(status)
        if cmd.startswith("D") and cmd[1:] in {"1", "2", "3", "4", "5"}:
            return self._pr655_data(cmd[1:])
        return self._write("00000")

    def _pr655_data(self, code: str) -> None:
        if self._last is None:
            return self._write("-0001")  # no measurement to report
        status = self._last["status"]
        if status:
            return self._write(f"{status:05d}")
        X, Y, Z = self._xyz()
        x, y = _WHITE_XY
        d = -2 * x + 12 * y + 3
        fault = self.faults.kind_for(self.n_measurements)
        if code == "1":
            reply = f"00000,0,{Y:.3e},{x:.4f},{y:.4f}"
        elif code == "2":
            reply = f"00000,0,{X:.3e},{Y:.3e},{Z:.3e}"
        elif code == "3":
            reply = f"00000,0,{Y:.3e},{4 * x / d:.4f},{9 * y / d:.4f}"
        elif code == "4":
            reply = f"00000,0,{Y:.3e},9300,0.0021"
        else:
            return self._pr655_spectrum(Y)
        if fault == "garbled" and code == "3":
            reply = "0#0?0,0,\x1b9.1" + reply[-7:].replace(",", ";")
        self._write(reply)

    def _pr655_spectrum(self, Y: float) -> None:
        # A fixed three-phosphor shape scaled with Y (not colorimetrically tied to X, Y, Z).
        nm = np.arange(380, 781, 4)
        shape = sum(a * np.exp(-0.5 * ((nm - c) / w) ** 2)
                    for a, c, w in ((0.6, 450, 12), (1.0, 535, 20), (0.8, 625, 8)))
        radiance = shape * Y / 683.0 / 60.0
        total = f"{radiance.sum() * 4:.3e}"
        lines = [f"00000,0,{nm[np.argmax(radiance)]:.0f},{total},{total}"]
        lines += [f"{w},{r:.4e}" for w, r in zip(nm, radiance)]
        self._write("\r\n".join(lines))

    def _handle_pr650(self, line: str) -> None:
        cmd = line.lower()
        if cmd.startswith("m"):
            fault = self._measure()
            if fault == "unplug":
                return None
            status = f"{self._last['status']:03d}"
            return self._timeout(status + "\r\n") if fault == "timeout" else self._write(status)
        if cmd == "d2":
            if self._last is None:
                return self._write("01,0,0.000e+00,0.000e+00,0.000e+00")
            X, Y, Z = self._xyz()
            reply = f"{self._last['status']:02d},0,{X:.3e},{Y:.3e},{Z:.3e}"
            if self.faults.kind_for(self.n_measurements) == "garbled":
                reply = reply[:6] + "\x7f\x00?" + reply[12:18]
            return self._write(reply)
        return self._write("000")

    def _handle_ls100(self, line: str) -> None:
        cmd = line.upper()
        if cmd == "MES":
            fault = self._measure()
            if fault == "unplug":
                return None
            if self._last["status"]:
                return self._write("ER10")
            Y = self._last["Y"]
            value = f"-{_four_digits(-Y)}" if Y < 0 else _four_digits(Y)
            reply = f"OK00,{value:>8}"
            if fault == "garbled":
                reply = "O?00,\x15" + reply[-4:].replace(".", "")
            return self._timeout(reply + "\r\n") if fault == "timeout" else self._write(reply)
        if cmd.startswith("MDS") or cmd == "CLE":
            return self._write("OK00")
        return self._write("ER00")
