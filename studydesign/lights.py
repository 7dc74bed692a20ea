"""The light: ``[[illuminations]]`` (the experiment's conditions, one light probe each) and
``[imagestats]`` (the light fields of the image-statistics set)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from studydesign.errors import DesignError, require
from studydesign.tables import build, section

__all__ = ["LIGHT_KINDS", "SCALE_RULES", "Illumination", "ImageStatsSpec", "LightField",
           "read_illuminations", "read_imagestats"]


#: Kinds of light field (and of illumination condition).
LIGHT_KINDS = ("indoor", "outdoor")
#: How a light field's ``scale`` is chosen: the factor that makes a matte white facing the viewer
#: luminance 1 (``stimuli.diffuse_white_scale``; ``python -m stimuli probe-scale FILE``).
SCALE_RULES = ("diffuse_white",)


def check_scale(scale, where: str) -> None:
    require(scale is None or (isinstance(scale, (int, float)) and not isinstance(scale, bool)
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
        require(
            self.name.isidentifier() and self.name == self.name.lower(),
            f"illumination name {self.name!r} must be a lower-case identifier (e.g. 'indoor')",
        )
        require(
            self.kind in LIGHT_KINDS,
            f"illumination {self.name!r}: kind must be 'indoor' or 'outdoor', got {self.kind!r}",
        )
        check_scale(self.scale, f"illumination {self.name!r}")


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
        require(self.name.isidentifier() and self.name == self.name.lower(),
                f"light field name {self.name!r} must be a lower-case identifier "
                "(e.g. 'noon_grass')")
        require(self.kind in LIGHT_KINDS,
                f"light field {self.name!r}: kind must be 'indoor' or 'outdoor', got "
                f"{self.kind!r}")
        require(isinstance(self.envmap, str) and self.envmap != "",
                f"light field {self.name!r}: envmap must name a probe file")
        check_scale(self.scale, f"light field {self.name!r}")
        require(self.scale is not None, f"light field {self.name!r}: give its scale")


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
        require(self.n_arrays >= 1, "imagestats.n_arrays must be >= 1")
        require(len(self.light_fields) >= 1,
                "imagestats.light_fields must list at least one light field")
        names = [lf.name for lf in self.light_fields]
        require(len(set(names)) == len(names),
                f"imagestats.light_fields: names repeat: "
                f"{sorted({n for n in names if names.count(n) > 1})}")
        files = [Path(lf.envmap).name for lf in self.light_fields]
        require(len(set(files)) == len(files),
                f"imagestats.light_fields: files repeat "
                f"{sorted({f for f in files if files.count(f) > 1})}; each light field is its "
                "own capture (a rotated copy is the same scene seen from another side)")
        require(self.scale_rule in SCALE_RULES,
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


def read_illuminations(raw: dict, path: Path) -> tuple[Illumination, ...]:
    """The ``[[illuminations]]`` entries of a design file's ``raw`` tables."""
    ills = raw.get("illuminations")
    if not isinstance(ills, list):
        raise DesignError(f"{path}: missing [[illuminations]] entries")
    return tuple(
        build(Illumination, {"scale": None, **il} if isinstance(il, dict) else il,
              "illuminations", path) for il in ills
    )


def read_imagestats(raw: dict, path: Path) -> ImageStatsSpec:
    """The ``[imagestats]`` table of a design file's ``raw`` tables."""
    raw = section(raw, "imagestats", path)
    lfs = raw.get("light_fields")
    if "n_light_fields" in raw:
        raise DesignError(
            f"{path}: [imagestats] n_light_fields is gone: list the light fields instead, each "
            "its own capture (light_fields = [{ name = ..., envmap = ..., kind = ..., scale = "
            "... }, ...]; see the shipped design.toml), rather than rotations of one probe")
    if not isinstance(lfs, list) or not all(isinstance(t, dict) for t in lfs):
        raise DesignError(f"{path}: [imagestats] light_fields must be a list of tables "
                          "{ name, envmap, kind, scale } (see the shipped design.toml)")
    light_fields = tuple(build(LightField, t, "imagestats.light_fields", path) for t in lfs)
    return build(ImageStatsSpec, {"scale_rule": "diffuse_white", **raw}, "imagestats", path,
                 light_fields=light_fields)
