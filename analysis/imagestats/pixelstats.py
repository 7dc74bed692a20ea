"""Pixel statistics of the stimulus region: mean luminance, RMS contrast, skewness, kurtosis and
highlight coverage (definitions in protocol.md, "Image statistics")."""

from __future__ import annotations

import numpy as np

__all__ = ["PIXEL_STATS", "pixel_statistics"]

#: Names of the pixel statistics, in the order `pixel_statistics` returns them.
PIXEL_STATS = (
    "mean_luminance",
    "rms_contrast",
    "skewness",
    "kurtosis",
    "highlight_coverage",
    "diffuse_luminance",
)


def pixel_statistics(luminance: np.ndarray, *, highlight_factor: float) -> dict[str, float]:
    """The first four moments of the luminance distribution and the highlight coverage.

    With L the N pixel luminances of the region, mu = mean(L) and m_k = mean((L - mu)^k)
    (population moments, ddof = 0):

    - ``mean_luminance`` = mu (the image's luminance unit, e.g. the renderer's CIE Y);
    - ``rms_contrast`` = sqrt(m_2) / mu (Peli 1990's RMS contrast, normalised by the mean);
    - ``skewness`` = m_3 / m_2^1.5 (Motoyoshi et al. 2007 relate it to gloss);
    - ``kurtosis`` = m_4 / m_2^2 (Pearson's, 3 for a Gaussian; not the excess);
    - ``diffuse_luminance`` = median(L), the diffuse level: highlights cover well under half
      of a glossy surface, so the median pixel is lit diffusely, whatever the highlights' strength;
    - ``highlight_coverage`` = fraction of pixels with L > highlight_factor * median(L).

    Parameters
    ----------
    luminance : ndarray
        Luminance of the region's pixels (any shape; all are used), finite and >= 0.
    highlight_factor : float
        Highlight threshold as a multiple of the diffuse level (> 1).

    Returns
    -------
    dict
        The values named in `PIXEL_STATS`, as floats.

    Raises
    ------
    ValueError
        If the region is empty, holds NaN/Inf or negative values, has mean or median 0 (a black
        image), or is uniform (skewness and kurtosis are undefined).
    """
    lum = np.asarray(luminance, dtype=np.float64).ravel()
    if lum.size == 0:
        raise ValueError("the stimulus region holds no pixels")
    bad = ~np.isfinite(lum)
    if bad.any():
        raise ValueError(f"{int(bad.sum())} pixels are NaN or Inf; re-render the image")
    if (lum < 0).any():
        raise ValueError(
            f"{int((lum < 0).sum())} pixels have negative luminance (min {lum.min():g}); "
            "luminance cannot be negative: re-render the image"
        )
    mu = lum.mean()
    median = float(np.median(lum))
    if mu <= 0 or median <= 0:
        raise ValueError(
            f"the stimulus region is black (mean {mu:g}, median {median:g}); check the "
            "illumination and camera of the render"
        )
    dev = lum - mu
    m2 = np.mean(dev**2)
    if m2 <= (1e-12 * mu) ** 2:
        raise ValueError(
            f"the stimulus region is uniform (luminance {mu:g} everywhere); skewness and "
            "kurtosis are undefined: check the render"
        )
    return {
        "mean_luminance": float(mu),
        "rms_contrast": float(np.sqrt(m2) / mu),
        "skewness": float(np.mean(dev**3) / m2**1.5),
        "kurtosis": float(np.mean(dev**4) / m2**2),
        "highlight_coverage": float(np.mean(lum > highlight_factor * median)),
        "diffuse_luminance": median,
    }
