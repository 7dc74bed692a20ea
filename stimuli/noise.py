"""Monte-Carlo noise as the observer sees it, and the samples per pixel each gloss level needs.

A render at n samples per pixel (spp) differs from its noise-free expectation by Monte-Carlo
noise. What matters is the noise *after the tone map* (the displayed error): the tone map
compresses the bright highlights where linear-luminance noise is largest. The displayed error of
a render is estimated without a reference image from k >= 2 renders of the same stimulus with
independent seeds: the per-pixel sample variance of the display value v = tonemap(L) is an
unbiased estimate of one render's variance, so

    e(n) = sqrt(mean over pixels of var_k(v)) / v_max                                        (1)

is the expected RMS displayed error of one n-spp render, as a fraction of the display range
(0-255). Independent samples make the variance fall as 1/n, e(n') = e(n) sqrt(n / n'), so the spp
that reaches a target e* is n' = ceil(n (e(n) / e*)^2), rounded up to a count the multijitter
sampler takes. Stratification makes smooth (matte) images converge faster than that and
highlights of sharp lobes slower, so :func:`plan_spp` does not trust one extrapolation: it fits
e(n) = c n^-b through its last two measurements, predicts the spp, renders again at it, and
keeps a count only once a measurement there meets the target.

Matte arrays (low gloss) are nearly noise-free at a few spp; the glossiest ones, with small,
bright highlights of the probe's light sources, need the most. :func:`plan_spp` measures each
gloss level on its hardest stimulus (deepest array, each probe) and returns the spp per level for
``design.render.spp_by_gloss_level``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stimuli.tonemap import ToneCurve, tonemap

__all__ = [
    "RenderAgreement",
    "SppPlan",
    "compare_renders",
    "displayed_error",
    "plan_spp",
    "spp_for_displayed_error",
    "spp_table",
]


def displayed_error(images, curve: ToneCurve) -> float:
    """Expected RMS displayed error of one render, from independent renders of one stimulus.

    Parameters
    ----------
    images : array_like, shape (k, h, w)
        k >= 2 renders (linear luminance) of the same stimulus with independent seeds.
    curve : ToneCurve
        The condition's tone curve (:func:`stimuli.tone_curve`).

    Returns
    -------
    float
        Eq. (1) of the module docstring: RMS over pixels of the per-pixel standard deviation of
        the display value, as a fraction of the display range (0.0075 = 0.75 %).

    Raises
    ------
    ValueError
        Fewer than 2 renders, or not a stack of 2-D images.
    """
    stack = np.asarray(images, dtype=float)
    if stack.ndim != 3 or stack.shape[0] < 2:
        raise ValueError(f"displayed_error needs k >= 2 renders of shape (k, h, w), got shape "
                         f"{stack.shape}; render the stimulus again with other seeds")
    shown = np.stack([tonemap(im, curve) for im in stack])
    return float(np.sqrt(np.mean(np.var(shown, axis=0, ddof=1))) / curve.max_value)


@dataclass(frozen=True)
class RenderAgreement:
    """How far two renderers' expected images differ, in Monte-Carlo standard errors.

    Attributes
    ----------
    chi2_per_df : float
        Mean of z^2 over the blocks (about 1 when the expectations agree).
    max_abs_z : float
        Largest |z| over the blocks.
    n_blocks : int
        Number of pixel blocks compared (the degrees of freedom).
    mean_rel_diff : float
        (mean(a) - mean(b)) / mean(b) over the whole image.
    mean_z : float
        That whole-image difference in standard errors.
    """

    chi2_per_df: float
    max_abs_z: float
    n_blocks: int
    mean_rel_diff: float
    mean_z: float


def compare_renders(a, b, *, block_px: int = 4) -> RenderAgreement:
    """Compare two stacks of independent renders of one scene block by block.

    Each image is averaged over ``block_px`` x ``block_px`` blocks (pixel noise is correlated
    through the reconstruction filter; blocks make the per-block estimates nearly independent).
    Per block, z = (mean_a - mean_b) / sqrt(var_a / k_a + var_b / k_b) with sample variances over
    the renders.

    Parameters
    ----------
    a, b : array_like, shape (k, h, w)
        k >= 2 renders each, independent seeds (a and b with different seeds too); h and w
        multiples of ``block_px``.
    block_px : int
        Block side, px.

    Returns
    -------
    RenderAgreement
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.ndim != 3 or b.ndim != 3 or a.shape[1:] != b.shape[1:] or min(len(a), len(b)) < 2:
        raise ValueError(f"compare_renders needs two stacks (k >= 2, h, w) of equal image size, "
                         f"got {a.shape} and {b.shape}")
    h, w = a.shape[1:]
    if h % block_px or w % block_px:
        raise ValueError(f"image size {h} x {w} is not a multiple of block_px={block_px}")

    def blocks(x):
        return x.reshape(len(x), h // block_px, block_px, w // block_px, block_px).mean(
            axis=(2, 4)).reshape(len(x), -1)

    ba, bb = blocks(a), blocks(b)
    se = np.sqrt(ba.var(axis=0, ddof=1) / len(ba) + bb.var(axis=0, ddof=1) / len(bb))
    se = np.maximum(se, 1e-12 * np.abs(bb.mean(axis=0)).max())
    z = (ba.mean(axis=0) - bb.mean(axis=0)) / se
    ma, mb = a.mean(axis=(1, 2)), b.mean(axis=(1, 2))
    se_mean = np.sqrt(ma.var(ddof=1) / len(ma) + mb.var(ddof=1) / len(mb))
    return RenderAgreement(chi2_per_df=float(np.mean(z**2)), max_abs_z=float(np.abs(z).max()),
                           n_blocks=int(z.size), mean_rel_diff=float(ma.mean() / mb.mean() - 1),
                           mean_z=float((ma.mean() - mb.mean()) / max(se_mean, 1e-300)))


