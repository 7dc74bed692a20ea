"""The study design as one typed, validated, frozen object.

Every number that defines the gloss x depth study (levels, array geometry, sessions, display,
slider scale, analysis bins) lives in ``design.toml`` and reaches code only through
:class:`StudyDesign`. Nothing here reads a file at import time: call :func:`load_design`.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from labfiles import LabFileError, read_toml

__all__ = [
    "MODEL_RESPONSES",
    "AnalysisModel",
    "AnalysisSpec",
    "ArraySpec",
    "DepthSpec",
    "DesignError",
    "DisplaySpec",
    "GapSpec",
    "GlossSpec",
    "Illumination",
    "ImageStatsSpec",
    "LightField",
    "SessionSpec",
    "SliderSpec",
    "StudyDesign",
    "ToneMapSpec",
    "default_design_path",
    "load_design",
]

STIMULUS_COLUMNS = (
    "stimulus_id",
    "illumination",
    "gloss_level",
    "depth_level",
    "true_gloss_pct",
    "true_depth_cm",
)


class DesignError(ValueError):
    """A design file is missing, malformed, or inconsistent."""


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise DesignError(message)


def _levels(levels: Any, n_levels: int, name: str) -> tuple[int, ...]:
    _require(
        isinstance(levels, (list, tuple)) and len(levels) > 0,
        f"{name}.rendered_levels must be a non-empty list of level labels, got {levels!r}",
    )
    out = tuple(int(v) for v in levels)
    _require(
        all(1 <= v <= n_levels for v in out),
        f"{name}.rendered_levels {list(out)} has labels outside 1..{n_levels}; "
        f"use labels of the physical reference set",
    )
    _require(
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
        _require(self.n_levels >= 2, f"gloss.n_levels must be >= 2, got {self.n_levels}")
        _require(self.step_pct > 0, f"gloss.step_pct must be > 0 %, got {self.step_pct}")
        _require(
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
        _require(self.n_levels >= 2, f"depth.n_levels must be >= 2, got {self.n_levels}")
        _require(self.step_cm > 0, f"depth.step_cm must be > 0 cm, got {self.step_cm}")

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
        _require(self.n_x >= 1 and self.n_y >= 1, "array.n_x and array.n_y must be >= 1")
        _require(self.extent_cm > 0, f"array.extent_cm must be > 0, got {self.extent_cm}")
        _require(self.pitch_cm > 0, f"array.pitch_cm must be > 0, got {self.pitch_cm}")
        _require(
            self.pitch_cm * (max(self.n_x, self.n_y) - 1) <= self.extent_cm + 1e-9,
            f"array.pitch_cm {self.pitch_cm} puts grid centres outside the "
            f"{self.extent_cm} cm square; use pitch_cm <= extent_cm / (n - 1)",
        )
        _require(self.radius_xy_cm > 0, "array.radius_xy_cm must be > 0")
        _require(self.jitter_cm >= 0, "array.jitter_cm must be >= 0")
        _require(
            max(self.n_x, self.n_y) == 1 or self.jitter_cm < self.pitch_cm / 2,
            f"array.jitter_cm {self.jitter_cm:g} is not under half the pitch_cm "
            f"{self.pitch_cm:g}: centres would leave their cells and cross their neighbours' "
            f"(and the {self.extent_cm:g} cm square); use jitter_cm < {self.pitch_cm / 2:g} "
            "(the source study's 0.2 cm on a 1 cm pitch)",
        )
        _require(
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


#: Kinds of light field (and of illumination condition).
LIGHT_KINDS = ("indoor", "outdoor")
#: How a light field's ``scale`` is chosen: the factor that makes a matte white facing the viewer
#: luminance 1 (``stimuli.diffuse_white_scale``; ``python -m stimuli probe-scale FILE``).
SCALE_RULES = ("diffuse_white",)


def _check_scale(scale, where: str) -> None:
    _require(scale is None or (isinstance(scale, (int, float)) and not isinstance(scale, bool)
                               and math.isfinite(scale) and scale > 0),
             f"{where}: scale must be a number > 0 (the factor applied to the file's values; "
             f"`python -m stimuli probe-scale FILE` prints it), got {scale!r}")


@dataclass(frozen=True)
class Illumination:
    """One illumination condition: a name used in stimulus ids and a light-probe file.

    Attributes
    ----------
    name : str
        Lower-case identifier (``indoor``).
    envmap : str
        A shipped probe's file name, or a path (a lab's own panorama).
    kind : {"indoor", "outdoor"}
    scale : float or None
        Factor applied to the file's values (the design's scale rule, ``[imagestats]
        scale_rule``); None (left out): the map is scaled to mean luminance 1, as designs written
        before light fields had scales were.
    """

    name: str
    envmap: str
    kind: str
    scale: float | None = None

    def __post_init__(self) -> None:
        _require(
            self.name.isidentifier() and self.name == self.name.lower(),
            f"illumination name {self.name!r} must be a lower-case identifier (e.g. 'indoor')",
        )
        _require(
            self.kind in LIGHT_KINDS,
            f"illumination {self.name!r}: kind must be 'indoor' or 'outdoor', got {self.kind!r}",
        )
        _check_scale(self.scale, f"illumination {self.name!r}")


@dataclass(frozen=True)
class LightField:
    """One light field of the image-statistics set: a captured panorama and its scale.

    Attributes
    ----------
    name : str
        Lower-case identifier, used in stimulus ids and folder names (``noon_grass``).
    envmap : str
        A shipped probe's file name (``stimuli/probes``), or a path.
    kind : {"indoor", "outdoor"}
    scale : float
        Factor applied to the file's values, > 0, chosen by ``[imagestats] scale_rule``.
    """

    name: str
    envmap: str
    kind: str
    scale: float

    def __post_init__(self) -> None:
        _require(self.name.isidentifier() and self.name == self.name.lower(),
                 f"light field name {self.name!r} must be a lower-case identifier "
                 "(e.g. 'noon_grass')")
        _require(self.kind in LIGHT_KINDS,
                 f"light field {self.name!r}: kind must be 'indoor' or 'outdoor', got "
                 f"{self.kind!r}")
        _require(isinstance(self.envmap, str) and self.envmap != "",
                 f"light field {self.name!r}: envmap must name a probe file")
        _check_scale(self.scale, f"light field {self.name!r}")
        _require(self.scale is not None, f"light field {self.name!r}: give its scale")


@dataclass(frozen=True)
class ToneMapSpec:
    """The source study's tone mapping: linear below the knee, asymptotic logistic above
    (8-bit values)."""

    linear_fraction: float
    knee_value: int
    max_value: int

    def __post_init__(self) -> None:
        _require(
            0.0 < self.linear_fraction < 1.0,
            f"tonemap.linear_fraction must lie in (0, 1), got {self.linear_fraction}",
        )
        _require(
            0 < self.knee_value < self.max_value,
            "tonemap.knee_value must lie between 0 and tonemap.max_value",
        )


@dataclass(frozen=True)
class SessionSpec:
    n_sessions: int
    trials_per_session: int


@dataclass(frozen=True)
class DisplaySpec:
    """The CRT as the design expects it."""

    resolution_px: tuple[int, int]
    viewing_distance_cm: float
    nominal_refresh_hz: float

    def __post_init__(self) -> None:
        _require(
            len(self.resolution_px) == 2 and all(v > 0 for v in self.resolution_px),
            f"display.resolution_px must be [width, height] in pixels, got {self.resolution_px}",
        )
        _require(self.viewing_distance_cm > 0, "display.viewing_distance_cm must be > 0")
        _require(self.nominal_refresh_hz > 0, "display.nominal_refresh_hz must be > 0")

    @property
    def frame_s(self) -> float:
        """Nominal frame duration in s."""
        return 1.0 / self.nominal_refresh_hz


@dataclass(frozen=True)
class SliderSpec:
    """Continuous slider scale and its mapping to physical units."""

    min: float
    max: float
    depth_cm_per_unit: float
    gloss_pct_per_unit: float

    def __post_init__(self) -> None:
        _require(self.max > self.min, "slider.max must exceed slider.min")

    @property
    def ticks(self) -> tuple[int, ...]:
        return tuple(range(int(np.ceil(self.min)), int(np.floor(self.max)) + 1))

    def _check(self, value) -> np.ndarray:
        v = np.asarray(value, dtype=float)
        bad = ~np.isfinite(v) | (v < self.min) | (v > self.max)
        if np.any(bad):
            raise DesignError(
                f"slider value(s) {np.atleast_1d(v)[np.atleast_1d(bad)][:5].tolist()} lie outside "
                f"[{self.min:g}, {self.max:g}]; slider matches are raw slider positions"
            )
        return v

    def to_depth_cm(self, value):
        """Slider position(s) in [min, max] -> matched depth in cm (``depth_cm_per_unit * v``,
        0.4 v in the shipped design: position v matches the depth reference labelled v)."""
        return self.depth_cm_per_unit * self._check(value)

    def to_gloss_pct(self, value):
        """Slider position(s) in [min, max] -> matched gloss in %
        (``gloss_pct_per_unit * (v - FIRST_GLOSS_LABEL)``, 10 (v - 1) in the shipped design:
        position v matches the gloss reference labelled v whatever ``min`` is; ``min`` and
        ``max`` bound the positions accepted)."""
        return self.gloss_pct_per_unit * (self._check(value) - FIRST_GLOSS_LABEL)

    def from_depth_cm(self, depth_cm, *, clip: bool):
        """Depth in cm -> slider position(s), the inverse of :meth:`to_depth_cm`.

        ``clip=True`` clips to [min, max], where a slider's marker can be (a simulated
        observer's answer); ``clip=False`` returns positions the slider may not reach.
        """
        v = np.asarray(depth_cm, dtype=float) / self.depth_cm_per_unit
        return np.clip(v, self.min, self.max) if clip else v

    def from_gloss_pct(self, gloss_pct, *, clip: bool):
        """Gloss in % -> slider position(s), the inverse of :meth:`to_gloss_pct` (whatever
        ``min`` is, ``to_gloss_pct(from_gloss_pct(g)) == g``); ``clip`` as
        :meth:`from_depth_cm`."""
        v = FIRST_GLOSS_LABEL + np.asarray(gloss_pct, dtype=float) / self.gloss_pct_per_unit
        return np.clip(v, self.min, self.max) if clip else v


#: Responses of the analysis's model frame a mixed model may use (analysis.models.model_frame).
MODEL_RESPONSES = ("gloss_match_pct", "depth_match_bc", "depth_match_cm")


@dataclass(frozen=True)
class AnalysisModel:
    """An extra mixed model the report fits (a table of ``[analysis.models]``).

    Attributes
    ----------
    name : str
        The table's name, e.g. ``gloss_crossed`` (letters, digits, ``_``).
    response : str
        One of `MODEL_RESPONSES`.
    formula : str
        The right-hand side of ``response ~ ...`` in lme4 syntax, with at least one random term,
        e.g. ``gloss * depth + (1 + gloss + depth | participant) + (1 | stimulus_id)``.
    label : str
        What the model is, for the report.
    source_model : str
        ``"gloss"`` or ``"depth"`` when the model re-specifies that model of the source study
        (the report then checks the source's findings under it), else ``""``.
    """

    name: str
    response: str
    formula: str
    label: str = ""
    source_model: str = ""

    def __post_init__(self) -> None:
        where = f"analysis.models.{self.name}"
        _require(self.name.replace("_", "").isalnum(),
                 f"{where}: use letters, digits or '_' in a model name")
        _require(self.name not in ("gloss", "depth"),
                 f"{where}: 'gloss' and 'depth' name the source study's models; choose another "
                 "name (e.g. gloss_crossed)")
        _require(self.response in MODEL_RESPONSES,
                 f"{where}.response {self.response!r} is not one of {list(MODEL_RESPONSES)}")
        _require(isinstance(self.formula, str) and "~" not in self.formula,
                 f"{where}.formula must be the right-hand side only (no '~'; the response is "
                 f"{where}.response), e.g. 'gloss * depth + (1 | participant)'")
        depth = 0
        for ch in self.formula:
            depth += {"(": 1, ")": -1}.get(ch, 0)
            _require(depth >= 0, f"{where}.formula {self.formula!r} has an unmatched ')'")
        _require(depth == 0, f"{where}.formula {self.formula!r} has an unmatched '('")
        _require("|" in self.formula,
                 f"{where}.formula {self.formula!r} has no random-effect term such as "
                 "(1 | participant)")
        _require(self.source_model in ("", "gloss", "depth"),
                 f"{where}.source_model {self.source_model!r} must be 'gloss', 'depth' or "
                 "left out")
        _require(not self.source_model
                 or {"gloss": "gloss_match_pct", "depth": "depth_match_bc"}[self.source_model]
                 == self.response,
                 f"{where}: source_model {self.source_model!r} needs the source model's "
                 "response (gloss: gloss_match_pct, depth: depth_match_bc)")


@dataclass(frozen=True)
class AnalysisSpec:
    depth_bins_cm: dict[str, tuple[float, ...]]
    gloss_bins_pct: dict[str, tuple[float, ...]]
    depth_boxcox_lambda: float
    models: tuple[AnalysisModel, ...] = ()


@dataclass(frozen=True)
class ImageStatsSpec:
    """The large render set of the image-statistics analysis: every light field x every physical
    gloss and depth level x ``n_arrays`` arrays (seed: 22 x 11 x 11 x 22 = 58,564).

    Attributes
    ----------
    n_arrays : int
        Random arrays per light field, gloss and depth level, >= 1.
    light_fields : tuple of LightField
        Distinct files (one scene each: no file twice, so no rotation stands in for a scene).
    scale_rule : str
        How each light field's ``scale`` was chosen (:data:`SCALE_RULES`).
    """

    n_arrays: int
    light_fields: tuple[LightField, ...]
    scale_rule: str = "diffuse_white"

    def __post_init__(self) -> None:
        _require(self.n_arrays >= 1, "imagestats.n_arrays must be >= 1")
        _require(len(self.light_fields) >= 1,
                 "imagestats.light_fields must list at least one light field")
        names = [lf.name for lf in self.light_fields]
        _require(len(set(names)) == len(names),
                 f"imagestats.light_fields: names repeat: "
                 f"{sorted({n for n in names if names.count(n) > 1})}")
        files = [Path(lf.envmap).name for lf in self.light_fields]
        _require(len(set(files)) == len(files),
                 f"imagestats.light_fields: files repeat "
                 f"{sorted({f for f in files if files.count(f) > 1})}; each light field is its "
                 "own capture (a rotated copy is the same scene seen from another side)")
        _require(self.scale_rule in SCALE_RULES,
                 f"imagestats.scale_rule {self.scale_rule!r} is not one of {list(SCALE_RULES)}")

    @property
    def n_light_fields(self) -> int:
        return len(self.light_fields)

    def light_field(self, name: str) -> LightField:
        for lf in self.light_fields:
            if lf.name == name:
                return lf
        raise DesignError(f"unknown light field {name!r}; the design has "
                          f"{[lf.name for lf in self.light_fields]}")


#: Mitsuba variants a render may name ("auto": monochrome for grey materials, CUDA when found).
RENDER_VARIANTS = ("auto", "llvm_ad_mono", "llvm_ad_rgb", "llvm_ad_spectral", "cuda_ad_mono",
                   "cuda_ad_rgb", "cuda_ad_spectral")


@dataclass(frozen=True)
class RenderSpec:
    """How stimuli are rendered: variant, the displayed-error target and the spp it implies.

    Attributes
    ----------
    variant : str
        One of :data:`RENDER_VARIANTS`.
    displayed_error_pct : float
        Target RMS difference between a render and its noise-free expectation after the tone
        map, in % of the display range (0-255), in (0, 10].
    spp_by_gloss_level : tuple of int
        Samples per pixel of each physical gloss level (labels 1..n), each >= 1: the smallest
        that reaches ``displayed_error_pct`` (measured by ``python -m stimuli plan-spp``).
    spp_planned_at_px : int
        Image width (px) the spp were measured at.
    spp_by_light_field : tuple of (str, tuple of int)
        ``[render.spp_by_light_field]``: per light field (its name), the spp of each gloss level
        measured under that light field alone (``plan-spp --light-fields all``); a light field
        not listed takes ``spp_by_gloss_level``.
    """

    variant: str
    displayed_error_pct: float
    spp_by_gloss_level: tuple[int, ...]
    spp_planned_at_px: int
    spp_by_light_field: tuple[tuple[str, tuple[int, ...]], ...] = ()

    def __post_init__(self) -> None:
        _require(self.variant in RENDER_VARIANTS,
                 f"render.variant {self.variant!r} is not one of {list(RENDER_VARIANTS)}")
        _require(0.0 < float(self.displayed_error_pct) <= 10.0,
                 f"render.displayed_error_pct must lie in (0, 10] (% of the display range), got "
                 f"{self.displayed_error_pct}")
        _require(all(isinstance(v, int) and v >= 1 for v in self.spp_by_gloss_level),
                 f"render.spp_by_gloss_level must hold integers >= 1, got "
                 f"{list(self.spp_by_gloss_level)}")
        _require(isinstance(self.spp_planned_at_px, int) and self.spp_planned_at_px >= 8,
                 f"render.spp_planned_at_px must be an integer >= 8, got {self.spp_planned_at_px}")
        for name, spp in self.spp_by_light_field:
            _require(all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in spp),
                     f"render.spp_by_light_field.{name} = {list(spp)}: give one whole number "
                     ">= 1 per gloss level, as `python -m stimuli plan-spp --light-fields all` "
                     "prints them")

    def spp(self, gloss_level: int, light_field: str | None = None) -> int:
        """Samples per pixel of a gloss level label (1..n), under ``light_field`` where its own
        counts are listed (``spp_by_light_field``), else the design-wide ones."""
        own = dict(self.spp_by_light_field).get(light_field) if light_field else None
        return (own or self.spp_by_gloss_level)[int(gloss_level) - 1]


@dataclass(frozen=True)
class GapSpec:
    """Practical tolerances of the sim-to-real gap diagnosis (``analysis.gap``).

    Attributes
    ----------
    render_tolerance_pct : float
        The render layer's tolerance for what the catalogue leaves: a remaining misfit between
        the photos and the extended renders counts as a gap beyond the catalogue only if it is
        statistically significant *and* at least this large, as an RMS over the sphere's pixels
        in % of the photos' RMS luminance; a smaller one is reported with its size but not
        flagged. In (0, 20]. Default 1.0 (see the shipped design.toml for why).
    observer_tolerance_slider : float
        The observer layer's tolerance, in slider units: what the catalogue leaves counts as a
        gap beyond it only if it is statistically significant *and* the chosen model's
        predicted settings lie at least this far (RMS over held-out trials, gloss and depth
        together) from a flexible model of the data. In (0, 2]. Default 0.25 (2.5 % gloss,
        0.1 cm depth in the shipped slider; see the shipped design.toml for why). Another
        lab's rating study is held to the same share of its own scale (0.25 of the slider's
        span of 10 is 2.5 % of the scale's span).
    display_tolerance_pct : float
        The display layer's tolerance: a remaining misfit between a check's photometer
        readings and the calibration (with the effects the diagnosis chose) counts as a gap
        only if it is statistically significant *and* its systematic RMS, in % of each
        reading's luminance (readings above near black), is at least this large; a smaller one
        is "no gap that matters", reported with its size and where it lies. In (0, 20].
        Default 1.0 (see the shipped design.toml for why).

    A design written before this section existed has no ``[gap]``: it takes these defaults,
    so an older lab design still runs sessions and renders (the diagnosis reports the
    tolerance it used).
    """

    render_tolerance_pct: float = 1.0
    observer_tolerance_slider: float = 0.25
    display_tolerance_pct: float = 1.0

    def __post_init__(self) -> None:
        _require(0.0 < float(self.render_tolerance_pct) <= 20.0,
                 f"gap.render_tolerance_pct must lie in (0, 20] (% of the photos' RMS "
                 f"luminance), got {self.render_tolerance_pct}")
        _require(0.0 < float(self.observer_tolerance_slider) <= 2.0,
                 f"gap.observer_tolerance_slider must lie in (0, 2] (slider units, RMS), got "
                 f"{self.observer_tolerance_slider}")
        _require(0.0 < float(self.display_tolerance_pct) <= 20.0,
                 f"gap.display_tolerance_pct must lie in (0, 20] (% of luminance), got "
                 f"{self.display_tolerance_pct}")


@dataclass(frozen=True)
class ClusterSpec:
    """Batch jobs of ``--cluster slurm|pbs|sge`` (renders, image statistics): one Dask worker
    per job; the command line's ``--cores`` etc. override each.

    Attributes
    ----------
    cores : int
        Cores per job, >= 1.
    memory : str
        Memory per job (``"8GiB"``).
    walltime : str
        Run time per job, ``HH:MM:SS`` (a job that ends is replaced).
    queue : str
        Queue or SLURM partition; empty: the system's default.
    jobs : int
        Jobs kept running at once, >= 1.
    account : str
        Account or project charged; empty: the user's default.

    A design without ``[cluster]`` takes these defaults.
    """

    cores: int = 4
    memory: str = "8GiB"
    walltime: str = "04:00:00"
    queue: str = ""
    jobs: int = 4
    account: str = ""

    def __post_init__(self) -> None:
        _require(isinstance(self.cores, int) and self.cores >= 1,
                 f"cluster.cores must be an integer >= 1, got {self.cores!r}")
        _require(isinstance(self.jobs, int) and self.jobs >= 1,
                 f"cluster.jobs must be an integer >= 1, got {self.jobs!r}")
        _require(re.fullmatch(r"(\d+-)?\d{1,3}:\d{2}:\d{2}", str(self.walltime)) is not None,
                 f"cluster.walltime must be HH:MM:SS, got {self.walltime!r}")


@dataclass(frozen=True)
class StudyDesign:
    """The whole study design. Build it with :func:`load_design`."""

    gloss: GlossSpec
    depth: DepthSpec
    array: ArraySpec
    illuminations: tuple[Illumination, ...]
    tonemap: ToneMapSpec
    sessions: SessionSpec
    display: DisplaySpec
    slider: SliderSpec
    analysis: AnalysisSpec
    imagestats: ImageStatsSpec
    render: RenderSpec
    gap: GapSpec
    source: str = ""
    cluster: ClusterSpec = ClusterSpec()

    def spp(self, gloss_level: int, light_field: str) -> int:
        """Samples per pixel of a gloss level label under a light field (an image-statistics
        light field's name, or an illumination's, which takes the counts of the light field
        with its file and scale where it has none of its own)."""
        own = dict(self.render.spp_by_light_field)
        if light_field not in own:
            il = next((il for il in self.illuminations if il.name == light_field), None)
            twin = next((lf.name for lf in self.imagestats.light_fields if il is not None
                         and Path(lf.envmap).name == Path(il.envmap).name
                         and lf.scale == il.scale), None)
            light_field = twin or light_field
        return self.render.spp(gloss_level, light_field)

    def __post_init__(self) -> None:
        _require(
            len(self.render.spp_by_gloss_level) == self.gloss.n_levels,
            f"render.spp_by_gloss_level has {len(self.render.spp_by_gloss_level)} values; give "
            f"one per physical gloss level ({self.gloss.n_levels}, labels 1..{self.gloss.n_levels})",
        )
        names = [il.name for il in self.illuminations]
        _require(len(names) >= 1, "the design needs at least one [[illuminations]] entry")
        _require(len(set(names)) == len(names), f"illumination names repeat: {names}")
        for lf, spp in self.render.spp_by_light_field:
            _require(len(spp) == self.gloss.n_levels,
                     f"render.spp_by_light_field.{lf} = {list(spp)}: give one whole number >= 1 "
                     f"per gloss level ({self.gloss.n_levels}), as `python -m stimuli plan-spp "
                     "--light-fields all` prints them")
        known = {lf.name for lf in self.imagestats.light_fields} | set(names)
        unknown = sorted({n for n, _ in self.render.spp_by_light_field} - known)
        _require(not unknown, f"render.spp_by_light_field names {unknown}, which are no light "
                              f"field of [imagestats] nor illumination: use one of {sorted(known)}")
        n = self.n_stimuli
        _require(
            self.sessions.n_sessions * self.sessions.trials_per_session == n,
            f"sessions: {self.sessions.n_sessions} x {self.sessions.trials_per_session} trials "
            f"!= {n} stimuli ({len(names)} illuminations x {len(self.gloss.rendered_levels)} "
            f"gloss x {len(self.depth.rendered_levels)} depth); fix [sessions]",
        )
        # The slider and the physical reference set must describe the same units.
        _require(
            np.isclose(self.slider.depth_cm_per_unit, self.depth.step_cm)
            and np.isclose(self.slider.gloss_pct_per_unit, self.gloss.step_pct),
            "slider units disagree with the reference sets: slider.depth_cm_per_unit must equal "
            "depth.step_cm and slider.gloss_pct_per_unit must equal gloss.step_pct",
        )
        rendered_depth = set(np.round(self.depth.rendered_cm, 9).tolist())
        for name, values in self.analysis.depth_bins_cm.items():
            _require(
                set(np.round(values, 9)) <= rendered_depth,
                f"analysis.depth_bins_cm.{name} {list(values)} are not rendered depths "
                f"{sorted(rendered_depth)}",
            )
        rendered_gloss = set(np.round(self.gloss.rendered_pct, 9).tolist())
        for name, values in self.analysis.gloss_bins_pct.items():
            _require(
                set(np.round(values, 9)) <= rendered_gloss,
                f"analysis.gloss_bins_pct.{name} {list(values)} are not rendered gloss values",
            )

    @property
    def n_stimuli(self) -> int:
        return (
            len(self.illuminations)
            * len(self.gloss.rendered_levels)
            * len(self.depth.rendered_levels)
        )

    @property
    def n_imagestats_images(self) -> int:
        """Images in the image-statistics set: light fields x every physical gloss and depth
        level x arrays."""
        return (self.imagestats.n_light_fields * self.gloss.n_levels * self.depth.n_levels
                * self.imagestats.n_arrays)

    def illumination_of_kind(self, kind: str) -> str:
        """The condition a light field of ``kind`` belongs to: the name of the design's one
        illumination of that kind (``indoor``), else the kind itself."""
        names = [il.name for il in self.illuminations if il.kind == kind]
        return names[0] if len(names) == 1 else kind

    def illumination(self, name: str) -> Illumination:
        for il in self.illuminations:
            if il.name == name:
                return il
        raise DesignError(
            f"unknown illumination {name!r}; the design has "
            f"{[il.name for il in self.illuminations]}"
        )

    @staticmethod
    def stimulus_id(illumination: str, gloss_level: int, depth_level: int) -> str:
        """Stable stimulus id, e.g. ``indoor_g05_d07``."""
        return f"{illumination}_g{int(gloss_level):02d}_d{int(depth_level):02d}"

    def stimuli(self) -> pd.DataFrame:
        """The experiment's stimulus set, one row per stimulus.

        Returns
        -------
        DataFrame
            Columns ``stimulus_id, illumination, gloss_level, depth_level, true_gloss_pct (%),
            true_depth_cm (cm)``; ``n_stimuli`` rows ordered illumination, gloss, depth.
        """
        rows = []
        for il in self.illuminations:
            for g in self.gloss.rendered_levels:
                for d in self.depth.rendered_levels:
                    rows.append(
                        (
                            self.stimulus_id(il.name, g, d),
                            il.name,
                            g,
                            d,
                            float(self.gloss.pct(g)),
                            float(self.depth.cm(d)),
                        )
                    )
        return pd.DataFrame(rows, columns=list(STIMULUS_COLUMNS))

    def depth_bin(self, depth_cm) -> np.ndarray:
        """Bin name ('low', 'medium', 'high') of each true depth in cm; '' when in no bin."""
        return _bin(depth_cm, self.analysis.depth_bins_cm)

    def gloss_bin(self, gloss_pct) -> np.ndarray:
        """Bin name of each true gloss in %; '' when in no bin."""
        return _bin(gloss_pct, self.analysis.gloss_bins_pct)

    def to_dict(self) -> dict:
        """Plain-dict form, e.g. to save beside data."""
        return asdict(self)


def _bin(values, bins: dict[str, tuple[float, ...]]) -> np.ndarray:
    v = np.round(np.asarray(values, dtype=float), 9)
    out = np.full(v.shape, "", dtype=object)
    for name, members in bins.items():
        out[np.isin(v, np.round(members, 9))] = name
    return out


def default_design_path() -> Path:
    """Path of the ``design.toml`` shipped with the project."""
    return Path(str(resources.files("studydesign").joinpath("design.toml")))


def _section(raw: dict, name: str, path: Path, cls=None) -> dict:
    if name not in raw:
        raise DesignError(f"{path}: missing section [{name}]; see the shipped design.toml")
    if not isinstance(raw[name], dict):
        raise DesignError(f"{path}: {name} must be a table ([{name}]), got {raw[name]!r}")
    if cls is not None:
        _check_types(cls, raw[name], name, path)
    return raw[name]


#: TOML types a design field of each annotated Python type accepts (bool is not a number):
#: (types, what to write, an example).
_TOML_TYPES = {"int": ((int,), "a whole number", "2"),
               "float": ((int, float), "a number", "85.0"),
               "str": ((str,), "text in quotes", '"indoor"')}


def _check_types(cls, raw: dict, name: str, path: Path) -> None:
    """Each value of ``raw`` of the type its field is annotated with (numbers unquoted, lists
    of numbers), so that a quoted number is named here, not as Python's "'>' not supported
    between 'str' and 'int'" later."""
    fields = cls.__dataclass_fields__
    for key, value in raw.items():
        if key not in fields:
            continue  # unknown keys: _build names them
        ann = str(fields[key].type)
        elem = ann.split("[", 1)[1].split(",")[0].strip() if ann.startswith("tuple[") else None
        if ann in _TOML_TYPES:
            types, want, example = _TOML_TYPES[ann]
            ok = isinstance(value, types) and not isinstance(value, bool)
        elif elem in _TOML_TYPES:
            types, want, example = _TOML_TYPES[elem]
            want, example = f"a list of {want.removeprefix('a ')}s", f"[{example}, {example}]"
            ok = isinstance(value, list) and all(
                isinstance(v, types) and not isinstance(v, bool) for v in value)
        else:
            continue
        if not ok:
            shipped = _shipped_value(name, key)
            raise DesignError(f"{path}: [{name}] {key} = {_toml_repr(value)}: write {want}"
                              f"{', without quotes' if 'number' in want else ''} (e.g. {key} = "
                              f"{example if shipped is None else _toml_repr(shipped)})")


def _shipped_value(section: str, key: str):
    """The shipped design's value of ``[section] key`` (an example in messages), or None."""
    try:
        raw = tomllib.loads(default_design_path().read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return None
    table = raw.get(section)
    table = table[0] if isinstance(table, list) and table else table
    return table.get(key) if isinstance(table, dict) else None


def _toml_repr(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_repr(v) for v in value) + "]"
    return repr(value)


def _build(cls, raw: dict, name: str, path: Path, **override):
    fields = set(cls.__dataclass_fields__)
    if not isinstance(raw, dict):
        raise DesignError(f"{path}: [{name}] must be a table of keys, got {_toml_repr(raw)}")
    _check_types(cls, raw, name, path)
    given = dict(raw)
    given.update(override)
    unknown = set(given) - fields
    missing = fields - set(given)
    if unknown:
        raise DesignError(f"{path}: unknown key(s) {sorted(unknown)} in [{name}]")
    if missing:
        raise DesignError(f"{path}: missing key(s) {sorted(missing)} in [{name}]")
    try:
        return cls(**given)
    except TypeError as exc:
        raise DesignError(f"{path}: [{name}]: {exc}") from exc


def _spp_by_light_field(raw: Any, path: Path) -> tuple[tuple[str, tuple[int, ...]], ...]:
    if not isinstance(raw, dict) or not all(isinstance(v, list) for v in raw.values()):
        raise DesignError(f"{path}: [render.spp_by_light_field] must hold one list of spp per "
                          "light field (name = [30, 30, ...]), as `python -m stimuli plan-spp "
                          "--light-fields all` prints it")
    return tuple((str(k), tuple(v)) for k, v in raw.items())


def _models(raw: Any, path: Path) -> tuple[AnalysisModel, ...]:
    if not isinstance(raw, dict):
        raise DesignError(f"{path}: [analysis.models] must hold one table per model")
    out = []
    for name, table in raw.items():
        if not isinstance(table, dict):
            raise DesignError(f"{path}: analysis.models.{name} must be a table "
                              "(response, formula, label, source_model)")
        defaults = {"name": name, "label": "", "source_model": ""}
        out.append(_build(AnalysisModel, {**defaults, **table}, f"analysis.models.{name}", path))
    return tuple(out)


def _imagestats(raw: dict, path: Path) -> ImageStatsSpec:
    lfs = raw.get("light_fields")
    if "n_light_fields" in raw:
        raise DesignError(
            f"{path}: [imagestats] n_light_fields is gone: list the light fields instead, each "
            "its own capture (light_fields = [{ name = ..., envmap = ..., kind = ..., scale = "
            "... }, ...]; see the shipped design.toml), rather than rotations of one probe")
    if not isinstance(lfs, list) or not all(isinstance(t, dict) for t in lfs):
        raise DesignError(f"{path}: [imagestats] light_fields must be a list of tables "
                          "{ name, envmap, kind, scale } (see the shipped design.toml)")
    light_fields = tuple(_build(LightField, t, "imagestats.light_fields", path) for t in lfs)
    return _build(ImageStatsSpec, {"scale_rule": "diffuse_white", **raw}, "imagestats", path,
                  light_fields=light_fields)


def _refuse_non_finite(value, path, key: str = "") -> None:
    """TOML writes nan and inf as numbers; no design value may be either (a Box-Cox lambda of
    nan, a refresh rate of inf passed every range check written as ``x > 0``)."""
    if isinstance(value, dict):
        for k, v in value.items():
            _refuse_non_finite(v, path, f"{key}.{k}" if key else k)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _refuse_non_finite(v, path, f"{key}[{i}]")
    elif isinstance(value, float) and not math.isfinite(value):
        raise DesignError(f"design file {path}: {key} = {value} is not a finite number; write "
                          "a number there (see the shipped design.toml)")


def load_design(path: str | Path | None = None) -> StudyDesign:
    """Load and validate a study design.

    Parameters
    ----------
    path : path-like, optional
        A ``design.toml``; the shipped one when omitted.

    Returns
    -------
    StudyDesign

    Raises
    ------
    DesignError
        If the file is missing, is not TOML, or any value is inconsistent; the message names the
        key and the fix.
    """
    path = Path(path) if path is not None else default_design_path()
    if not path.is_file():
        raise DesignError(f"design file {path} not found; pass an existing design.toml")
    try:
        # A BOM, CRLF line ends or UTF-16 (Notepad, Excel) read as UTF-8 does.
        raw = read_toml(path)
    except LabFileError as exc:
        raise DesignError(f"design file {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise DesignError(f"design file {path} is not valid TOML: {exc}") from exc
    _refuse_non_finite(raw, path)

    g = _section(raw, "gloss", path, GlossSpec)
    d = _section(raw, "depth", path, DepthSpec)
    gloss = _build(
        GlossSpec, g, "gloss", path,
        rendered_levels=_levels(g.get("rendered_levels"), int(g.get("n_levels", 0)), "gloss"),
    )
    depth = _build(
        DepthSpec, d, "depth", path,
        rendered_levels=_levels(d.get("rendered_levels"), int(d.get("n_levels", 0)), "depth"),
    )
    array = _build(ArraySpec, _section(raw, "array", path), "array", path)
    ills = raw.get("illuminations")
    if not isinstance(ills, list):
        raise DesignError(f"{path}: missing [[illuminations]] entries")
    illuminations = tuple(
        _build(Illumination, {"scale": None, **il} if isinstance(il, dict) else il,
               "illuminations", path) for il in ills
    )
    tonemap = _build(ToneMapSpec, _section(raw, "tonemap", path), "tonemap", path)
    sessions = _build(SessionSpec, _section(raw, "sessions", path), "sessions", path)
    disp = _section(raw, "display", path, DisplaySpec)
    display = _build(
        DisplaySpec, disp, "display", path,
        resolution_px=tuple(int(v) for v in disp.get("resolution_px", ())),
    )
    slider = _build(SliderSpec, _section(raw, "slider", path), "slider", path)
    an = _section(raw, "analysis", path, AnalysisSpec)
    analysis = _build(
        AnalysisSpec, an, "analysis", path,
        depth_bins_cm={
            k: tuple(float(x) for x in v) for k, v in an.get("depth_bins_cm", {}).items()
        },
        gloss_bins_pct={
            k: tuple(float(x) for x in v) for k, v in an.get("gloss_bins_pct", {}).items()
        },
        models=_models(an.get("models", {}), path),
    )
    imagestats = _imagestats(_section(raw, "imagestats", path), path)
    if set(raw.get("render", {"variant": ""})) <= {"spp_by_light_field"}:
        raw = {k: v for k, v in raw.items() if k != "render"}  # only [render.spp_by_light_field]
    rd = _section(raw, "render", path, RenderSpec)
    render = _build(RenderSpec, rd, "render", path,
                    spp_by_gloss_level=tuple(rd.get("spp_by_gloss_level", ())),
                    spp_by_light_field=_spp_by_light_field(rd.get("spp_by_light_field", {}), path))
    gap = _build(GapSpec, {**asdict(GapSpec()), **raw.get("gap", {})}, "gap", path)
    cluster = _build(ClusterSpec, {**asdict(ClusterSpec()), **raw.get("cluster", {})},
                     "cluster", path)
    return StudyDesign(
        gloss=gloss,
        depth=depth,
        array=array,
        illuminations=illuminations,
        tonemap=tonemap,
        sessions=sessions,
        display=display,
        slider=slider,
        analysis=analysis,
        imagestats=imagestats,
        render=render,
        gap=gap,
        source=str(path),
        cluster=cluster,
    )
