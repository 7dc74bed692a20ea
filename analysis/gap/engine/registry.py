"""The catalogue: one :class:`Candidate` object per effect a layer's simulation may lack, and
one :class:`OutOfCatalogue` object per effect the blind benchmark injects that no candidate
models, registered per layer (in registration order) and looked up by name."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field

from analysis.gap.engine.errors import GapError

__all__ = ["LAYER_NAMES", "Candidate", "OutOfCatalogue", "ParamDoc", "candidate", "catalogue", "effect", "out_of_catalogue",
           "register", "register_out_of_catalogue", "strengths"]

#: The layers, in the pipeline's order of diagnosis; each is a package ``analysis.gap.<layer>``
#: whose import registers its catalogue and which defines ``plan`` (:mod:`.layer`).
LAYER_NAMES = ("observer", "display", "render")
_LAYER_MODULES = LAYER_NAMES

@dataclass(frozen=True)
class ParamDoc:
    """How one fitted parameter of a candidate reads in reports (the table of a chosen effect's
    parameters, :func:`analysis.gap.params_table.param_rows`).

    ====== ======================== ===========================================================
    field  type                     meaning
    ====== ======================== ===========================================================
    name   str                      the parameter in words ("black offset")
    unit   str or ``unit(value)``   its unit or scale ("cd/m²"), or a function of the value
                                    where the unit follows a chosen form
    parts  tuple of str             names of a pair's parts ("diffuse scale", "specular
                                    scale"), each then a row of its own
    where  str                      ``str.format`` pattern for what a nested key is for
                                    ("{} response"); "{}": the key itself
    shown  ``shown(value)`` or None the value as the table shows it where the fit stores a
                                    code (a form in its sign: the magnitude); None: as stored
    ====== ======================== ===========================================================
    """

    name: str
    unit: str | Callable[[object], str] = ""
    parts: tuple[str, ...] = ()
    where: str = "{}"
    shown: Callable[[object], object] | None = None


@dataclass(frozen=True)
class Candidate:
    """One catalogue entry: everything about one effect, in one place.

    ================ ============================ ===============================================
    field            type                         meaning
    ================ ============================ ===============================================
    name             str                          the effect's name in verdicts and reports
    fit              ``fit(train, chosen)``       its parameters fitted on training data, given
                                                  the already chosen ``[(name, params), ...]``
    description      str                          one line for reports
    apply            callable or None             its term in the layer's mean or likelihood
                                                  (signature per layer, e.g. the observer's
                                                  ``apply(data, prediction, params)``)
    inject           callable or None             its injector for the blind benchmark (per
                                                  layer; never called by the diagnosis)
    default_strength float                        the benchmark's moderate strength
    units            str                          units of the strength
    truth            ``truth(strength, **ctx)``   the fitted parameters the injected strength
                                                  should give, ``[(name, params), ...]`` (the
                                                  benchmark's shrinkage score)
    params           dict of str -> ParamDoc      how each key ``fit`` returns reads in reports
                                                  (name, unit); key ``"*"``: every key is what
                                                  the value is for (e.g. per response)
    words            ``words(params) -> str``     the fitted effect in plain words for the
                     or None                      summary ("the display is 27 % brighter than
                                                  its calibration at every level")
    ================ ============================ ===============================================
    """

    name: str
    fit: Callable
    description: str = ""
    apply: Callable | None = None
    inject: Callable | None = None
    default_strength: float = float("nan")
    units: str = ""
    truth: Callable | None = None
    params: dict = field(default_factory=dict, compare=False, hash=False)
    words: Callable | None = field(default=None, compare=False, hash=False)


_REGISTRY: dict[str, dict[str, Candidate]] = {}


def register(layer: str, cand: Candidate) -> Candidate:
    """Add ``cand`` to ``layer``'s catalogue (in registration order); returns it.

    Raises
    ------
    GapError
        If ``cand`` is not a Candidate, or another candidate of that name is registered.
    """
    return _add(layer, cand, Candidate, "register", _REGISTRY, "a candidate",
                _OUT_REGISTRY, "an out-of-catalogue effect")


def _add(layer, obj, kind, caller, registry, what, others, other_what):
    """Put ``obj`` into ``registry[layer]`` unless its name is taken (by another object there,
    or by one in ``others[layer]``)."""
    if not isinstance(obj, kind):
        raise GapError(f"{caller}({layer!r}, ...): {obj!r} is not an engine.{kind.__name__}")
    if obj.name in others.get(layer, {}):
        raise GapError(f"layer {layer!r} has {other_what} {obj.name!r}; {what} needs another "
                       "name")
    table = registry.setdefault(layer, {})
    old = table.get(obj.name)
    if old is not None and old != obj:
        raise GapError(f"layer {layer!r} already has {what} {obj.name!r}; pick another name")
    table[obj.name] = obj
    return obj


def catalogue(layer: str) -> list[Candidate]:
    """The registered candidates of ``layer``, in registration order.

    Raises
    ------
    GapError
        If no candidate is registered for ``layer``.
    """
    if layer not in _REGISTRY and layer in _LAYER_MODULES:
        module = importlib.import_module(f"analysis.gap.{layer}")
        # A layer module that lists its candidates without registering them (``<LAYER>_
        # CANDIDATES``) gets them registered in that order.
        for cand in getattr(module, f"{layer.upper()}_CANDIDATES", ()) if not _REGISTRY.get(
                layer) else ():
            register(layer, cand)
    if not _REGISTRY.get(layer):
        raise GapError(f"no candidates registered for layer {layer!r}; known layers: "
                       f"{sorted(set(_REGISTRY) | set(_LAYER_MODULES))}")
    return list(_REGISTRY[layer].values())


def candidate(layer: str, name: str) -> Candidate:
    """The candidate ``name`` of ``layer``.

    Raises
    ------
    GapError
        ``unknown candidate ...; known: ...`` for a name not in the catalogue.
    """
    table = {c.name: c for c in catalogue(layer)}
    if name not in table:
        raise GapError(f"unknown candidate {name!r} for layer {layer!r}; known: "
                       f"{', '.join(table)}")
    return table[name]


@dataclass(frozen=True)
class OutOfCatalogue:
    """An effect outside a layer's catalogue: the blind benchmark injects it to check that the
    diagnosis calls its gap unexplained; no candidate models it and the diagnosis never sees
    it. Registered per layer with :func:`register_out_of_catalogue`, beside the candidates.

    ================ ============ ======================================================
    field            type         meaning
    ================ ============ ======================================================
    name             str          the effect's name in the benchmark's records
    inject           callable     its injector, with the layer's candidates' signature
    default_strength float        the benchmark's moderate strength
    units            str          units of the strength
    description      str          one line for reports
    ================ ============ ======================================================
    """

    name: str
    inject: Callable
    default_strength: float
    units: str = ""
    description: str = ""


_OUT_REGISTRY: dict[str, dict[str, OutOfCatalogue]] = {}


def register_out_of_catalogue(layer: str, eff: OutOfCatalogue) -> OutOfCatalogue:
    """Add ``eff`` to ``layer``'s out-of-catalogue effects (in registration order); returns it.

    Raises
    ------
    GapError
        If ``eff`` is not an OutOfCatalogue, or its name is taken by another out-of-catalogue
        effect or by a candidate of the layer.
    """
    return _add(layer, eff, OutOfCatalogue, "register_out_of_catalogue", _OUT_REGISTRY,
                "an out-of-catalogue effect", _REGISTRY, "a candidate")


def out_of_catalogue(layer: str) -> list[OutOfCatalogue]:
    """The registered out-of-catalogue effects of ``layer``, in registration order (the
    benchmark's injectors register theirs on import; empty before)."""
    return list(_OUT_REGISTRY.get(layer, {}).values())


def effect(layer: str, name: str) -> Candidate | OutOfCatalogue:
    """The candidate or out-of-catalogue effect ``name`` of ``layer``.

    Raises
    ------
    GapError
        ``unknown effect ...; known: ...`` (the candidates, then the out-of-catalogue
        effects) for a name in neither.
    """
    table = {c.name: c for c in catalogue(layer)} | _OUT_REGISTRY.get(layer, {})
    if name not in table:
        out = ", ".join(_OUT_REGISTRY.get(layer, {})) or "none registered"
        raise GapError(f"unknown effect {name!r} for layer {layer!r}; known: candidates "
                       f"{', '.join(c.name for c in catalogue(layer))}; out of catalogue "
                       f"{out}")
    return table[name]


def strengths(layer: str) -> dict[str, float]:
    """Moderate strength per effect of ``layer``: each candidate's and each out-of-catalogue
    effect's ``default_strength`` (the one place it is written)."""
    return ({c.name: float(c.default_strength) for c in catalogue(layer)}
            | {e.name: float(e.default_strength) for e in out_of_catalogue(layer)})