def spp_for_displayed_error(error: float, spp: int, target: float) -> int:
    """Samples per pixel that bring a displayed error measured at ``spp`` down to ``target``.

    Parameters
    ----------
    error : float
        Displayed error measured at ``spp`` (fraction of the display range), >= 0.
    spp : int
        Samples per pixel of that measurement, >= 1.
    target : float
        Wanted displayed error (same unit), > 0.

    Returns
    -------
    int
        ``ceil(spp (error / target)^2)`` (the 1/n variance law), at least 1, rounded up to a
        count the multijitter sampler takes exactly (:func:`stimuli.multijitter_spp`).
    """
    from stimuli.render import multijitter_spp

    if not target > 0 or spp < 1 or not error >= 0:
        raise ValueError(f"need target > 0, spp >= 1 and error >= 0, got {target}, {spp}, {error}")
    need = max(1, int(np.ceil(spp * (error / target) ** 2 - 1e-9)))
    return multijitter_spp(need)


@dataclass(frozen=True)
class SppPlan:
    """Samples per pixel per (light field, gloss level) for a displayed-error target
    (:func:`plan_spp`).

    Attributes
    ----------
    gloss_levels : tuple of int
        Physical gloss level labels (1..n).
    spp : tuple of int
        Samples per pixel per level, the largest over the light fields (multijitter counts).
    error_at_pilot : tuple of float
        Displayed error per level at the pilot spp (max over the light fields, fraction of range).
    error_at_spp : tuple of float
        Displayed error measured at the chosen spp (of the light field that set it); each <=
        ``target`` unless ``max_spp`` stopped the search (then the level's spp is ``max_spp``).
    pilot_spp, repeats, size_px : int
        The measurement: renders of ``size_px`` px at ``pilot_spp``, ``repeats`` seeds each.
    target : float
        The displayed-error target (fraction of range).
    variant : str
        Mitsuba variant measured.
    light_fields : tuple of str
        Names of the light fields measured (one per probe).
    spp_by_light_field : tuple of tuple of int
        Per light field, its own spp per level (planned from its own noise).
    predicted_by_light_field : tuple of tuple of float
        Per light field and level, the displayed error the last fit predicted at the chosen spp.
    measured_by_light_field : tuple of tuple of float
        Per light field and level, the displayed error measured at the chosen spp.
    """

    gloss_levels: tuple[int, ...]
    spp: tuple[int, ...]
    error_at_pilot: tuple[float, ...]
    error_at_spp: tuple[float, ...]
    pilot_spp: int
    repeats: int
    size_px: int
    target: float
    variant: str
    light_fields: tuple[str, ...] = ()
    spp_by_light_field: tuple[tuple[int, ...], ...] = ()
    predicted_by_light_field: tuple[tuple[float, ...], ...] = ()
    measured_by_light_field: tuple[tuple[float, ...], ...] = ()

    def toml(self) -> str:
        """The ``[render]`` lines to paste into ``design.toml`` (the per-light-field table last,
        after the other keys of ``[render]``)."""
        own = "".join(f"\n{name} = [{', '.join(str(v) for v in spp)}]"
                      for name, spp in zip(self.light_fields, self.spp_by_light_field,
                                           strict=True))
        return (f"spp_by_gloss_level = [{', '.join(str(v) for v in self.spp)}]\n"
                f"spp_planned_at_px = {self.size_px}"
                + (f"\n\n[render.spp_by_light_field]{own}" if own else ""))

    def summary(self) -> dict:
        """The plan as JSON-ready numbers (errors in % of the display range)."""

        def pct(values):
            return [round(100 * e, 3) for e in values]

        def per_lf(rows):
            return dict(zip(self.light_fields, (pct(r) for r in rows), strict=True))

        return {"variant": self.variant, "size_px": self.size_px, "target_pct": round(100 * self.target, 6),
                "gloss_levels": self.gloss_levels, "spp": self.spp,
                "error_at_spp_pct": pct(self.error_at_spp), "pilot_spp": self.pilot_spp,
                "error_at_pilot_pct": pct(self.error_at_pilot),
                "spp_by_light_field": dict(zip(self.light_fields, self.spp_by_light_field,
                                               strict=True)),
                "predicted_error_pct": per_lf(self.predicted_by_light_field),
                "measured_error_pct": per_lf(self.measured_by_light_field)}

    def report(self) -> str:
        """One line per light field: spp, predicted and measured displayed error per level, %."""
        lines = []
        for name, spp, pred, meas in zip(self.light_fields, self.spp_by_light_field,
                                         self.predicted_by_light_field,
                                         self.measured_by_light_field, strict=True):
            worst = max(meas)
            lines.append(f"{name:26s} largest {100 * worst:.2f} % "
                         f"{'<=' if worst <= self.target else 'ABOVE'} target "
                         f"{100 * self.target:g} %; g: spp (predicted / measured %) "
                         + ", ".join(f"{g}: {n} ({100 * p:.2f}/{100 * m:.2f})" for g, n, p, m
                                     in zip(self.gloss_levels, spp, pred, meas, strict=True)))
        return "\n".join(lines)


