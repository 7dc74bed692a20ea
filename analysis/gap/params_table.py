"""The fitted parameters of a chosen effect as rows for people: readable names, units, values
to 3 significant digits, one row per number (a per-level, per-illumination or per-response
value is a row of its own, named by what it is for).

What each parameter means is read off each layer's candidates (``analysis.gap.observer``,
``display``, ``render``: their ``fit`` returns the parameters, their ``apply`` uses them); a
parameter of an effect not listed here is named after its key (a unit suffix such as ``_s`` or
``_px`` read as its unit), so a newly registered candidate still gets a table.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from decimal import Decimal
from numbers import Number

__all__ = ["ParamRow", "format_sig", "param_rows"]


@dataclass(frozen=True)
class ParamRow:
    """One number of a fitted effect, ready for a table.

    ========= ==== =======================================================================
    field     type meaning
    ========= ==== =======================================================================
    name      str  the parameter, in words ("black offset", "diffuse scale")
    where     str  what this value is for ("gloss_020", "lab_A", "gloss response"); ""
                   for a single value
    value     str  the value to 3 significant digits (or the text of a chosen form)
    unit      str  its unit or scale ("cd/m²", "fraction"); "" where none applies
    ========= ==== =======================================================================
    """

    name: str
    where: str
    value: str
    unit: str


@dataclass(frozen=True)
class _Param:
    """How one parameter key reads: its name, its unit (or a function of the value giving
    it), the names of a tuple's parts, and the words before a nested dict's keys."""

    name: str
    unit: str | Callable[[object], str] = ""
    parts: tuple[str, ...] = ()
    where: str = "{}"


def _tail_width_unit(width) -> str:
    """The long tail's wing form (render ``_wings``, ``_TAIL_WIDTHS``, ``_wider_lobe``)."""
    if isinstance(width, str):
        return "the wider lobe of this less glossy level"
    if width >= 1:
        return "px, SD of a Gaussian blur of the lobe"
    if width > 0:
        return "power the lobe is raised to (a wider Ward lobe)"
    return "-px, half width of a GTR1 haze kernel"


def _glare_unit(spread) -> str:
    """The veiling glare's spread (render ``_GLARE_SIGMAS``, ``_glare_blur``)."""
    if isinstance(spread, Number) and spread < 0:
        return "-x image width, core of a power-law kernel"
    return "x image width, SD of a Gaussian kernel"


_SCALE = _Param("scale", "× the gloss fit's component", parts=("diffuse scale",
                                                                   "specular scale"))

#: (layer, effect) -> {parameter key: how it reads}. ``"*"``: every key of the effect's
#: parameters is what the value is for (the observer's per-response effects).
PARAMS: dict[tuple[str, str], dict[str, _Param]] = {
    ("observer", "crosstalk"): {
        "c": _Param("crosstalk slope", "gloss slider units per depth slider unit")},
    ("observer", "central_tendency"): {
        "*": _Param("pull toward the slider's middle", "share of the distance to the middle",
                    where="{} response")},
    ("observer", "illumination_gain"): {
        "gain": _Param("gloss gain change", "gloss slider units per slider unit of true gloss")},
    ("observer", "label_rounding"): {
        "weight": _Param("responses snapped to a tick label", "fraction of responses")},
    ("observer", "lapses"): {"rate": _Param("lapse rate", "fraction of responses")},
    ("observer", "serial_dependence"): {
        "*": _Param("pull toward the previous response", "share of the distance to it",
                    where="{} response")},
    ("display", "black_offset"): {"c": _Param("black offset", "cd/m²")},
    ("display", "nonuniformity"): {
        "f": _Param("radial falloff: gain change at the corners", "fraction"),
        "g": _Param("horizontal gradient: gain change at the right edge", "fraction"),
        "h": _Param("vertical gradient: gain change at the top edge", "fraction")},
    ("display", "warmup_drift"): {
        "w": _Param("luminance deficit at switch-on", "fraction"),
        "tau_s": _Param("warm-up time constant", "s")},
    ("display", "quantisation"): {"bits": _Param("DAC resolution", "bits")},
    ("render", "fresnel"): {
        "kappa": _Param("cap on the view cosine (0: plain Schlick)", "cosine"),
        "c": _Param("Fresnel rise", "Schlick gain (1 − F0) / F0"),
        "scale": _SCALE},
    ("render", "long_tail"): {
        "c": _Param("haze share", "share of the lobe's energy in the haze"),
        "width": _Param("wing form", _tail_width_unit),
        "scale": _SCALE},
    ("render", "clearcoat"): {
        "entry": _Param("where the diffuse light entered the coat"),
        "c": _Param("diffuse light through the coat", "fraction"),
        "scale": _SCALE},
    ("render", "veiling_glare"): {
        "sigma_frac": _Param("glare spread", _glare_unit),
        "c": _Param("light in the glare", "fraction"),
        "scale": _SCALE},
    ("render", "vignetting"): {
        "c": _Param("darkening ∝ ρ²", "fraction (ρ: distance from the image centre, 1 at "
                    "the corners)"),
        "c2": _Param("darkening ∝ ρ⁴", "fraction (ρ as above)"),
        "scale": _SCALE},
    ("render", "misregistration"): {
        "shift_px": _Param("shift", "px", parts=("render shift down", "render shift right")),
        "scale": _SCALE},
}

