"""Reading render outputs: the float32 luminance EXR and the checks on it."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

__all__ = ["ImageStatsError", "read_luminance"]

#: EXR channel names accepted as luminance, in order of preference.
_LUMINANCE_CHANNELS = ("Y", "L", "luminance")


class ImageStatsError(ValueError):
    """Image statistics cannot be computed as asked (bad input, or a stats file that disagrees)."""


def read_luminance(path: str | Path, *, sha256: str | None = None) -> np.ndarray:
    """Read the luminance channel of a render's EXR.

    Parameters
    ----------
    path : path-like
        An OpenEXR file with one channel named ``Y`` (CIE Y, the renderer's luminance), ``L`` or
        ``luminance``, or a single channel of any name.
    sha256 : str, optional
        The manifest's checksum of the file; the bytes read are checked against it.

    Returns
    -------
    ndarray, shape (height, width), float64

    Raises
    ------
    ImageStatsError
        If the file is missing or unreadable, its checksum differs, it has no luminance channel,
        or any pixel is NaN or Inf.
    """
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise ImageStatsError(f"{path} is missing; re-render it or fix the manifest")
    data = path.read_bytes()
    if sha256 is not None and hashlib.sha256(data).hexdigest() != str(sha256):
        raise ImageStatsError(
            f"{path} does not match its checksum in the manifest (changed after rendering); "
            "re-render it"
        )
    try:
        channels = OpenEXR.File(str(path), separate_channels=True).channels()
    except Exception as exc:  # OpenEXR raises RuntimeError, or others for truncated files
        raise ImageStatsError(f"{path} is not a readable OpenEXR file ({exc}); re-render it") \
            from exc
    names = [c for c in _LUMINANCE_CHANNELS if c in channels]
    if names:
        name = names[0]
    elif len(channels) == 1:
        name = next(iter(channels))
    else:
        raise ImageStatsError(
            f"{path} has channels {sorted(channels)}, none of them luminance "
            f"({', '.join(_LUMINANCE_CHANNELS)}); write the render as one luminance channel"
        )
    lum = np.asarray(channels[name].pixels, dtype=np.float64)
    if lum.ndim != 2:
        raise ImageStatsError(f"{path}: channel {name!r} has shape {lum.shape}, not 2-D")
    bad = ~np.isfinite(lum)
    if bad.any():
        raise ImageStatsError(
            f"{path}: {int(bad.sum())} of {lum.size} pixels are NaN or Inf; re-render it"
        )
    return lum