def spp_table(design, light_fields) -> tuple[tuple[int, ...],
                                            tuple[tuple[str, tuple[int, ...]], ...]]:
    """The multijitter spp a render of ``light_fields`` takes: design-wide per gloss level, and
    per light field (its own counts, ``[render.spp_by_light_field]``, else the design-wide ones).

    Returns
    -------
    (tuple of int, tuple of (str, tuple of int))
        For :class:`stimuli.pipeline.RenderJob` (``spp_by_gloss_level``, ``spp_by_light_field``).
    """
    from stimuli.render import multijitter_spp

    levels = range(1, len(design.render.spp_by_gloss_level) + 1)
    by_level = tuple(multijitter_spp(design.render.spp(g)) for g in levels)
    return by_level, tuple((str(lf), tuple(multijitter_spp(design.spp(g, lf)) for g in levels))
                           for lf in dict.fromkeys(light_fields))


def _search_spp(measure, n0: int, e0: float, target: float, *, max_spp: int, max_rounds: int,
                spp_for) -> tuple[int, float, float]:
    """The smallest count found whose measured error meets ``target`` (module docstring):
    fit e(n) = c n^-b through the last two measurements, predict, render there, repeat.
    Returns (spp, error measured there, error the fit predicted there)."""
    best = (n0, e0, e0) if e0 <= target else None
    points = [(n0, e0)]
    predicted = {}
    n = spp_for_displayed_error(e0, n0, target)
    predicted[n] = e0 * np.sqrt(n0 / n)
    for _ in range(max_rounds):
        n = int(min(max(n, 1), max_spp))
        if any(n == q for q, _ in points):
            break
        e = measure(n)
        points.append((n, e))
        if e <= target and (best is None or n < best[0]):
            best = (n, e, predicted.get(n, e))
        (na, ea), (nb, eb) = sorted(points[-2:])
        slope = np.log(ea / eb) / np.log(nb / na) if ea > 0 and eb > 0 else 0.5
        slope = float(np.clip(slope, 0.25, 1.5))  # guard a noisy fit
        pred = spp_for(int(np.ceil(n * (e / target) ** (1.0 / slope))))
        if best is not None and pred >= best[0]:
            break
        predicted[pred] = e * (n / pred) ** slope
        n = pred
    if best is None:
        best = (max_spp, points[-1][1], predicted.get(max_spp, points[-1][1]))
    return best


