"""Tone mapping (the source study's linear + asymptotic logistic) and gamma correction to 8-bit PNG.

Per light field (the tone-mapping condition: the experiment's illumination condition, or one
light field of the image-statistics set), one curve for all its stimuli, as the seed did per
illumination condition. With ``L_max`` the condition's
luminance range (below), ``f = design.tonemap.linear_fraction`` (0.67), ``v_k = knee_value`` (171)
and ``v_max = max_value`` (255), the display value ``v`` (0-255, proportional to the wanted screen
luminance) of a pixel of luminance ``L`` is

    L_k = f L_max                                                         (knee luminance)
    v(L) = v_k L / L_k                                  for 0 <= L <= L_k  (linear part)
    v(L) = v_k + (v_max - v_k) tanh(s (L - L_k))        for L > L_k        (asymptotic logistic)
    s = v_k / (L_k (v_max - v_k))

``tanh(x) = 2 / (1 + exp(-2x)) - 1`` is the logistic centred on the knee and rescaled so that it is
0 there and tends to 1: v is continuous at the knee (both parts give v_k), its slope is continuous
(both give v_k / L_k: the choice of s), it increases strictly, and it approaches v_max only as
L -> infinity, so highlights above ``L_max`` still map to distinct values below 255 (``L_max``
itself maps to v_k + (v_max - v_k) tanh(s (1 - f) L_max), 235 for the design's numbers).

``L_max`` of a condition is the largest, over its stimuli, of each image's 99.9th luminance
percentile (robust to Monte-Carlo fireflies; the brighter 0.1 % fall on the logistic's tail).

Gamma: ``v / v_max`` is the wanted fraction of the display's luminance range; the calibration's
inverse gamma (``Calibration.drive_for_fraction``) turns it into a drive value, rounded to 8 bits.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from labfiles import atomic_open
from studydesign import ToneMapSpec

__all__ = [
    "LMAX_PERCENTILE",
    "ToneCurve",
    "display_fraction",
    "gamma_encode",
    "luminance_range",
    "tone_curve",
    "tone_curve_record",
    "tonemap",
    "write_png",
]

#: Percentile of each image's luminance that defines its contribution to L_max.
LMAX_PERCENTILE = 99.9


@dataclass(frozen=True)
class ToneCurve:
    """One condition's tone curve (module docstring): knee at ``knee_luminance``.

    Attributes
    ----------
    max_luminance : float
        L_max, render units.
    linear_fraction, knee_value, max_value : float
        f, v_k and v_max of the design.
    """

    max_luminance: float
    linear_fraction: float
    knee_value: float
    max_value: float

    @property
    def knee_luminance(self) -> float:
        return self.linear_fraction * self.max_luminance

    @property
    def logistic_rate(self) -> float:
        """s, chosen so the slopes of both parts agree at the knee."""
        return self.knee_value / (self.knee_luminance * (self.max_value - self.knee_value))


def tone_curve(spec: ToneMapSpec, max_luminance: float) -> ToneCurve:
    """The tone curve of a condition whose luminance range is [0, ``max_luminance``].

    Raises
    ------
    ValueError
        If ``max_luminance`` is not finite and > 0 (an all-black or broken render).
    """
    if not (np.isfinite(max_luminance) and max_luminance > 0):
        raise ValueError(
            f"tone-map luminance range L_max={max_luminance} must be finite and > 0; the renders "
            "are black or broken: check the light probe and the EXR files")
    return ToneCurve(float(max_luminance), float(spec.linear_fraction), float(spec.knee_value),
                     float(spec.max_value))


def tone_curve_record(curve: ToneCurve) -> dict:
    """The numbers that define a curve, as recorded beside renders (``tonemaps.csv``):
    ``lmax_percentile``, ``tonemap_lmax`` (L_max), ``knee_luminance`` (L_k), ``logistic_rate``
    (s), ``linear_fraction`` (f), ``knee_value`` (v_k), ``max_value`` (v_max)."""
    return {"lmax_percentile": LMAX_PERCENTILE, "tonemap_lmax": curve.max_luminance,
            "knee_luminance": curve.knee_luminance, "logistic_rate": curve.logistic_rate,
            "linear_fraction": curve.linear_fraction, "knee_value": curve.knee_value,
            "max_value": curve.max_value}


def luminance_range(images) -> float:
    """L_max of a condition: the largest of each image's 99.9th luminance percentile."""
    values = [float(np.percentile(np.asarray(im), LMAX_PERCENTILE)) for im in images]
    if not values:
        raise ValueError("luminance_range needs at least one image")
    return max(values)


def tonemap(luminance: np.ndarray, curve: ToneCurve) -> np.ndarray:
    """Display values v in [0, v_max) (float) of luminance values (module docstring).

    Negative luminance (none in a valid render) maps to 0; NaN raises.
    """
    L = np.asarray(luminance, dtype=float)
    if np.isnan(L).any():
        raise ValueError("tonemap got NaN luminance; the render is broken: re-render it")
    L = np.maximum(L, 0.0)
    lk, vk, vmax = curve.knee_luminance, curve.knee_value, curve.max_value
    linear = vk * L / lk
    logistic = vk + (vmax - vk) * np.tanh(curve.logistic_rate * (L - lk))
    return np.where(L <= lk, linear, logistic)


def display_fraction(luminance: np.ndarray, curve: ToneCurve) -> np.ndarray:
    """Wanted fraction of the display's luminance range, v / v_max, in [0, 1)."""
    return tonemap(luminance, curve) / curve.max_value


def gamma_encode(fraction: np.ndarray, calibration) -> np.ndarray:
    """8-bit drive values (uint8) that make the calibrated display show ``fraction`` of its range.

    Parameters
    ----------
    fraction : ndarray
        Wanted luminance fraction of [min, max] display luminance, in [0, 1].
    calibration : calibration.Calibration
        Supplies the inverse gamma ``drive_for_fraction``.
    """
    drive = np.asarray(calibration.drive_for_fraction(fraction), dtype=float)
    return np.clip(np.rint(drive * 255.0), 0, 255).astype(np.uint8)


def write_png(path: str | os.PathLike, image_u8: np.ndarray) -> Path:
    """Write a grey 8-bit PNG atomically (temporary file, fsync, ``os.replace``)."""
    from PIL import Image

    path = Path(path)
    img = np.asarray(image_u8)
    if img.dtype != np.uint8 or img.ndim != 2:
        raise ValueError(f"write_png needs a 2-D uint8 image, got {img.dtype} {img.shape}")
    with atomic_open(path, "wb") as fh:
        Image.fromarray(img).save(fh, format="PNG")
    return path
