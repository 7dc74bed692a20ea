"""Residuals of a fit, kept as data: regions of the sphere, RMSE by region, highlight offset.

Regions on the fit grid (r = distance from the sphere's projected centre in sphere radii):

* rim: 0.85 <= r < 1 + 1 px (near the silhouette, where registration and Fresnel matter most);
* highlight: r < 0.85 where the fitted specular component is at least half its maximum on the
  sphere (empty when the fit has no specular light);
* body: r < 0.85, not highlight;
* background: beyond the rim.

RMSEs are relative: the root mean squared residual of a region divided by the photo's mean
luminance on the sphere (0.05 = 5 %), so photo sets of different exposure compare.
"""

from __future__ import annotations

import numpy as np

from stimuli.glossfit.scene import Camera, sphere_distance_px

__all__ = ["RIM_START", "highlight_centroid", "region_masks", "region_rmse"]

#: Where the rim begins, in sphere radii.
RIM_START = 0.85


def region_masks(camera: Camera, specular_lum: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks highlight, body, rim, background on the fit grid (module docstring)."""
    r = sphere_distance_px(camera)
    edge = 1.0 + 1.0 / camera.sphere_radius_px
    inner = r < RIM_START
    rim = (r >= RIM_START) & (r < edge)
    spec = np.where(inner, specular_lum, 0.0)
    top = float(spec.max())
    highlight = inner & (spec >= 0.5 * top) if top > 0 else np.zeros_like(inner)
    return {"highlight": highlight, "body": inner & ~highlight, "rim": rim,
            "background": r >= edge}


def region_rmse(residual_lum: np.ndarray, masks: dict[str, np.ndarray], photo_lum: np.ndarray,
                sphere: np.ndarray, valid: np.ndarray) -> dict[str, float]:
    """Relative RMSE overall (on the sphere) and by region; NaN for an empty region.

    Parameters
    ----------
    residual_lum : ndarray (h, w)
        Photo minus render luminance.
    masks : dict of name -> bool ndarray (h, w)
    photo_lum : ndarray (h, w)
    sphere : bool ndarray (h, w)
        The fit's sphere mask (for "rmse" and the normalising mean).
    valid : bool ndarray (h, w)
        Pixels with photo data (inside the photo, not clipped).
    """
    scale = float(photo_lum[sphere & valid].mean())
    out = {"rmse": float(np.sqrt(np.mean(residual_lum[sphere & valid] ** 2)) / scale)}
    for name, mask in masks.items():
        m = mask & valid
        out[f"rmse_{name}"] = (float(np.sqrt(np.mean(residual_lum[m] ** 2)) / scale)
                               if m.any() else float("nan"))
    return out


def highlight_centroid(lum: np.ndarray, region: np.ndarray) -> tuple[float, float] | None:
    """Luminance-weighted centroid (x, y in pixels) of the brightest 5 % of a region, or None."""
    if region.sum() < 3:
        return None
    values = lum[region]
    threshold = np.quantile(values, 0.95)
    sel = region & (lum >= threshold)
    w = lum[sel] - threshold + 1e-12
    y, x = np.nonzero(sel)
    return float(np.sum(w * (x + 0.5)) / w.sum()), float(np.sum(w * (y + 0.5)) / w.sum())