_SUFFIX_UNITS = {"_px": "px", "_s": "s", "_cd_m2": "cd/m²", "_pct": "%", "_deg": "deg",
                 "_nats": "nats"}


def format_sig(value, digits: int = 3) -> str:
    """``value`` rounded to ``digits`` significant digits, trailing zeros dropped, without an
    exponent from 0.001 to below 1e6 (0.786, -0.173, 1.06, 600, 1230, 6); integers and text
    as they are, booleans as yes / no, non-finite numbers as ``nan`` / ``inf``.

    Raises
    ------
    ValueError
        If ``digits`` is below 1.
    """
    if digits < 1:
        raise ValueError(f"digits {digits}: use at least 1 significant digit")
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if not isinstance(value, Number):
        return "" if value is None else str(value)
    x = float(value)
    if not math.isfinite(x) or x == 0:
        return str(x) if x else "0"
    rounded = Decimal(f"{x:.{digits - 1}e}")
    if not -3 <= rounded.adjusted() < 6:
        return f"{x:.{digits}g}"
    text = format(rounded, "f")
    return text.rstrip("0").rstrip(".") if "." in text else text


def _readable(key: str) -> _Param:
    for suffix, unit in _SUFFIX_UNITS.items():
        if key.endswith(suffix):
            return _Param(key[: -len(suffix)].replace("_", " "), unit)
    return _Param(key.replace("_", " "))


def _rows(spec: _Param, value, where: tuple[str, ...]) -> list[ParamRow]:
    """Rows of one parameter: a dict's keys and a sequence's positions say what each number
    is for (a sequence with named parts gives each part its own name)."""
    if isinstance(value, dict):
        out = []
        for k, v in value.items():
            out += _rows(spec, v, (*where, spec.where.format(k) if not where else str(k)))
        return out
    if isinstance(value, (list, tuple)):
        if spec.parts and len(spec.parts) == len(value):
            return [row for part, v in zip(spec.parts, value)
                    for row in _rows(_Param(part, spec.unit), v, where)]
        return [row for i, v in enumerate(value)
                for row in _rows(spec, v, (*where, f"[{i}]"))]
    unit = spec.unit(value) if callable(spec.unit) else spec.unit
    return [ParamRow(spec.name, " / ".join(where), format_sig(value), unit)]


def param_rows(layer: str, effect: str, params: dict) -> list[ParamRow]:
    """The table of one chosen effect's fitted parameters, one row per number.

    Parameters
    ----------
    layer : str
        The diagnosis's layer (``"observer"``, ``"display"``, ``"render"``, or another).
    effect : str
        The candidate's name (``Diagnosis.steps[i]["added"]``).
    params : dict
        Its parameters as in ``Diagnosis.steps[i]["params"]`` (numbers, text, and dicts and
        lists of them, nested per level, illumination, response or participant).

    Returns
    -------
    list of ParamRow
        In the order of ``params``: nested values flattened, their keys joined in ``where``;
        values to 3 significant digits. An empty ``params`` gives no rows.

    Raises
    ------
    TypeError
        If ``params`` is not a dict.
    """
    if not isinstance(params, dict):
        raise TypeError(f"parameters of {effect!r}: {params!r} is not a dict of name -> value")
    specs = PARAMS.get((layer, effect), {})
    out = []
    for key, value in params.items():
        key = str(key)
        if key in specs:
            rows = _rows(specs[key], value, ())
        elif "*" in specs:
            star = specs["*"]
            rows = _rows(_Param(star.name, star.unit, star.parts), value,
                         (star.where.format(key),))
        else:
            rows = _rows(_readable(key), value, ())
        # A tuple's parts (diffuse, specular scale) each in one run of rows, per level within.
        names = list(dict.fromkeys(r.name for r in rows))
        out += sorted(rows, key=lambda r: names.index(r.name))
    return out
