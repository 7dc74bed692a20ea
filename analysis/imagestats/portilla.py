"""Portilla-Simoncelli texture statistics through plenoptic (CPU PyTorch).

Portilla J & Simoncelli EP (2000) A parametric texture model based on joint statistics of complex
wavelet coefficients. IJCV 40:49-71. plenoptic's ``models.PortillaSimoncelli`` returns only the
non-redundant statistics (710 for 4 scales x 4 orientations, spatial width 7); each becomes one
column ``ps_<group>_<i>_<j>...`` named by its place in ``convert_to_dict``'s arrays.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["ps_names", "ps_statistics"]


@lru_cache(maxsize=8)
def _model(size_px: int, n_scales: int, n_orientations: int, spatial_corr_width: int):
    import plenoptic as po

    try:
        return po.models.PortillaSimoncelli(
            (size_px, size_px), n_scales=n_scales, n_orientations=n_orientations,
            spatial_corr_width=spatial_corr_width,
        )
    except ValueError as exc:
        raise ValueError(f"Portilla-Simoncelli on {size_px} px: {exc}") from exc


@lru_cache(maxsize=8)
def ps_names(size_px: int, *, n_scales: int = 4, n_orientations: int = 4,
             spatial_corr_width: int = 7) -> tuple[str, ...]:
    """Column names of the PS statistics, in the order of the model's output vector.

    Each name is ``ps_`` + plenoptic's group name (``pixel_statistics``,
    ``auto_correlation_magnitude``, ...) + the statistic's index in that group's array, e.g.
    ``ps_pixel_statistics_1`` (the variance) or ``ps_magnitude_std_2_0`` (orientation 2,
    scale 0).
    """
    import torch

    model = _model(size_px, n_scales, n_orientations, spatial_corr_width)
    with torch.no_grad():
        n = int(model(torch.ones(1, 1, size_px, size_px)).shape[-1])
    groups = model.convert_to_dict(torch.arange(n, dtype=torch.float32).reshape(1, 1, n))
    names = [""] * n
    for group, values in groups.items():
        arr = values.numpy()[0, 0]
        for pos in zip(*np.nonzero(np.isfinite(arr))):
            suffix = "_".join(str(int(p)) for p in pos)
            names[int(arr[pos])] = f"ps_{group}_{suffix}"
    if "" in names:
        raise RuntimeError("could not name every Portilla-Simoncelli statistic")
    return tuple(names)


def ps_statistics(image: np.ndarray, *, n_scales: int = 4, n_orientations: int = 4,
                  spatial_corr_width: int = 7) -> np.ndarray:
    """Portilla-Simoncelli statistics of a square luminance image.

    Parameters
    ----------
    image : ndarray, shape (n, n)
        Luminance, finite; n divisible by 2**n_scales and large enough for the coarsest scale's
        spatial correlations (n >= 128 for the defaults).
    n_scales, n_orientations, spatial_corr_width : int
        plenoptic's model parameters.

    Returns
    -------
    ndarray, shape (n_stats,)
        float64, in the order of `ps_names`.

    Raises
    ------
    ValueError
        If the image is not square or its side does not suit the pyramid.
    """
    import torch

    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2 or img.shape[0] != img.shape[1]:
        raise ValueError(f"Portilla-Simoncelli needs a square 2-D image, not {img.shape}")
    model = _model(img.shape[0], n_scales, n_orientations, spatial_corr_width)
    with torch.no_grad():
        try:
            out = model(torch.from_numpy(np.ascontiguousarray(img))[None, None])
        except (RuntimeError, ValueError) as exc:
            raise ValueError(
                f"Portilla-Simoncelli on {img.shape[0]} px failed ({exc}); use images of at "
                f"least {2**n_scales * spatial_corr_width} px per side or fewer scales"
            ) from exc
    return out.numpy()[0, 0].astype(np.float64)
