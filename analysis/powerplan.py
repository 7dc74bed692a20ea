"""Planning a study: power curves, the smallest N for a target power and the smallest effect
a given N detects, from `analysis.power`'s simulated studies counted by `analysis.montecarlo`.

`run_power` answers for each model (the source study's "gloss" and "depth" by default) and
each of its tested terms; `write_power` writes ``power.json`` (every number, the settings and
the seed), ``power.csv`` (one row per point and term) and ``power.png``; `power_html` is the
analysis report's section.
"""

from __future__ import annotations

import itertools
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.montecarlo import Progress, rates_curve, size_search, smallest_size
from analysis.power import (
    ALPHA,
    Effect,
    ModelDraws,
    ObserverDraws,
    PowerError,
    check_terms,
    layout_frame,
    observer_params,
    scaled_fixef,
    study_unit_scale,
)
from studydesign import StudyDesign

__all__ = ["DEFAULT_TERMS", "PowerSettings", "power_html", "run_power", "write_power"]

#: The seed's tests: gloss, depth and their interaction on gloss settings, depth on depth ones.
DEFAULT_TERMS = {"gloss": ["gloss", "depth", "gloss:depth"], "depth": ["depth"]}
#: Multiples of the fitted effect tried for the smallest detectable effect.
DEFAULT_SCALES = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.25, 1.5, 2.0, 3.0)


@dataclass(frozen=True)
class PowerSettings:
    """What to simulate; every field is recorded in ``power.json``.

    Attributes
    ----------
    simulate : {"model", "observers"}
    models : tuple of str
        "gloss", "depth" (the source study's) or a design model's name.
    terms : dict of str to list of str
        Terms tested per model (default `DEFAULT_TERMS`, other models all their terms).
    participants : tuple of int
        Numbers of participants of the curve, increasing.
    sessions : tuple of int
        Sessions of the plan each participant does (default: all of the design's).
    repeats : tuple of int
        Times each participant does those sessions.
    n_sim : int
        Simulated studies per point.
    seed : int
        Root seed; model k of ``models`` uses ``seed + k``.
    alpha, target : float
        Test level; the power the smallest N and the smallest effect aim at.
    effects : tuple of Effect
    detect_n : int or None
        Number of participants at which the smallest detectable effect is searched (None: not).
    scales : tuple of float
        Multiples of the fitted effect tried in that search.
    """

    simulate: str = "model"
    models: tuple = ("gloss", "depth")
    terms: dict = field(default_factory=dict)
    participants: tuple = tuple(range(4, 25, 2))
    sessions: tuple = (None,)
    repeats: tuple = (1,)
    n_sim: int = 1000
    seed: int = 0
    alpha: float = ALPHA
    target: float = 0.8
    effects: tuple = ()
    detect_n: int | None = None
    scales: tuple = DEFAULT_SCALES
    chunk: int = 25

    def __post_init__(self):
        if self.simulate not in ("model", "observers"):
            raise PowerError(f"simulate {self.simulate!r}: use 'model' (a fitted mixed model) "
                             "or 'observers' (simulated observers, observers.toml)")
        p = list(self.participants)
        if not p or any(b <= a for a, b in itertools.pairwise(p)):
            raise PowerError(f"participants {p}: give increasing numbers, e.g. 4:24:2")
        if self.n_sim < 1:
            raise PowerError(f"n_sim {self.n_sim}: simulate at least 1 study per point")
        if not 0 < self.alpha < 1 or not 0 < self.target < 1:
            raise PowerError(f"alpha {self.alpha} / target {self.target}: each between 0 and 1")


def _formula(name: str, design: StudyDesign) -> str:
    from analysis.models import SOURCE_STUDY_MODELS, SOURCE_STUDY_RHS

    if "~" in name:  # a formula given as it is (--formula)
        return name
    if name in SOURCE_STUDY_MODELS:
        return f"{SOURCE_STUDY_MODELS[name][0]} ~ {SOURCE_STUDY_RHS}"
    for m in design.analysis.models:
        if m.name == name:
            return f"{m.response} ~ {m.formula}"
    known = list(SOURCE_STUDY_MODELS) + [m.name for m in design.analysis.models]
    raise PowerError(f"no model {name!r}; the models are {known} (the design's "
                     "[analysis.models] add to the source study's gloss and depth)")


