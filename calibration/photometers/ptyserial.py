"""A pyserial port that accepts 7-bit / even-parity settings on a pseudo-terminal.

The LS-100 talks at 4800 baud, 7 data bits, even parity, 2 stop bits. A Linux pseudo-terminal
(the simulated instrument's port) keeps the baud rate and the stop bits but silently drops CS7
and PARENB, and then refuses (EINVAL) every later ``tcsetattr`` that asks for them again, which
pyserial does whenever the timeout changes. :class:`PtyTolerantSerial` retries such a refused
update with the bits a pty supports (8 data bits, no parity), keeping the requested settings in
``requested_line``. It changes nothing on a real serial device: the fallback only runs when the
port is a Unix98 pty slave (``/dev/pts/N``, device major 136-143) and the kernel refused.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import termios
import types

import serial

__all__ = ["PtyTolerantSerial", "is_pty", "pty_tolerant_serial_in"]


def is_pty(port: str) -> bool:
    """True if ``port`` is a pseudo-terminal slave device."""
    try:
        st = os.stat(port)
    except OSError:
        return False
    return stat.S_ISCHR(st.st_mode) and 136 <= os.major(st.st_rdev) <= 143


class PtyTolerantSerial(serial.Serial):
    """``serial.Serial`` that falls back to 8N on a pty that refuses 7-bit/parity settings."""

    requested_line: str = ""

    def _reconfigure_port(self, force_update=False):
        try:
            return super()._reconfigure_port(force_update)
        except termios.error as exc:
            if exc.args[0] != errno.EINVAL or not is_pty(self.portstr):
                raise
            self.requested_line = f"{self._baudrate} {self._bytesize}{self._parity}{self._stopbits}"
            saved = (self._bytesize, self._parity)
            self._bytesize, self._parity = serial.EIGHTBITS, serial.PARITY_NONE
            try:
                return super()._reconfigure_port(force_update)
            finally:
                self._bytesize, self._parity = saved


@contextlib.contextmanager
def pty_tolerant_serial_in(module, port: str):
    """While open, ``module.serial.Serial`` is :class:`PtyTolerantSerial` if ``port`` is a pty.

    PsychoPy's plugin drivers build their port with ``serial.Serial(port)`` from their module's
    global ``serial``; this swaps that name for the duration of the driver's construction only,
    and only for a pseudo-terminal.
    """
    if not is_pty(port):
        yield
        return
    original = module.serial
    module.serial = types.SimpleNamespace(**(vars(serial) | {"Serial": PtyTolerantSerial}))
    try:
        yield
    finally:
        module.serial = original
