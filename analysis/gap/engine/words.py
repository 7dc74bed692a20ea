"""The diagnosis in words: :func:`summarise` turns a :class:`Diagnosis` into one or two plain
sentences (the report's verdict), from the floor's status, what remains beyond the catalogue
and the chosen candidates' share."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from analysis.gap.engine.errors import GapError
from analysis.gap.engine.registry import candidate
from analysis.gap.engine.result import Diagnosis
from analysis.gap.engine.steps import INCONCLUSIVE, NO_GAP_THAT_MATTERS, NOT_A_GAP, judged_plain

__all__ = ["summarise", "with_summary"]


def _names(steps) -> str:
    return " + ".join(s["added"].replace("_", " ") for s in steps)


def summarise(d: Diagnosis) -> str:
    """The verdict in one or two plain sentences (no markup), then one per effect the data
    cannot identify; with single units that depart from the others (``d.departures``), what
    they change first (:func:`_departure_summary`)."""
    dep = d.departures or {}
    if dep.get("significant") or dep.get("verdict_without", d.verdict) != d.verdict:
        return _departure_summary(d, dep)
    text = _verdict_words(d)
    absorbed = _absorbed_words(d)
    if absorbed:
        # The gap first: the sentences after it speak of the held-out data alone.
        text = f"{absorbed} {text.replace(' is excluded.', ' is excluded on the held-out data.')}"
    misfit = _misfit_words(d)
    text += f" {misfit}" if misfit else ""
    if d.steps and d.verdict != "unexplained" and d.floor_status == "ok":
        for st in d.steps:
            said = _effect_words(d.layer, st)
            text += f" {st['added'].replace('_', ' ').capitalize()}: {said}." if said else ""
    for name, why in (d.not_identifiable or {}).items():
        text += f" {name.replace('_', ' ').capitalize()}: not identifiable from these readings ({why})."
    return text


def _departure_summary(d: Diagnosis, dep: dict) -> str:
    """The words of a verdict the departing units changed or added to: the verdict the rest of
    the data gave (:func:`summarise` without them), headed or followed by the departures."""
    before = summarise(replace(d, verdict=dep.get("verdict_without", d.verdict), departures={}))
    unit = d.misfit_unit or (d.remaining or {}).get("size_unit", "")
    size = (f"a misfit of about {dep.get('size', float('nan')):.2g} {unit} over all trials "
            f"(upper 95 % bound {dep.get('size_upper', float('nan')):.2g}), tolerance "
            f"{dep.get('tolerance', float('nan')):g}")
    rest = before.split(": ", 1)[1] if before.startswith(("No gap that matters: ",
                                                            "Inconclusive: ")) else before
    if dep.get("significant") and dep.get("verdict_without") in NOT_A_GAP:
        return (f"A gap, unexplained by the catalogue, {dep['where']} ({size}). Over the "
                f"population's settings by stimulus and time on task: {rest}")
    if dep.get("significant"):
        return f"{before} Besides, {dep['where']} ({size})."
    why = dep.get("reason") or (
        f"{dep['where']} ({size}); part of such a departure passes for the participant's own "
        "slopes, so a gap of the tolerance is not excluded" if dep.get("departing") else
        f"single participants' departures from the others leave {size}, so a gap of the "
        "tolerance is not excluded")
    return (f"Inconclusive: {rest.replace(' is excluded', ' is excluded for the population')}"
            f" But {why}.{_power_words(d)}")


def _effect_words(layer: str, step: dict) -> str:
    """The chosen effect in plain words (its candidate's ``words``), or ''."""
    try:
        cand = candidate(layer, step["added"])
    except GapError:
        return ""
    return cand.words(step["params"]) if cand.words is not None else ""


def _misfit_words(d: Diagnosis) -> str:
    """'Misfit of the predicted responses, RMS over held-out trials: 0.92 slider units (gloss
    9.1 %, depth 0.21 cm) before -> 0.04 after the chosen effects; held-out responses scatter
    1.3 slider units about a flexible model of the data (their noise).' from the
    ``misfit_*`` fields (a layer that measures them: the observer layer), or ''."""
    if not np.isfinite(d.misfit_before):
        return ""
    by = d.misfit_by_response or {}

    def each(key):
        parts = [f"{name} {v[key]:.2g} {v['unit']}" for name, v in by.items()
                 if np.isfinite(v.get(key, float("nan")))]
        return f" ({', '.join(parts)})" if len(parts) > 1 else ""
    after = ("the same after (nothing chosen)" if not d.steps else
             f"{d.misfit_after:.2g}{each('after')} after the chosen effects")
    return (f"Misfit of the predicted responses against a flexible model of the data, RMS over "
            f"held-out trials: {d.misfit_before:.2g} {d.misfit_unit}{each('before')} before -> "
            f"{after}; held-out responses scatter {d.misfit_ceiling:.2g} {d.misfit_unit} "
            "about that model (their noise).")


def _verdict_words(d: Diagnosis) -> str:
    """The verdict's own sentence(s)."""
    if d.floor_status == "misestimated":
        head = {INCONCLUSIVE: "Inconclusive: ",
                NO_GAP_THAT_MATTERS: "No gap that matters (the misfit's bound rests on no "
                                     "noise model): "}.get(d.verdict, "")
        rem = d.remaining or {}
        bound = (f" It leaves {_bound_words(rem)}." if "size_upper" in rem and "size" in rem
                 else "")
        if judged_plain(d):
            # Held to the tolerance by the plain simulation's own misfit (tolerate_chosen).
            plain = dict(rem, size=rem["size_before"], size_upper=d.misfit_upper)
            them = "it" if len(d.steps) == 1 else "them"
            bound = f" Without {them} the plain simulation leaves {_bound_words(plain)}."
        return f"{head}{_floor_words(d)}{bound}{_power_words(d)}"
    rem = d.remaining or {}
    further, within = _remaining_words(rem)
    if not d.steps:
        return _nothing_chosen_words(d, rem, further, within)
    if judged_plain(d):
        one = len(d.steps) == 1
        size = dict(rem, size=rem["size_before"], size_upper=d.misfit_upper)
        head = "No gap that matters" if d.verdict == NO_GAP_THAT_MATTERS else "Inconclusive"
        return (f"{head}: {_names(d.steps)} {'is' if one else 'are'} statistically "
                f"significant, but the plain simulation leaves {_bound_words(size)}; nothing "
                f"significant remains beyond {'it' if one else 'them'}."
                f"{_power_words(d)}")
    share = (f"{100 * d.explained_share:.0f} %" if np.isfinite(d.explained_share)
             else "all")
    if d.verdict == "unexplained":
        one = len(d.steps) == 1
        text = (f"{_names(d.steps)} {'reduces' if one else 'reduce'} the gap significantly but "
                f"{'explains' if one else 'explain'} only {share} of "
                f"it (an attribution needs {100 * d.min_share:.0f} %): unexplained by the "
                "catalogue")
    else:
        of = " a flexible model of the data removes" if rem else ""
        verb = "explains" if len(d.steps) == 1 else "explain"
        text = f"{_names(d.steps)} {verb} {share} of the gap{of}"
    if further:
        return f"{text}; {further}."
    if within:
        return f"{text}; {within}."
    if rem:
        return f"{text}; nothing significant remains beyond a flexible model of the data."
    return f"{text}."


def _absorbed_words(d: Diagnosis) -> str:
    """'A gap in the fitted model: ...' where the chosen effects are a gap because the
    simulation's own fit took them up by at least the tolerance (``remaining['absorbed']``),
    else ''."""
    rem = d.remaining or {}
    tol = rem.get("tolerance", np.inf)
    if not d.steps or d.verdict in NOT_A_GAP or rem.get("absorbed", 0.0) < tol:
        return ""
    unit = rem.get("size_unit", "")
    short = " %" if unit.startswith("%") else (f" {unit}" if unit else "")
    source = f" ({rem['size_source']})" if rem.get("size_source") else ""
    it = "it" if len(d.steps) == 1 else "them"
    return (f"A gap in the fitted model: the simulation's own fit took {_names(d.steps)} up -- "
            f"modelled, the fitted model moves by {rem['absorbed']:.2g} {unit} from the plain "
            f"fit's, at least the tolerance of {tol:g}{short}{source}, though the plain "
            f"simulation predicts the held-out data within "
            f"{rem.get('size_before', float('nan')):.2g}{short}; fit it again with {it} "
            "modelled.").replace("  ", " ")


def _floor_words(d: Diagnosis) -> str:
    """The sentence for a mis-estimated floor (a gap whose CI lies wholly below zero)."""
    ci = d.gap_before_ci or (float("nan"), float("nan"))
    which = ("before any extension" if d.gap_before_ci and d.gap_before_ci[1] < 0
             else "after the chosen extensions")
    text = (f"The noise floor is mis-estimated: the held-out loss lies below it {which} "
            f"(gap {d.gap_before:.3f} -> {d.gap_after:.3f} nats per unit; 95 % CI before "
            f"{ci[0]:.3f} to {ci[1]:.3f}). This is not a match between simulation and data; "
            "check the floor's inputs.")
    if d.steps:
        text += f" Attributed: {_names(d.steps)}."
    return text


def _remaining_words(rem: dict) -> tuple[str, str]:
    """(further, within): the clause for a gap that remains beyond the catalogue, and the one
    for a significant remainder within the tolerance; each '' where it does not apply."""
    further = within = ""
    nats = (f"{rem.get('gap', float('nan')):.3f} nats per unit above a flexible model of the "
            f"data, 95 % CI {rem.get('ci', (float('nan'),) * 2)[0]:.3f} to "
            f"{rem.get('ci', (float('nan'),) * 2)[1]:.3f}")
    if rem.get("significant"):
        where = f" {rem['where']}" if rem.get("where") else ""
        size = f"; {_size_words(rem, 'above')}" if "size" in rem else ""
        further = (f"a further gap remains, unexplained by the catalogue,{where} ({nats}{size})")
    elif rem.get("within_tolerance"):
        where = f", {rem['where']}" if rem.get("where") else ""
        within = (f"what remains is statistically significant ({nats}) but within the "
                  f"tolerance: {_size_words(rem, 'below')}{where}; not counted as a gap beyond "
                  "the catalogue")
    return further, within


def _nothing_chosen_words(d: Diagnosis, rem: dict, further: str, within: str) -> str:
    """The sentence when no candidate was chosen."""
    ci = d.gap_before_ci or (float("nan"), float("nan"))
    if further:
        return f"No catalogue effect explains the gap; {further}."
    if d.verdict == "unexplained":
        return (f"The gap ({d.gap_before:.3f} nats per unit, 95 % CI {ci[0]:.3f} to "
                f"{ci[1]:.3f}) is unexplained: no catalogue effect reduces it significantly.")
    head = ("No gap that matters" if d.verdict == NO_GAP_THAT_MATTERS else "Inconclusive")
    if within:
        said = f"no catalogue effect improves the simulation; {within}"
    elif rem:
        said = (f"no catalogue effect improves the simulation, and it predicts the held-out "
                f"data about as well as a flexible model of the data does ({-rem['gap']:+.3f} "
                f"nats per unit, 95 % CI {-rem['ci'][1]:+.3f} to {-rem['ci'][0]:+.3f}; "
                "positive: the simulation is better)")
    else:
        said = (f"the held-out gap ({d.gap_before:.3f} nats per unit, 95 % CI {ci[0]:.3f} to "
                f"{ci[1]:.3f}) is not significantly above the noise floor")
    if "size" in rem and "size_upper" in rem:
        said += f"; it leaves {_bound_words(rem)}"
    elif d.verdict == INCONCLUSIVE:
        said += "; this layer gives no bound on the misfit in its units, so no gap is excluded"
    return f"{head}: {said}.{_power_words(d)}"


def _bound_words(rem: dict) -> str:
    """'a misfit of about 0.4 % of luminance (upper 95 % bound 1.3 %), so a misfit of the
    tolerance of 1 % (the design's ...) is not excluded' from a size, its bound and the
    tolerance."""
    unit = rem.get("size_unit", "")
    short = " %" if unit.startswith("%") else (f" {unit}" if unit else "")
    source = f" ({rem['size_source']})" if rem.get("size_source") else ""
    upper = rem.get("size_upper", float("nan"))
    excluded = bool(np.isfinite(upper) and upper < rem["tolerance"])
    return (f"a misfit of about {rem['size']:.2g} {unit} (upper 95 % bound {upper:.2g}"
            f"{short}), so a misfit of the tolerance, {rem['tolerance']:g}{short}{source}, "
            f"is {'excluded' if excluded else 'not excluded'}").replace("  ", " ")


def _power_words(d: Diagnosis) -> str:
    """' These data would detect a misfit of 2.5 % ... with 80 % power; to decide: 4 repeats
    of each patch (4x the readings).' for an inconclusive verdict with ``detectable`` and
    ``to_decide`` (:mod:`.power`), else ''."""
    if d.verdict != INCONCLUSIVE or not d.detectable:
        return ""
    det, dec = d.detectable, d.to_decide
    pct = f"{100 * det['power']:.0f} %"
    if det.get("value") is None:
        seen = (f" These data would not detect even a misfit of {det['tried_up_to']:.2g} "
                f"{det['unit']} with {pct} power")
    else:
        seen = (f" These data would detect a misfit of {det['value']:.2g} {det['unit']} with "
                f"{pct} power")
    return (f"{seen} (simulated from the fitted models); to decide whether the misfit "
            f"measured ({dec['truth']:.2g}) matters, {dec['words']} would decide it in "
            f"{pct} of simulated data sets.").replace("  ", " ")


def _size_words(rem: dict, side: str) -> str:
    """'a misfit of about 0.24 % of the photos' RMS luminance, below the tolerance of 1 % (the
    design's [gap] render_tolerance_pct)' from a remaining gap's size fields."""
    unit = rem.get("size_unit", "")
    tol_unit = " %" if unit.startswith("%") else (f" {unit}" if unit else "")
    source = f" ({rem['size_source']})" if rem.get("size_source") else ""
    return (f"a misfit of about {rem['size']:.2g} {unit}, {side} the tolerance of "
            f"{rem['tolerance']:g}{tol_unit}{source}").replace("  ", " ")


def with_summary(d: Diagnosis) -> Diagnosis:
    """``d`` with its ``summary`` written by :func:`summarise`."""
    return replace(d, summary=summarise(d))