class _Source:
    """Where one model's simulated studies come from: ``draws(layout, effects, terms)``."""

    def __init__(self, name, formula, settings, design, *, data=None, observers=None):
        self.name, self.formula, self.design = name, formula, design
        self.settings = settings
        if settings.simulate == "model":
            from analysis.lmm import fit

            self.fit = fit(formula, data)
            self.terms_all = list(self.fit.terms)
        else:
            from analysis.formula import build_model

            self.params = observers
            layout = layout_frame(design, 4)
            response = formula.split("~")[0].strip()
            spec = build_model(formula, layout.assign(**{response: 0.0}))
            self.terms_all = list(spec.fixed.terms)
            self.fit, self.theta0 = None, None
        self.terms = check_terms(settings.terms.get(name) or DEFAULT_TERMS.get(name)
                                 or self.terms_all, self.terms_all, f"model {name!r} ({formula})")
        self.effects = [e for e in settings.effects if e.term in self.terms_all]

    def draws(self, layout, effects, terms):
        if self.fit is not None:
            return ModelDraws(self.fit, layout, scaled_fixef(self.fit, effects, self.design),
                              terms, alpha=self.settings.alpha)
        response = self.formula.split("~")[0].strip()
        d = ObserverDraws(self.design, observer_params(self.params, response, effects),
                          layout, self.formula, terms, self.theta0, alpha=self.settings.alpha)
        self.theta0 = d.theta0
        return d

    def fitted_effect(self, term: str) -> dict:
        """The term's size in the source: the fitted coefficient(s) or observer parameter."""
        if self.fit is not None:
            idx = [i for i, a in enumerate(self.fit.assign) if a == self.terms_all.index(term)]
            names = list(self.fit.fixef)
            out = {"coefficients": {names[i]: self.fit.fixef[names[i]] for i in idx}}
            if len(idx) == 1:
                try:
                    out["study_units"] = (self.fit.fixef[names[idx[0]]]
                                          / study_unit_scale(term, self.design))
                except PowerError:
                    pass
            return out
        from analysis.power import OBSERVER_EFFECTS

        name = OBSERVER_EFFECTS[self.formula.split("~")[0].strip()].get(term)
        return {"observer_parameter": name, "value": self.params.get(name) if name else None}


class _Pick:
    """One column of a many-term draw function (for `smallest_size`'s one decision)."""

    def __init__(self, draws):
        self.draws = draws

    def __call__(self, rng, k):
        return self.draws(rng, k)[:, 0]


def _curve(src: _Source, settings, seed, client, quiet) -> list:
    points = list(itertools.product(settings.participants, settings.sessions, settings.repeats))
    layouts = {}

    def draws_at(point):
        n, s, r = point
        layouts[point] = layout_frame(src.design, n, sessions=s, repeats=r)
        return src.draws(layouts[point], src.effects, src.terms)

    progress = None if quiet else Progress(f"power {src.name} ({settings.simulate})")
    curve = rates_curve(draws_at, points, settings.n_sim, columns=len(src.terms), seed=seed,
                        chunk=settings.chunk, client=client, progress=progress)
    rows = []
    for (n, s, r), rates in curve:
        trials = int(len(layouts[(n, s, r)]) / n)
        for term, rate in zip(src.terms, rates):
            rows.append({"model": src.name, "simulate": settings.simulate, "term": term,
                         "participants": n, "sessions": s, "repeats": r,
                         "trials_per_participant": trials, **rate.to_dict(),
                         "alpha": settings.alpha, "seed": seed})
    return rows


def _smallest_n(rows: list, settings) -> list:
    from analysis.montecarlo import Rate

    out = []
    frame = pd.DataFrame(rows)
    for (model, term, s, r), g in frame.groupby(["model", "term", "sessions", "repeats"],
                                                sort=False, dropna=False):
        curve = [(int(row.participants), Rate(int(row.hits), int(row.n)))
                 for row in g.itertuples()]
        found = size_search(curve, settings.target)
        out.append({"model": model, "term": term, "sessions": None if pd.isna(s) else int(s),
                    "repeats": int(r), "target": settings.target, "participants": found.size,
                    "range": list(found.size_range)})
    return out


