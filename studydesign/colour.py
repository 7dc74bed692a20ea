"""Colour constants every package shares: the Rec. 709 luminance weights.

One owner for the weights that turn linear RGB into CIE Y (the renderer's light probes, the gloss
fit's photos, the image statistics and the sim-to-real diagnosis all use them).
"""

from __future__ import annotations

import numpy as np

__all__ = ["REC709_Y", "rec709_luminance"]

#: CIE Y from linear Rec. 709 / sRGB primaries (D65), ITU-R BT.709-6 item 3.2.
REC709_Y = (0.2126, 0.7152, 0.0722)


def rec709_luminance(rgb, *, dtype=None) -> np.ndarray:
    """CIE Y of linear Rec. 709 RGB, shape (..., 3) -> (...); same units as the input.

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
        Linear (not gamma-encoded) R, G, B.
    dtype : numpy dtype, optional
        Of the result; default the input's float type (float64 for integers).

    Raises
    ------
    ValueError
        If the last axis is not 3 long.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim < 1 or rgb.shape[-1] != 3:
        raise ValueError(f"luminance needs a last axis of 3 (R, G, B), got shape {rgb.shape}")
    if dtype is None:
        dtype = rgb.dtype if rgb.dtype.kind == "f" else np.float64
    return rgb.astype(dtype, copy=False) @ np.asarray(REC709_Y, dtype=dtype)
