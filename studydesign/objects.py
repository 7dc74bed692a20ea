"""The physical objects: ``[gloss]`` and ``[depth]`` (the reference sets' levels and those
rendered) and ``[array]`` (the ellipsoid array's geometry)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from studydesign.errors import require
from studydesign.tables import build, section

__all__ = ["FIRST_GLOSS_LABEL", "ArraySpec", "DepthSpec", "GlossSpec", "read_array",
           "read_depth", "read_gloss"]


def _levels(levels: Any, n_levels: int, name: str) -> tuple[int, ...]:
    require(
        isinstance(levels, (list, tuple)) and len(levels) > 0,
        f"{name}.rendered_levels must be a non-empty list of level labels, got {levels!r}",
    )
    out = tuple(int(v) for v in levels)
    require(
        all(1 <= v <= n_levels for v in out),
        f"{name}.rendered_levels {list(out)} has labels outside 1..{n_levels}; "
        f"use labels of the physical reference set",
    )
    require(
        len(set(out)) == len(out) and list(out) == sorted(out),
        f"{name}.rendered_levels {list(out)} must be strictly increasing without repeats",
    )
    return out


#: The label of the first (matte, 0 %) gloss reference object. A slider position is the label
#: of the reference object it matches, so the slider's gloss scale is anchored here, not at
#: ``slider.min`` (which only bounds where the marker can go).
FIRST_GLOSS_LABEL = 1.0


@dataclass(frozen=True)
class GlossSpec:
    """Gloss levels: physical references labelled 1..n, ``gloss_pct = step_pct * (label - 1)``."""

    n_levels: int
    step_pct: float
    rendered_levels: tuple[int, ...]

    def __post_init__(self) -> None:
        require(self.n_levels >= 2, f"gloss.n_levels must be >= 2, got {self.n_levels}")
        require(self.step_pct > 0, f"gloss.step_pct must be > 0 %, got {self.step_pct}")
        require(
            self.step_pct * (self.n_levels - 1) <= 100.0 + 1e-9,
            f"gloss levels reach {self.step_pct * (self.n_levels - 1)} % > 100 %; "
            "lower gloss.step_pct or gloss.n_levels",
        )

    @property
    def labels(self) -> tuple[int, ...]:
        """Labels of the physical reference objects, 1..n."""
        return tuple(range(1, self.n_levels + 1))

    def pct(self, level):
        """Gloss in % (0-100) of level label(s) 1..n."""
        return np.round(self.step_pct * (np.asarray(level, dtype=float) - FIRST_GLOSS_LABEL), 10)

    @property
    def physical_pct(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.pct(self.labels))

    @property
    def rendered_pct(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.pct(self.rendered_levels))


@dataclass(frozen=True)
class DepthSpec:
    """Depth levels: ``d_i = step_cm * i`` for i = 1..n (cm)."""

    n_levels: int
    step_cm: float
    rendered_levels: tuple[int, ...]

    def __post_init__(self) -> None:
        require(self.n_levels >= 2, f"depth.n_levels must be >= 2, got {self.n_levels}")
        require(self.step_cm > 0, f"depth.step_cm must be > 0 cm, got {self.step_cm}")

    @property
    def labels(self) -> tuple[int, ...]:
        return tuple(range(1, self.n_levels + 1))

    def cm(self, level):
        """Maximum ellipsoid height d_i in cm of level label(s) i."""
        return np.round(self.step_cm * np.asarray(level, dtype=float), 10)

    @property
    def physical_cm(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.cm(self.labels))

    @property
    def rendered_cm(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.cm(self.rendered_levels))


@dataclass(frozen=True)
class ArraySpec:
    """The ellipsoid array: ``n_x * n_y`` half-ellipsoids on a jittered grid (cm)."""

    n_x: int
    n_y: int
    extent_cm: float
    pitch_cm: float
    radius_xy_cm: float
    jitter_cm: float
    z_radius_min_fraction: float

    def __post_init__(self) -> None:
        require(self.n_x >= 1 and self.n_y >= 1, "array.n_x and array.n_y must be >= 1")
        require(self.extent_cm > 0, f"array.extent_cm must be > 0, got {self.extent_cm}")
        require(self.pitch_cm > 0, f"array.pitch_cm must be > 0, got {self.pitch_cm}")
        require(
            self.pitch_cm * (max(self.n_x, self.n_y) - 1) <= self.extent_cm + 1e-9,
            f"array.pitch_cm {self.pitch_cm} puts grid centres outside the "
            f"{self.extent_cm} cm square; use pitch_cm <= extent_cm / (n - 1)",
        )
        require(self.radius_xy_cm > 0, "array.radius_xy_cm must be > 0")
        require(self.jitter_cm >= 0, "array.jitter_cm must be >= 0")
        require(
            max(self.n_x, self.n_y) == 1 or self.jitter_cm < self.pitch_cm / 2,
            f"array.jitter_cm {self.jitter_cm:g} is not under half the pitch_cm "
            f"{self.pitch_cm:g}: centres would leave their cells and cross their neighbours' "
            f"(and the {self.extent_cm:g} cm square); use jitter_cm < {self.pitch_cm / 2:g} "
            "(the source study's 0.2 cm on a 1 cm pitch)",
        )
        require(
            0.0 <= self.z_radius_min_fraction <= 1.0,
            "array.z_radius_min_fraction must lie in [0, 1]",
        )

    @property
    def n_ellipsoids(self) -> int:
        return self.n_x * self.n_y

    def grid_centres_cm(self) -> np.ndarray:
        """Un-jittered centres, shape (n_x * n_y, 2), in cm, centred on the origin."""
        xs = (np.arange(self.n_x) - (self.n_x - 1) / 2.0) * self.pitch_cm
        ys = (np.arange(self.n_y) - (self.n_y - 1) / 2.0) * self.pitch_cm
        gx, gy = np.meshgrid(xs, ys, indexing="xy")
        return np.column_stack([gx.ravel(), gy.ravel()])


def _rendered_levels(table: dict, name: str) -> dict:
    """``rendered_levels`` checked against ``n_levels``, as an override for :func:`build`; none
    where the key is missing (build then names every missing key)."""
    if "rendered_levels" not in table:
        return {}
    return {"rendered_levels": _levels(table["rendered_levels"], int(table.get("n_levels", 0)),
                                       name)}


def read_gloss(raw: dict, path: Path) -> GlossSpec:
    """The ``[gloss]`` table of a design file's ``raw`` tables."""
    g = section(raw, "gloss", path, GlossSpec)
    return build(GlossSpec, g, "gloss", path, **_rendered_levels(g, "gloss"))


def read_depth(raw: dict, path: Path) -> DepthSpec:
    """The ``[depth]`` table of a design file's ``raw`` tables."""
    d = section(raw, "depth", path, DepthSpec)
    return build(DepthSpec, d, "depth", path, **_rendered_levels(d, "depth"))


def read_array(raw: dict, path: Path) -> ArraySpec:
    """The ``[array]`` table of a design file's ``raw`` tables."""
    return build(ArraySpec, section(raw, "array", path), "array", path)