def _smallest_effect(src: _Source, settings, seed, client, quiet) -> list:
    n = settings.detect_n
    layout = layout_frame(src.design, n, sessions=settings.sessions[0],
                          repeats=settings.repeats[0])
    out = []
    for k, term in enumerate(src.terms):
        others = [e for e in src.effects if e.term != term]

        def draws_at(scale, term=term, others=others):
            return _Pick(src.draws(layout, [*others, Effect(term, scale=scale)], [term]))

        progress = None if quiet else Progress(f"smallest effect {src.name} {term} N={n}")
        found = smallest_size(draws_at, list(settings.scales), settings.n_sim,
                              seed=seed + 7919 * (k + 1), target=settings.target,
                              chunk=settings.chunk, client=client, progress=progress)
        fitted = src.fitted_effect(term)
        unit = fitted.get("study_units")
        out.append({"model": src.name, "term": term, "participants": n,
                    "target": settings.target, "scale": found.size,
                    "scale_range": list(found.size_range),
                    "study_units": None if found.size is None or unit is None
                    else found.size * unit,
                    "curve": [{"scale": s, **r.to_dict()} for s, r in found.curve]})
    return out


def run_power(settings: PowerSettings, design: StudyDesign, *, data: pd.DataFrame | None = None,
              observers: dict | None = None, client=None, quiet: bool = False) -> dict:
    """Simulate, refit and test; the curve, smallest N and smallest effect of every term.

    Parameters
    ----------
    settings : PowerSettings
    design : StudyDesign
    data : DataFrame, optional
        The model frame the models are fitted to (``simulate="model"``).
    observers : dict, optional
        The humanlike observers' table (``simulate="observers"``).
    client : distributed.Client, optional
        Spread the simulations over a Dask cluster.
    quiet : bool
        No progress lines.

    Returns
    -------
    dict
        ``settings``, ``sources`` (per model: formula, fitted effects), ``curve`` (rows of
        power.csv), ``smallest_n``, ``smallest_effect``, ``seconds``, ``simulations_per_s``.

    Raises
    ------
    PowerError, analysis.formula.LmmError
        A model, term or formula that is not there (named with the ones that are).
    """
    if (settings.simulate == "model") == (data is None):
        raise PowerError("simulate='model' needs data (a pilot's or the study's sessions); "
                         "simulate='observers' needs an observers table")
    sources = [_Source(name, _formula(name, design), settings, design, data=data,
                       observers=observers) for name in settings.models]
    bad = [e.term for e in settings.effects if not any(e.term in s.terms_all for s in sources)]
    if bad:
        raise PowerError(f"effect(s) on {bad}: not a term of any model simulated; the terms are "
                         + "; ".join(f"{s.name}: {s.terms_all}" for s in sources))
    t0 = time.perf_counter()
    rows, smallest_effect = [], []
    for k, src in enumerate(sources):
        rows += _curve(src, settings, settings.seed + k, client, quiet)
        if settings.detect_n is not None:
            smallest_effect += _smallest_effect(src, settings, settings.seed + k, client, quiet)
    seconds = time.perf_counter() - t0
    n_studies = (len({(r["model"], r["participants"], r["sessions"], r["repeats"])
                      for r in rows}) + sum(len(e["curve"]) for e in smallest_effect)
                 ) * settings.n_sim
    return {
        "simulate": settings.simulate,
        "settings": {**asdict(settings), "effects": [asdict(e) for e in settings.effects]},
        "sources": {s.name: {"formula": s.formula, "terms": s.terms,
                             "fitted": {t: s.fitted_effect(t) for t in s.terms},
                             "fit": None if s.fit is None else json.loads(s.fit.to_json())}
                    for s in sources},
        "curve": rows, "smallest_n": _smallest_n(rows, settings),
        "smallest_effect": smallest_effect, "seconds": seconds,
        "simulated_studies": n_studies,
        "simulations_per_s": n_studies / seconds if seconds > 0 else float("nan"),
    }


