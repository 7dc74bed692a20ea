"""What a diagnosis is given besides the data: the layer's functions
(:class:`LayerFunctions`: the loss, the floor, the ceiling, where and how large a remaining
gap is) and the statistical choices (:class:`DiagnosisSettings`), each one frozen record
checked on creation."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from numbers import Integral, Real

from analysis.gap.engine.errors import GapError

__all__ = ["DiagnosisSettings", "LayerFunctions"]


@dataclass(frozen=True)
class LayerFunctions:
    """A layer's functions, as the engine calls them (``fitted``: a list of
    ``(name, params)`` of chosen candidates; per-unit arrays in the held-out units' order).

    ==================== ============================== =====================================
    field                signature                      meaning
    ==================== ============================== =====================================
    loss                 ``loss(data, fitted)``         per-unit loss (NLL, nats), shape
                                                        (n_units,). With folds:
                                                        ``loss(train)`` returns that fold's
                                                        ``loss(data, fitted)``
    floor                ``floor(test)``                per-unit loss of a model right up to
                                                        noise; gap = loss - floor
    ceiling              ``ceiling(train, test)``       per-unit held-out loss of a flexible
                         or None                        data-driven model any systematic
                                                        structure would fit; the chosen
                                                        model's loss is tested against it
                                                        (paired, one-sided): a significant
                                                        excess of at least ``min_gain`` is a
                                                        gap the catalogue does not explain
    ceiling_given_chosen bool (default False)           call ``ceiling(train, test, fitted)``
                                                        with the fold's chosen candidates, for
                                                        a ceiling of what the chosen model
                                                        leaves (e.g. a smooth of its
                                                        residual): one of the plain
                                                        simulation's residual alone can fall
                                                        behind a chosen model that fits sharp
                                                        structure, and hide a gap beside it
    where                ``where(fits) -> str``         words for where a remaining gap lies
                         or None                        (e.g. "in the depth response, rising
                                                        with gloss"); ``fits``: per fold
                                                        ``(train, test, fitted,
                                                        ceiling_loss)``, ``ceiling_loss`` as
                                                        ``ceiling`` returned it
    size                 ``size(fits) -> float``        the remaining misfit in the data's own
                         or None                        units (``fits`` as for ``where``), e.g.
                                                        an RMS misfit in % of the data's RMS;
                                                        with it a significant remaining gap
                                                        below ``min_size`` is within the
                                                        tolerance (many units make an
                                                        approximate form's small leftovers
                                                        significant)
    size_upper           ``size_upper(fits)`` -> float  the one-sided upper 95 % bound of
                         or None                        ``size(fits)``, same units (e.g. a
                                                        bootstrap over the held-out units or
                                                        their clusters). The verdict is no gap
                                                        that matters only when it lies below
                                                        ``min_size`` (an equivalence test);
                                                        without it a diagnosis that finds no
                                                        gap is inconclusive
    unit_ids             ``unit_ids(test)`` or None     names of the held-out units (str),
                                                        recorded in ``Diagnosis.heldout``;
                                                        needed with several folds
    cluster_of           ``cluster_of(unit_id) -> str`` groups of dependent units (e.g. the
                         or None                        pixels of one block): the tests of the
                                                        ranking, the greedy steps and what
                                                        remains use a cluster-robust normal
                                                        approximation (deterministic, so with
                                                        a fixed split the verdict does not
                                                        depend on the seed; other CIs stay
                                                        bootstrap CIs). Needs ``unit_ids``
    absorbed             ``absorbed(fits)`` -> float    how far the simulation's own fit moved
                         or None                        to take up the chosen effects, in
                                                        ``size``'s units (the render layer: its
                                                        material with the named camera terms
                                                        modelled against the plain fit's). At
                                                        least ``min_size``: named effects are a
                                                        gap even where the plain simulation's
                                                        misfit is within the tolerance
                                                        (``tolerate_chosen``)
    ==================== ============================== =====================================

    Raises
    ------
    GapError
        If ``loss`` or ``floor`` is not callable, another function is neither callable nor
        None, ``ceiling_given_chosen`` is not a bool, or it is True without a ceiling.
    """

    loss: Callable
    floor: Callable
    ceiling: Callable | None = None
    ceiling_given_chosen: bool = False
    where: Callable | None = None
    size: Callable | None = None
    size_upper: Callable | None = None
    unit_ids: Callable | None = None
    cluster_of: Callable | None = None
    absorbed: Callable | None = None

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "ceiling_given_chosen":
                if not isinstance(value, bool):
                    raise GapError(f"LayerFunctions: ceiling_given_chosen must be True or False; "
                                   f"got {value!r}")
            elif not (callable(value) or (value is None and f.name not in ("loss", "floor"))):
                need = "a function" if f.name in ("loss", "floor") else "a function or None"
                raise GapError(f"LayerFunctions: {f.name} must be {need}; got {value!r}")
        if self.size_upper is not None and self.size is None:
            raise GapError("LayerFunctions: size_upper needs size (the misfit it bounds)")
        if self.ceiling_given_chosen and self.ceiling is None:
            raise GapError("LayerFunctions: ceiling_given_chosen=True needs a ceiling")


@dataclass(frozen=True)
class DiagnosisSettings:
    """The statistical choices of one diagnosis (loss units: nats per held-out unit).

    ======================== ============ ======= ===========================================================
    field                    type         default meaning
    ======================== ============ ======= ===========================================================
    alpha                    float        0.05    family-wise error rate, in (0, 1): of the ranking (Holm),
                                                  of each greedy step and of the test of what remains
    n_boot                   int          2000    bootstrap resamples of the held-out units, >= 1
    max_steps                int or None  None    most candidates the greedy combination adds (None: the
                                                  whole catalogue). At each step every candidate not yet
                                                  chosen is re-fitted and re-tested; a step must reduce the
                                                  held-out loss significantly (one-sided p times the number
                                                  of candidates left < alpha) by at least ``min_gain``
    min_share                float        0.0     in [0, 1]: an attribution needs the chosen candidates to
                                                  remove at least this share of the held-out gap; below it
                                                  the verdict is 'unexplained' (the partial steps are kept)
    min_gain                 float        0.0     a candidate, a greedy step or a remaining gap counts only
                                                  if it is at least this many nats per unit
    refit_rounds             int          2       after each greedy step, rounds of backfitting (every
                                                  chosen candidate re-fitted given the others; their
                                                  reported parameters are the re-fitted ones); 0: none
    min_size                 float        0.0     the practical tolerance, >= 0, for the layer's ``size``
                                                  (same units)
    size_unit                str          ""      words for ``size``'s unit (e.g. "% of the photos' RMS
                                                  luminance")
    size_source              str          ""      where the tolerance is set (e.g. "the design's [gap]
                                                  render_tolerance_pct"), for the summary
    tolerate_chosen          bool         False   hold the plain simulation's misfit to the tolerance
                                                  too: where nothing significant remains and its
                                                  ``size`` (``size_before``) has its upper 95 % bound
                                                  below ``min_size``, chosen effects are reported but
                                                  the verdict is no gap that matters (a change smaller
                                                  than the tolerance); where only its point lies below,
                                                  inconclusive
    size_without_noise_model bool         False   the layer's ``size`` and ``size_upper`` do not use
                                                  its noise model (the render layer's lagged residual
                                                  products): a mis-estimated floor then does not stop
                                                  their bound from excluding a gap
    floor_sd                 float        0.0     SD (>= 0) of the floor's mean from its own estimation
                                                  (e.g. a noise measured from n pairs of repeats): a gap is
                                                  called below the floor only beyond it and its CI
    ======================== ============ ======= ===========================================================

    Raises
    ------
    GapError
        If a field has the wrong type or lies outside its range (the message names it).
    """

    alpha: float = 0.05
    n_boot: int = 2000
    max_steps: int | None = None
    min_share: float = 0.0
    min_gain: float = 0.0
    refit_rounds: int = 2
    min_size: float = 0.0
    size_unit: str = ""
    size_source: str = ""
    floor_sd: float = 0.0
    tolerate_chosen: bool = False
    size_without_noise_model: bool = False

    def __post_init__(self):
        _check_real("alpha", self.alpha, 0.0, 1.0, "in (0, 1)", open_low=True, open_high=True)
        _check_int("n_boot", self.n_boot, 1)
        if self.max_steps is not None:
            _check_int("max_steps", self.max_steps, 0)
        _check_real("min_share", self.min_share, 0.0, 1.0, "in [0, 1]")
        _check_real("min_gain", self.min_gain, -math.inf, math.inf, "a finite number")
        _check_int("refit_rounds", self.refit_rounds, 0)
        _check_real("min_size", self.min_size, 0.0, math.inf, ">= 0 and finite")
        _check_real("floor_sd", self.floor_sd, 0.0, math.inf, ">= 0 and finite")
        if not isinstance(self.size_without_noise_model, bool):
            raise GapError(f"DiagnosisSettings: size_without_noise_model must be True or "
                           f"False; got {self.size_without_noise_model!r}")
        if not isinstance(self.tolerate_chosen, bool):
            raise GapError(f"DiagnosisSettings: tolerate_chosen must be True or False; got "
                           f"{self.tolerate_chosen!r}")
        for name in ("size_unit", "size_source"):
            if not isinstance(getattr(self, name), str):
                raise GapError(f"DiagnosisSettings: {name} must be a string; got "
                               f"{getattr(self, name)!r}")


def _check_real(name, value, low, high, words, *, open_low=False, open_high=False):
    """Raise GapError unless ``value`` is a finite real number within [low, high] (ends
    excluded where open)."""
    ok = (isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value)
          and (value > low if open_low else value >= low)
          and (value < high if open_high else value <= high))
    if not ok:
        raise GapError(f"DiagnosisSettings: {name} must be {words}; got {value!r}")


def _check_int(name, value, low):
    """Raise GapError unless ``value`` is an integer >= ``low``."""
    if not (isinstance(value, Integral) and not isinstance(value, bool) and value >= low):
        raise GapError(f"DiagnosisSettings: {name} must be an integer >= {low}; got {value!r}")
