"""Spatial uniformity of the display: a relative-luminance map and a correction gain map.

A CRT is brightest near the centre and dims towards the corners (beam landing, phosphor and
glass). The map holds, at each measured position, the position's luminance above black relative
to the centre's, pooled over the bright levels. The correction gain at a position is the factor
(<= 1) by which linear luminance above black must be scaled there so every position matches the
dimmest one: ``gain = min(relative) / relative``.

Positions are in PsychoPy ``norm`` units: x_norm, y_norm in [-1, 1], (0, 0) the screen centre,
y up.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from calibration.errors import CalibrationError
from calibration.readings import at_centre

__all__ = ["UniformityMap", "fit_uniformity"]


@dataclass(frozen=True)
class UniformityMap:
    """Relative luminance and correction gain on a grid of screen positions.

    Attributes
    ----------
    x_norm, y_norm : tuple[float, ...]
        Grid coordinates (sorted, unique) in norm units.
    relative : tuple[tuple[float, ...], ...]
        ``relative[j][i]``: luminance above black at (x_norm[i], y_norm[j]) over the centre's
        (or, without a centre reading, over the grid's mean). Unitless.
    gain : tuple[tuple[float, ...], ...]
        Correction gain, same layout; ``min(relative) / relative``, in (0, 1].
    nonuniformity_pct : float
        (max - min) / max of ``relative`` in %.
    min_level : float
        Levels at or above this drive value were pooled.
    """

    x_norm: tuple
    y_norm: tuple
    relative: tuple
    gain: tuple
    nonuniformity_pct: float
    min_level: float

    def gain_at(self, x_norm, y_norm) -> np.ndarray:
        """Correction gain at any position, bilinearly interpolated (clamped at the grid's edge).

        Parameters
        ----------
        x_norm, y_norm : array_like
            Positions in norm units; broadcast together.
        """
        from scipy.interpolate import RegularGridInterpolator

        xs, ys = np.asarray(self.x_norm), np.asarray(self.y_norm)
        g = np.asarray(self.gain, dtype=float)
        x, y = np.broadcast_arrays(np.asarray(x_norm, float), np.asarray(y_norm, float))
        pts = np.stack([np.clip(y, ys.min(), ys.max()), np.clip(x, xs.min(), xs.max())], -1)
        if xs.size == 1 or ys.size == 1:
            return np.full(x.shape, float(g.mean()))
        return RegularGridInterpolator((ys, xs), g)(pts)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> UniformityMap:
        try:
            return cls(
                x_norm=tuple(float(v) for v in d["x_norm"]),
                y_norm=tuple(float(v) for v in d["y_norm"]),
                relative=tuple(tuple(float(v) for v in row) for row in d["relative"]),
                gain=tuple(tuple(float(v) for v in row) for row in d["gain"]),
                nonuniformity_pct=float(d["nonuniformity_pct"]),
                min_level=float(d["min_level"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(f"uniformity record is malformed ({exc!r})") from exc


def fit_uniformity(readings: pd.DataFrame, *, min_level: float = 0.5) -> UniformityMap:
    """Uniformity map from readings at several positions.

    Parameters
    ----------
    readings : DataFrame
        Columns x_norm, y_norm, level (drive in [0, 1]), luminance_cd_m2; usable readings only.
    min_level : float, keyword-only
        Pool levels at or above this drive value (dim levels are dominated by black and noise).

    Returns
    -------
    UniformityMap

    Raises
    ------
    CalibrationError
        If a column is missing, there is no reading at level 0 (black) per position, or no
        reading at or above ``min_level``.
    """
    need = {"x_norm", "y_norm", "level", "luminance_cd_m2"}
    missing = need - set(readings.columns)
    if missing:
        raise CalibrationError(f"readings lack column(s) {sorted(missing)}")
    df = readings[list(need)].astype(float)
    means = df.groupby(["x_norm", "y_norm", "level"], as_index=False)["luminance_cd_m2"].mean()
    black = means[means["level"] == means["level"].min()].set_index(["x_norm", "y_norm"])
    bright = means[means["level"] >= min_level]
    if bright.empty:
        raise CalibrationError(
            f"no readings at level >= {min_level}; lower min_level or measure brighter levels"
        )
    bright = bright.join(black["luminance_cd_m2"].rename("black"), on=["x_norm", "y_norm"])
    bright["above"] = bright["luminance_cd_m2"] - bright["black"]
    xs = np.sort(df["x_norm"].unique())
    ys = np.sort(df["y_norm"].unique())
    # Reference per level: the centre if measured, else the mean over positions.
    centre = bright[at_centre(bright)]
    if centre.empty:
        ref = bright.groupby("level")["above"].mean()
    else:
        ref = centre.set_index("level")["above"]
    bright["ratio"] = bright["above"] / bright["level"].map(ref)
    ratio = bright.groupby(["y_norm", "x_norm"])["ratio"].median()
    rel = np.full((ys.size, xs.size), np.nan)
    for (y, x), r in ratio.items():
        rel[np.searchsorted(ys, y), np.searchsorted(xs, x)] = r
    if np.isnan(rel).any():
        raise CalibrationError(
            "uniformity grid is incomplete: some position lacks bright readings; rerun to resume"
        )
    gain = rel.min() / rel
    return UniformityMap(
        x_norm=tuple(float(v) for v in xs),
        y_norm=tuple(float(v) for v in ys),
        relative=tuple(tuple(float(v) for v in row) for row in rel),
        gain=tuple(tuple(float(v) for v in row) for row in gain),
        nonuniformity_pct=float(100 * (rel.max() - rel.min()) / rel.max()),
        min_level=float(min_level),
    )