def plot_power(result: dict):
    """Power over participants, one panel per model, one line per term and trial count, with
    the Monte-Carlo 95 % interval as a band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frame = pd.DataFrame(result["curve"])
    models = list(dict.fromkeys(frame["model"]))
    fig, axes = plt.subplots(1, len(models), figsize=(5.2 * len(models), 4), squeeze=False)
    target = result["settings"]["target"]
    for ax, model in zip(axes[0], models):
        g = frame[frame["model"] == model]
        for (term, ses, rep), line in g.groupby(["term", "sessions", "repeats"], sort=False,
                                                dropna=False):
            trials = int(line["trials_per_participant"].iloc[0])
            how = "" if pd.isna(ses) and rep == 1 else (
                f" ({'all' if pd.isna(ses) else int(ses)} session(s) x {int(rep)})")
            label = f"{term}, {trials} trials/participant{how}"
            ax.plot(line["participants"], line["rate"], marker="o", ms=3, label=label)
            ax.fill_between(line["participants"], line["ci_low"], line["ci_high"], alpha=0.2)
        ax.axhline(target, ls="--", c="k", lw=0.8)
        ax.axhline(result["settings"]["alpha"], ls=":", c="grey", lw=0.8)
        ax.set(xlabel="participants", ylabel="power (Type II Wald χ², α = "
               f"{result['settings']['alpha']:g})", ylim=(-0.02, 1.02),
               title=f"{model} model, simulated from {result['simulate']}" + (
                   "\n" + ", ".join(Effect(**e).describe() for e in result["settings"]["effects"])
                   if result["settings"]["effects"] else ""))
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return fig


def write_power(result: dict, out_dir) -> dict:
    """``power.json``, ``power.csv``, ``power.png`` and ``summary.txt`` in ``out_dir`` (each
    written atomically); returns their paths."""
    from analysis.figures import save_figure
    from labfiles import atomic_write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / f for k, f in (("json", "power.json"), ("csv", "power.csv"),
                                    ("png", "power.png"), ("summary", "summary.txt"))}
    atomic_write_text(paths["csv"], pd.DataFrame(result["curve"]).to_csv(index=False))
    save_figure(plot_power(result), paths["png"])
    atomic_write_text(paths["summary"], summary_text(result))
    atomic_write_text(paths["json"], json.dumps(result, indent=1, default=_jsonable))
    return paths


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(f"{type(x)} is not JSON")


def summary_text(result: dict) -> str:
    """Sentences a plan can quote: the smallest N and the smallest effect per term."""
    s = result["settings"]
    lines = [(f"Power by simulation from {result['simulate']} ({s['n_sim']} simulated studies "
             f"per point, seed {s['seed']}, Type II Wald chi-square at alpha {s['alpha']:g}; "
             f"{result['simulated_studies']} studies in {result['seconds']:.1f} s).")]
    if s["effects"]:
        lines.append("Effects: " + ", ".join(Effect(**e).describe() for e in s["effects"]))
    for m in result["smallest_n"]:
        trials = "all sessions" if m["sessions"] is None else f"{m['sessions']} session(s)"
        where = f"{m['model']} model, {m['term']} ({trials} x {m['repeats']})"
        if m["participants"] is None:
            lines.append(f"{where}: {m['target']:.0%} power is not reached with up to "
                         f"{max(s['participants'])} participants.")
        elif m["participants"] == min(s["participants"]):
            lines.append(f"{where}: {m['target']:.0%} power already with {m['participants']} "
                         "participants, the fewest simulated.")
        else:
            lo, hi = m["range"]
            hi = hi if hi is not None else f"more than {max(s['participants'])}"
            lines.append(f"{where}: {m['target']:.0%} power with {m['participants']} "
                         f"participants (Monte-Carlo range {lo} to {hi}).")
    for e in result["smallest_effect"]:
        if e["scale"] is None:
            lines.append(f"{e['model']} model, {e['term']}: with {e['participants']} "
                         f"participants no effect up to {max(s['scales'])}x the fitted one "
                         f"reaches {e['target']:.0%} power.")
        else:
            unit = (f" ({e['study_units']:.4g} in study units)" if e["study_units"] is not None
                    else "")
            lo, hi = e["scale_range"]
            lines.append(f"{e['model']} model, {e['term']}: with {e['participants']} "
                         f"participants the smallest effect with {e['target']:.0%} power is "
                         f"{e['scale']:g}x the fitted one{unit} (range {lo} to {hi}).")
    return "\n".join(lines) + "\n"


def power_html(result: dict, *, png: str = "power.png") -> str:
    """One result in the analysis report (its figure is ``png`` beside the page)."""
    import html

    esc = html.escape
    rows = "".join(f"<li>{esc(line)}</li>" for line in summary_text(result).splitlines())
    return (f"<p>From <code>{esc(str(result.get('source', '')))}</code>:</p><ul>{rows}</ul>"
            f"<figure><img src='{esc(png)}' "
            "alt='power curves'><figcaption>Power over participants, Monte-Carlo 95 % "
            "intervals as bands; dashed: the target, dotted: alpha. Every point in "
            "power.csv.</figcaption></figure>")