def plan_spp(design, camera, *, size_px: int, pilot_spp: int = 16, repeats: int = 4,
             target: float | None = None, gloss_table=None, probes=None, max_spp: int = 1024,
             max_rounds: int = 5, gloss_levels=None, progress=None,
             light_fields=None) -> SppPlan:
    """Measure the displayed error of every physical gloss level and the spp each one needs,
    under each light field apart.

    For each probe, the deepest rendered array at every physical gloss level is rendered
    ``repeats`` times at ``pilot_spp`` (independent seeds). The tone curve is the probe's, from
    the mean images of the pilot renders of all levels (as the per-condition L_max of a real
    run). Then, per level and probe, the spp is searched as the module docstring says (fit,
    predict, render, until a measured error meets ``target``). Each light field keeps its own
    counts (``SppPlan.spp_by_light_field``); the design-wide count of a level is the largest
    over them. Needs :func:`stimuli.setup_mitsuba` (the variant measured is the active one).

    Parameters
    ----------
    design : StudyDesign
    camera : CameraGeometry
    size_px : int
        Image width = height of the renders, px.
    pilot_spp : int
        Samples per pixel of the measuring renders.
    repeats : int
        Renders per stimulus, >= 2.
    target : float, optional
        Displayed-error target, fraction of range; default ``design.render.displayed_error_pct``.
    gloss_table : DataFrame, optional
        Gloss % -> Ward parameters; default the shipped table.
    probes : sequence of LightProbe, optional
        Default: the design's illuminations' probes.
    max_spp : int
        Upper bound of the search.
    max_rounds : int
        Renders at predicted counts per level and probe before giving up (then the last count
        that met the target, or ``max_spp``).
    gloss_levels : sequence of int, optional
        Physical gloss level labels to plan (default all).
    progress : callable, optional
        Called with a message after each probe.
    light_fields : sequence of str, optional
        A name per probe (default: the illuminations' names, or the probes' file names).

    Returns
    -------
    SppPlan
    """
    import mitsuba as mi

    from stimuli.geometry import draw_array, stimulus_seed
    from stimuli.glosstable import default_gloss_table, ward_params_for_gloss
    from stimuli.illumination import load_light_probe
    from stimuli.render import StimulusRenderer
    from stimuli.tonemap import luminance_range, tone_curve

    if repeats < 2:
        raise ValueError(f"repeats={repeats}: the displayed error needs >= 2 renders per stimulus")
    target = design.render.displayed_error_pct / 100.0 if target is None else float(target)
    table = default_gloss_table() if gloss_table is None else gloss_table
    levels = tuple(design.gloss.labels if gloss_levels is None else (int(v) for v in gloss_levels))
    materials = list(zip(*ward_params_for_gloss(table, design.gloss.pct(np.asarray(levels))),
                         strict=True))
    depth = design.depth.rendered_levels[-1]
    geometry = draw_array(design, float(design.depth.cm(depth)), stimulus_seed(depth))
    if probes is None:
        from stimuli.sets import design_envmap

        probes = [load_light_probe(design_envmap(design, il.envmap), scale=il.scale)
                  for il in design.illuminations]
        light_fields = light_fields or [il.name for il in design.illuminations]
    names = tuple(light_fields or [p.name for p in probes])
    renderer = StimulusRenderer(camera, size_px=size_px, spp=pilot_spp)
    n0 = renderer.spp
    pilot, chosen, measured, predicted = (np.zeros((len(probes), len(levels))) for _ in range(4))
    seed = iter(range(1, 1 << 30))
    for p, probe in enumerate(probes):
        renderer.load(geometry, probe)
        stacks = [np.stack([renderer.render(*m, seed=next(seed)) for _ in range(repeats)])
                  for m in materials]
        curve = tone_curve(design.tonemap, luminance_range([s.mean(axis=0) for s in stacks]))
        for g, m in enumerate(materials):

            def measure(n, m=m, curve=curve):
                return displayed_error([renderer.render(*m, seed=next(seed), spp=n)
                                        for _ in range(repeats)], curve)

            pilot[p, g] = displayed_error(stacks[g], curve)
            chosen[p, g], measured[p, g], predicted[p, g] = _search_spp(
                measure, n0, pilot[p, g], target, max_spp=max_spp, max_rounds=max_rounds,
                spp_for=renderer.spp_for)
        if progress is not None:
            progress(f"{names[p]}: " + ", ".join(
                f"g{lv} {100 * e0:.2f} % at {n0} -> {int(n)} spp ({100 * e:.2f} %)"
                for lv, e0, n, e in zip(levels, pilot[p], chosen[p], measured[p], strict=True)))
    worst = chosen.argmax(axis=0)
    cols = np.arange(len(levels))

    def rows(a, kind):
        return tuple(tuple(kind(v) for v in r) for r in a)

    return SppPlan(gloss_levels=levels, spp=tuple(int(v) for v in chosen[worst, cols]),
                   error_at_pilot=tuple(float(e) for e in pilot.max(axis=0)),
                   error_at_spp=tuple(float(e) for e in measured[worst, cols]),
                   pilot_spp=n0, repeats=int(repeats), size_px=int(size_px), target=target,
                   variant=mi.variant(), light_fields=names,
                   spp_by_light_field=rows(chosen, int),
                   predicted_by_light_field=rows(predicted, float),
                   measured_by_light_field=rows(measured, float))
