"""Several layers at once: diagnose each, then say which layer carries the gap.

Each layer's gap is its held-out mean negative log-likelihood above its own noise floor, in
nats per unit (trial, reading, pixel): an estimate of the Kullback-Leibler divergence from the
data to the simulation per observation, so layers compare on one scale. Where the catalogue
removes more held-out loss than that, the removed loss is used (a floor-free lower bound). A layer carries a gap
when the lower end of its 95 % bootstrap CI lies above ``tolerance`` nats per unit; the
carrying layer is the one with the largest gap among those whose gap the catalogue attributes
(if none is attributed, the largest gap); the others are listed with their gaps. The pipeline runs display ->
render (photos of printed objects are not shown on the display) -> observer; an observer gap
next to a display or render gap may in part be inherited, which the verdict says.
"""

from __future__ import annotations

from pathlib import Path

from analysis.gap.engine import Diagnosis, GapError

__all__ = ["LAYER_ORDER", "parse_layer_paths", "which_layer"]

LAYER_ORDER = ("display", "render", "observer")
#: Gaps below this (nats per unit) are treated as none: the floor's own estimation error.
TOLERANCE_NATS = 0.02


def parse_layer_paths(text: str) -> dict[str, Path]:
    """``observer=PATH,display=PATH,render=PATH`` (any subset) -> {layer: Path}."""
    out = {}
    for part in filter(None, (t.strip() for t in text.split(","))):
        name, sep, path = part.partition("=")
        if not sep or name not in LAYER_ORDER:
            raise GapError(f"--layer all needs LAYER=PATH pairs separated by commas with LAYER "
                           f"in {LAYER_ORDER}; got {part!r}")
        if name in out:
            raise GapError(f"--layer all: {name} is named twice ({name}={out[name]} and {part}); "
                           f"give each layer once, e.g. {name}={path}")
        out[name] = Path(path)
    if not out:
        raise GapError("--layer all: no LAYER=PATH pairs given")
    return out


def _gap(d: Diagnosis) -> tuple[float, float, float]:
    """(gap, CI low, CI high): the gap above the floor, or, where larger, the held-out loss the
    catalogue removed, a lower bound on the distance to the truth that does not depend on the
    floor (for the observer layer the floor comes from the simulation's own data, and effects
    such as label rounding push the real loss below it)."""
    before = (d.gap_before, *(d.gap_before_ci or (float("nan"),) * 2))
    if d.steps and d.shrink_abs > before[0]:
        return (d.shrink_abs, *d.shrink_abs_ci)
    return before


def which_layer(diags: dict[str, Diagnosis], tolerance: float = TOLERANCE_NATS) -> dict:
    """The carrying layer and a plain-language sentence.

    Returns ``{"layer": name or None, "carrying": [names with a gap], "text": str,
    "gaps": {name: (gap, ci_low, ci_high)}}``.
    """
    from analysis.gap.engine.steps import NOT_A_GAP

    gaps = {n: _gap(d) for n, d in diags.items()}
    # A layer whose own verdict is not a gap (no gap that matters, or inconclusive) carries
    # none, whatever its distance to the floor.
    carrying = [n for n in LAYER_ORDER if n in gaps and gaps[n][1] > tolerance
                and diags[n].verdict not in NOT_A_GAP]
    if not carrying:
        undecided = [n for n in LAYER_ORDER if n in diags and diags[n].verdict == "inconclusive"]
        text = (f"No layer shows a gap (a held-out gap above {tolerance} nats per unit, lower "
                "95 % bound, that the layer's own verdict counts)")
        text += (f"; inconclusive at the {', '.join(undecided)} layer"
                 f"{'s' if len(undecided) > 1 else ''}: a gap there is not excluded (see "
                 "its detectable misfit and how much more data decides)." if undecided else
                 ": every layer given excludes a gap that matters.")
        return {"layer": None, "carrying": [], "text": text, "gaps": gaps}
    # An attributed gap outranks an unexplained one: a layer's unexplained gap is often the
    # estimation error of its own simulation (a calibration or fit from noisy data), which
    # nats per unit weigh very differently between layers (a photometer reading holds far
    # more information than a slider setting); it is reported beside the verdict.
    explained = [n for n in carrying if diags[n].steps and diags[n].verdict != "unexplained"]
    pool = explained or carrying
    top = max(pool, key=lambda n: gaps[n][0])
    d = diags[top]
    size = (f"{gaps[top][0]:.3f} nats per unit, 95 % CI {gaps[top][1]:.3f} to "
            f"{gaps[top][2]:.3f}")
    if explained:
        text = (f"The gap is carried by the {top} layer ({size}), explained by {d.verdict}.")
    else:
        text = (f"The gap is carried by the {top} layer ({size}), unexplained by its "
                "catalogue (no layer's gap is explained).")
    others = [n for n in carrying if n != top]
    if others:
        text += " Also above tolerance: " + ", ".join(
            f"{n} ({gaps[n][0]:.3f} nats per unit, "
            f"{'unexplained' if diags[n].verdict == 'unexplained' else diags[n].verdict})"
            for n in others) + "."
    if top == "observer" and any(n in carrying for n in ("display", "render")):
        text += (" The observer's gap may in part be inherited from the display or render "
                 "layer, which sits upstream.")
    return {"layer": top, "carrying": carrying, "text": text, "gaps": gaps}
