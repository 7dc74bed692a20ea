"""Serial ports the photometer may be on."""

from __future__ import annotations

from serial.tools import list_ports

__all__ = ["available_ports"]


def available_ports() -> list[dict]:
    """Serial ports the operating system reports, as dicts (device, description, hwid)."""
    return [
        {"device": p.device, "description": p.description, "hwid": p.hwid}
        for p in sorted(list_ports.comports(), key=lambda p: p.device)
    ]
