"""Radiance RGBE (``.hdr``) images: read and write linear float RGB, as Radiance defines them.

A pixel is four bytes, a mantissa per channel and a shared exponent E (Ward 1991, "Real pixels",
Graphics Gems II 80-83; Radiance's ``color.c``):

    value = (m + 0.5) * 2^(E - 136)      (E > 0; E = 0 is black)

so each pixel keeps about 1 % relative precision over a range of 2^255 (Poly Haven's captures
span 1e4 to 1e9 from darkest to brightest pixel, unclipped). Scanlines are stored "new-style"
run-length encoded (bytes 2, 2, width; then each of the four byte planes as runs of up to 127
repeats or literal stretches of up to 128 bytes) or flat; both are read, RLE is written. A
header ``EXPOSURE=`` multiplies the stored values (Radiance's ``EXPOSURE`` rule); the reader
divides it out, so a file reads as the radiance it holds.

Why by hand: Mitsuba's ``Bitmap`` reads ``.hdr`` too, but decodes as stb_image does (``m *
2^(E-136)``, without Radiance's half step, and a pixel of zero mantissas but an exponent as 0):
on the shipped aerodynamics_workshop map that is 0.37 % darker in the median and 738 channel
values of 1e-3 read as 0 (measured 2026-11-27). The light fields' scales (``probe-scale``) and
checksummed rebuilds (``scripts/make_lightfields.py --check``) need the format's own
definition, read and written the same way.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from labfiles import atomic_write_bytes
from stimuli.errors import IlluminationError

__all__ = ["RGBE_MAGIC", "is_rgbe", "read_rgbe", "write_rgbe"]

#: First bytes of a Radiance file (either spelling Radiance accepts).
RGBE_MAGIC = (b"#?RADIANCE", b"#?RGBE")
_RESOLUTION = re.compile(rb"^-Y (\d+) \+X (\d+)$")


def is_rgbe(path: str | os.PathLike) -> bool:
    """Whether a file starts like a Radiance RGBE image."""
    with open(path, "rb") as fh:
        head = fh.read(10)
    return any(head.startswith(m) for m in RGBE_MAGIC)


def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    e = rgbe[..., 3].astype(np.int32)
    f = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return ((rgbe[..., :3].astype(np.float64) + 0.5) * f[..., None]).astype(np.float32)


def _float_to_rgbe(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb, dtype=np.float64)
    peak = rgb.max(axis=-1)
    mant, exp = np.frexp(peak)  # peak = mant * 2^exp, mant in [0.5, 1)
    ok = peak > 1e-32
    scale = np.where(ok, mant * 256.0 / np.where(ok, peak, 1.0), 0.0)
    out = np.zeros(rgb.shape[:-1] + (4,), dtype=np.uint8)
    out[..., :3] = np.clip(np.floor(rgb * scale[..., None]), 0, 255).astype(np.uint8)
    out[..., 3] = np.where(ok, exp + 128, 0).astype(np.uint8)
    return out


def _decode_scanline(data: bytes, pos: int, width: int, path: Path) -> tuple[np.ndarray, int]:
    if (width < 8 or width > 0x7FFF or data[pos:pos + 2] != b"\x02\x02"
            or data[pos + 2] & 0x80):
        line = np.frombuffer(data, np.uint8, width * 4, pos).reshape(width, 4)
        if (line[:, :3] == 1).all(axis=1).any():
            raise IlluminationError(f"{path} uses Radiance's old run-length encoding; re-save it "
                                    "(e.g. `oiiotool in.hdr -o out.hdr`)")
        return line, pos + width * 4
    if (data[pos + 2] << 8 | data[pos + 3]) != width:
        raise IlluminationError(f"{path}: a scanline's length disagrees with the header; the "
                                "file is corrupt: re-copy it")
    pos += 4
    line = np.empty((4, width), np.uint8)
    for c in range(4):
        x = 0
        while x < width:
            n = data[pos]
            if n > 128:
                n -= 128
                line[c, x:x + n] = data[pos + 1]
                pos += 2
            else:
                line[c, x:x + n] = np.frombuffer(data, np.uint8, n, pos + 1)
                pos += 1 + n
            if n == 0 or x + n > width:
                raise IlluminationError(f"{path}: bad run length in a scanline; the file is "
                                        "corrupt: re-copy it")
            x += n
    return line.T, pos


def read_rgbe(path: str | os.PathLike) -> np.ndarray:
    """Read a Radiance RGBE image.

    Parameters
    ----------
    path : path-like
        A ``.hdr`` file (``-Y H +X W`` orientation: rows top to bottom, columns left to right).

    Returns
    -------
    ndarray, shape (H, W, 3), float32
        Linear RGB as stored, divided by the header's ``EXPOSURE`` values if any.

    Raises
    ------
    IlluminationError
        If the file is missing, not RGBE, of another orientation, or truncated.
    """
    path = Path(path)
    if not path.is_file():
        raise IlluminationError(f"RGBE file {path} does not exist; check the path")
    data = path.read_bytes()
    if not any(data.startswith(m) for m in RGBE_MAGIC):
        raise IlluminationError(f"{path} is not a Radiance RGBE file (no #?RADIANCE header)")
    end = data.find(b"\n\n")
    if end < 0:
        raise IlluminationError(f"{path}: the Radiance header never ends; the file is corrupt")
    exposure = 1.0
    for line in data[:end].split(b"\n")[1:]:
        if line.startswith(b"FORMAT=") and line.strip() != b"FORMAT=32-bit_rle_rgbe":
            raise IlluminationError(f"{path}: {line.decode(errors='replace')} is not RGBE "
                                    "(XYZE is not read); convert it to RGB")
        if line.startswith(b"EXPOSURE="):
            exposure *= float(line.split(b"=", 1)[1])
    nl = data.find(b"\n", end + 2)
    match = _RESOLUTION.match(data[end + 2:nl].strip())
    if not match:
        raise IlluminationError(f"{path}: resolution line {data[end + 2:nl]!r} is not "
                                "'-Y H +X W' (the standard orientation); re-save the file")
    height, width = int(match.group(1)), int(match.group(2))
    pos = nl + 1
    rows = np.empty((height, width, 4), np.uint8)
    try:
        for y in range(height):
            rows[y], pos = _decode_scanline(data, pos, width, path)
    except (IndexError, ValueError) as exc:
        raise IlluminationError(f"{path} is truncated ({exc}); re-copy it") from exc
    return _rgbe_to_float(rows) / np.float32(exposure)


def _encode_plane(plane: np.ndarray) -> bytes:
    """One byte plane of a scanline as runs (>= 4 equal bytes) and literal stretches."""
    out = bytearray()
    n = len(plane)
    x = 0
    while x < n:
        run = 1
        while x + run < n and run < 127 and plane[x + run] == plane[x]:
            run += 1
        if run >= 4:
            out += bytes((128 + run, int(plane[x])))
            x += run
            continue
        start = x
        while x < n and x - start < 128:
            if x + 3 < n and plane[x] == plane[x + 1] == plane[x + 2] == plane[x + 3]:
                break
            x += 1
        out.append(x - start)
        out += plane[start:x].tobytes()
    return bytes(out)


def write_rgbe(path: str | os.PathLike, rgb: np.ndarray) -> Path:
    """Write linear RGB as a run-length encoded Radiance RGBE file, atomically.

    Parameters
    ----------
    path : path-like
        Destination ``.hdr``.
    rgb : ndarray, shape (h, w, 3)
        Linear values >= 0, finite (each pixel is stored to about 1 %, module docstring).

    Returns
    -------
    Path
        ``path`` (a temporary file renamed into place).
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"write_rgbe needs shape (h, w, 3), got {rgb.shape}")
    if not np.isfinite(rgb).all() or (rgb < 0).any():
        raise ValueError("write_rgbe needs finite values >= 0")
    h, w = rgb.shape[:2]
    pix = _float_to_rgbe(rgb)
    body = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode())
    for y in range(h):
        if 8 <= w <= 0x7FFF:
            body += bytes((2, 2, w >> 8, w & 0xFF))
            for c in range(4):
                body += _encode_plane(pix[y, :, c])
        else:
            body += pix[y].tobytes()
    path = Path(path)
    atomic_write_bytes(path, bytes(body))
    return path
