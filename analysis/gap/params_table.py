"""The fitted parameters of a chosen effect as rows for people: readable names, units, values
to 3 significant digits, one row per number (a per-level, per-illumination or per-response
value is a row of its own, named by what it is for).

What each parameter means is the candidate's own word on it (``Candidate.params``, a
:class:`analysis.gap.engine.ParamDoc` per key, written beside its ``fit`` in each layer's
``candidates.py``); a parameter no candidate describes is named after its key (a unit suffix
such as ``_s`` or ``_px`` read as its unit), so a newly registered candidate still gets a
table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import Decimal
from numbers import Number

from analysis.gap.engine import GapError, ParamDoc, candidate

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


def _readable(key: str) -> ParamDoc:
    for suffix, unit in _SUFFIX_UNITS.items():
        if key.endswith(suffix):
            return ParamDoc(key[: -len(suffix)].replace("_", " "), unit)
    return ParamDoc(key.replace("_", " "))


def _rows(spec: ParamDoc, value, where: tuple[str, ...]) -> list[ParamRow]:
    """Rows of one parameter: a dict's keys and a sequence's positions say what each number
    is for (a sequence with named parts gives each part its own name)."""
    if isinstance(value, dict):
        out = []
        for k, v in value.items():
            k = _KEY_WORDS.get(str(k), k)
            out += _rows(spec, v, (*where, spec.where.format(k) if not where else str(k)))
        return out
    if isinstance(value, (list, tuple)):
        if spec.parts and len(spec.parts) == len(value):
            return [row for part, v in zip(spec.parts, value)
                    for row in _rows(ParamDoc(part, spec.unit, shown=spec.shown), v, where)]
        return [row for i, v in enumerate(value)
                for row in _rows(spec, v, (*where, f"[{i}]"))]
    unit = spec.unit(value) if callable(spec.unit) else spec.unit
    shown = spec.shown(value) if spec.shown is not None else value
    return [ParamRow(spec.name, " / ".join(where), format_sig(shown), unit)]


#: What a nested key means where it is not a name: ``*`` holds the one value that every level
#: shares (a directional-light set's photos are of one material: one pair of scales).
_KEY_WORDS = {"*": "every photo (one material)"}
#: Catalogues registered apart from a layer's own whose candidates its diagnoses may choose
#: (the render layer's broad lobe needs each photo's light: ``render_lights``).
_MORE_CATALOGUES = {"render": ("render_lights",)}


def _docs(layer: str, effect: str) -> dict:
    """The registered candidate's :class:`ParamDoc` per key (in ``layer``'s catalogue or one
    registered apart for it), or {} for an effect no registered candidate has (a report built
    by hand, an unknown layer)."""
    for name in (layer, *_MORE_CATALOGUES.get(layer, ())):
        try:
            return candidate(name, effect).params
        except GapError:
            continue
    return {}


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
    specs = _docs(layer, effect)
    out = []
    for key, value in params.items():
        key = str(key)
        if key in specs:
            rows = _rows(specs[key], value, ())
        elif "*" in specs:
            star = specs["*"]
            rows = _rows(ParamDoc(star.name, star.unit, star.parts), value,
                         (star.where.format(key),))
        else:
            rows = _rows(_readable(key), value, ())
        # A tuple's parts (diffuse, specular scale) each in one run of rows, per level within.
        names = list(dict.fromkeys(r.name for r in rows))
        out += sorted(rows, key=lambda r: names.index(r.name))
    return out
