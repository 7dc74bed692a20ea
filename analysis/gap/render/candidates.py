"""The render layer's catalogue: one registered Candidate per effect.

fresnel, long_tail, clearcoat, veiling_glare, vignetting and misregistration, registered in
the order their terms apply (``model._basis``). Each has its term (``_apply_*``, with the forms
of ``model``; the package's docstring tabulates them), its fit (one bounded amplitude and a
form from a grid, ``_fit_amp``, or its own: ``_fit_long_tail``, ``_fit_vignetting``,
``_fit_misregistration``), its injector (``_inject_*``: the effect built into a Mitsuba material
or the camera), its default strength and the parameters a right fit recovers.
"""

from __future__ import annotations

import copy
import weakref
from numbers import Number

import numpy as np
from scipy import optimize

from analysis.gap.engine import Candidate, ParamDoc, catalogue, register
from analysis.gap.render.data import _FRESNEL_CAPS, BROAD_ALPHAS, RenderData
from analysis.gap.render.model import (
    _basis,
    _glare_blur,
    _scaled_residuals,
    _scaled_sse,
    _shift_scene,
    _weights,
    _wider_lobe,
    _wings,
)

#: The render catalogue's candidates whose parameters one material shares across directional
#: lights, in the order their terms apply; the broad lobe ("render_lights") after them.
LIGHT_CANDIDATES = ("fresnel", "clearcoat", "veiling_glare", "vignetting")
#: Glare spreads (x image width): a Gaussian's SD (> 0) or a power-law kernel's core (< 0).
_GLARE_SIGMAS = (0.125, 0.25, 0.5, -0.015, -0.03, -0.06)
#: Where the diffuse light entered the coat (see _coat_t, _coat_lights and _coat_mirror): from
#: a uniform surround, along the view, from the lights seen in the shading and the highlight,
#: or from the room seen in the specular render.
_COAT_ENTRY = ("surround", "view", "lights", "mirror")
#: Wing forms (see _wings): Gaussian blur px (>= 1), lobe power (in (0, 1)) or a GTR1 kernel
#: of that many px half width (< 0); besides these, each less glossy level's name (_wider_lobe).
_TAIL_WIDTHS = (1.0, 2.0, 4.0, 8.0, 0.5, 0.25, 0.12, -2.0, -4.0, -8.0, -16.0)


# --- each effect's term (the forms in model) ------------------------------------------------

def _apply_fresnel(lv, im, q):
    return im | {"S": im["S"] * (1 + q["c"] * lv["fres5"][q["kappa"]])}


def _apply_long_tail(lv, im, q):
    c, width = q["c"].get(lv["name"], 0.0), q["width"].get(lv["name"], 1.0)
    if isinstance(width, str):
        wide = _wider_lobe(lv, im["S"], width)
    else:
        wide = _wings(im["S"], width, lv["cover"])
    return im | {"S": im["S"] + c * (wide - im["S"])}


def _apply_clearcoat(lv, im, q):
    out = im | {"D": im["D"] * (1 + q["c"] * (lv["coat"][q["entry"]] - 1))}
    if q.get("k"):  # the coated surface's second lobe (directional lights, _fit_coat_lights)
        out["S"] = im["S"] + q["k"] * lv["lobes"][q["alpha2"]]
    return out


def _apply_glare(lv, im, q):
    # The image-space effects are linear: apply them to each component.
    return {k: v + q["c"] * _glare_blur(v, q["sigma_frac"] * lv["width"])
            for k, v in im.items()}


def _apply_vignetting(lv, im, q):
    rho2 = lv["rho2"]
    return {k: v * (1 - q["c"] * rho2 - q.get("c2", 0.0) * rho2**2) for k, v in im.items()}


def _apply_misregistration(lv, im, q):
    dy, dx = q["shift_px"].get(lv["name"], (0.0, 0.0))
    d, s, b = _shift_scene(lv, [im["D"], im["S"], im["B"]], dy, dx)
    return {"D": d, "S": s, "B": b}


# --- the fits of their own ------------------------------------------------------------------

def _best_on_grid(sse, lo: float, hi: float, grid) -> tuple[float, float]:
    """(c, g) minimising ``sse(c, g)``: c bounded in [lo, hi] for each g of the grid."""
    best = None
    for g in grid:
        res = optimize.minimize_scalar(lambda c, g=g: sse(float(c), g), bounds=(lo, hi),
                                       method="bounded", options={"xatol": 1e-4 * (hi - lo)})
        if best is None or res.fun < best[0]:
            best = (res.fun, float(res.x), g)
    return best[1], best[2]


def _fit_amp(name, lo, hi, key=None, grid=(None,)):
    """One amplitude (bounded) and optionally a form parameter from a grid, with the scales
    re-fitted. Where the extended render is affine in the amplitude (:func:`_affine_sse`)
    each trial amplitude costs a few dot products instead of a render's extension."""
    def fit(train, chosen):
        base = [f for f in chosen if f[0] != name]

        def params_of(c, g):
            if key is None:
                return {"c": c}
            return {key: g if isinstance(g, str) else float(g), "c": c}
        fast = {}

        def sse(c, g):
            if g not in fast:
                fast[g] = _affine_sse(train, base, name, lambda c: params_of(c, g), lo, hi)
            if fast[g] is not None:
                return fast[g](c)
            return _scaled_sse(train, base + [(name, params_of(c, g))])[0]
        c, g = _best_on_grid(sse, lo, hi, grid)
        params = params_of(c, g)
        params["scale"] = _scaled_sse(train, base + [(name, params)])[1]
        return params
    return fit


def _affine_sse(train, base, name, params_at, lo: float, hi: float):
    """The weighted SSE of :func:`_scaled_sse` as a function of the amplitude c alone, or None.

    The fresnel, clearcoat, glare and broad-lobe terms are affine in c (R + c X), and so is
    every later term of the render (linear blurs, shifts, vignetting) except a long tail's
    power form: then each level's weighted columns are p + c q, and the SSE after the scales'
    least squares is y'y - b' M^-1 b with every product a quadratic in c from one 6 x 6 Gram
    matrix of (y, D, S) at c = lo and their slopes. The extension is rendered at c = lo, hi
    and a third amplitude; None (the caller renders each c) where the third departs from the
    line by more than 1e-9 of the images' scale."""
    mid, grams = lo + 0.37 * (hi - lo), []
    for lv in train.levels:
        at = [_basis(lv, base + [(name, params_at(c))]) for c in (lo, hi, mid)]
        for x0, x1, xm in zip(*at):
            if np.max(np.abs(xm - x0 - 0.37 * (x1 - x0)), initial=0.0) > 1e-9 * (
                    np.max(np.abs(x0), initial=0.0) + np.max(np.abs(x1), initial=0.0) + 1e-300):
                return None
        m, w, pw = _weights(lv)
        (d0, s0, b0), (d1, s1, b1) = ((x.ravel()[m] * w for x in xs) for xs in at[:2])
        vecs = np.stack([pw - b0, (b0 - b1) / (hi - lo), d0, (d1 - d0) / (hi - lo), s0,
                         (s1 - s0) / (hi - lo)])
        grams.append(vecs @ vecs.T)
    if all(lv.get("shared") for lv in train.levels):
        grams = [sum(grams)]

    def sse(c):
        u = np.array([1.0, c - lo])
        total = 0.0
        for g in grams:
            blocks = u @ g.reshape(3, 2, 3, 2).transpose(0, 2, 1, 3) @ u  # (3, 3): y, D, S
            mat, rhs = blocks[1:, 1:], blocks[1:, 0]
            coef = np.linalg.lstsq(mat, rhs, rcond=None)[0]
            total += float(blocks[0, 0] - rhs @ coef)
        return total
    return sse


_fit_coat_panorama = _fit_amp("clearcoat", 0.0, 1.0, "entry", _COAT_ENTRY)


def _fit_clearcoat(train, chosen):
    """Under directional lights :func:`_fit_coat_lights`; in a panorama ``_fit_amp``'s."""
    if train.levels and all("light" in lv for lv in train.levels):
        return _fit_coat_lights(train, chosen)
    return _fit_coat_panorama(train, chosen)


def _fit_coat_lights(train, chosen):
    """A clear coat over the fitted material under directional lights: all diffuse light leaves
    through the coat (c = 1, entry "lights": T(n.l) T(view) of IOR 1.5), and the specular shows
    two lobes, the coat's and the base's beneath; the gloss fit's one Ward lobe took one (the
    brighter), the other is a Ward lobe of width ``alpha2`` (:data:`BROAD_ALPHAS`) and albedo
    ``k`` x the fitted diffuse albedo.

    A coat is a layer the base's light passes through, not a share of it: its loss towards
    grazing light and view is fixed by its index (a free share would hold broad_lobe as its
    case c = 0 and tie with it on photos without a coat). The lobes' transmission is left out
    (within 30 deg of the normal T(n.l) T(view) stays within 0.4 % of normal incidence).
    Later terms are linear in the images, so the prediction is a D' + b S + w L: a, b, w >= 0
    by NNLS over all lights per width, the least SSE kept, k = w / b; scales re-fitted."""
    base = [f for f in chosen if f[0] != "clearcoat"]
    best = None
    for alpha2 in BROAD_ALPHAS:
        coat = {"entry": "lights", "c": 1.0, "alpha2": alpha2}
        cols, ys = [], []
        for lv in train.levels:
            m, w, pw = _weights(lv)
            d1, s0, b0 = (x.ravel()[m] * w for x in _basis(lv, base + [("clearcoat", coat)]))
            s1 = _basis(lv, base + [("clearcoat", coat | {"k": 1.0})])[1].ravel()[m] * w
            cols.append(np.stack([d1, s0, s1 - s0], axis=1))
            ys.append(pw - b0)
        x, rnorm = optimize.nnls(np.concatenate(cols), np.concatenate(ys))
        if best is None or rnorm < best[0]:
            best = (rnorm, coat | {"k": float(x[2] / x[1]) if x[1] > 0 else 0.0})
    params = best[1]
    params["scale"] = _scaled_sse(train, base + [("clearcoat", params)])[1]
    return params


def _fit_misregistration(train, chosen):
    base = [f for f in chosen if f[0] != "misregistration"]
    shifts = {}
    for lv in train.levels:
        m = lv["use"]
        dy = dx = 0.0
        one = RenderData([lv])
        for _ in range(4):
            p = [("misregistration", {"shift_px": {lv["name"]: (dy, dx)}})]
            _, scale = _scaled_sse(one, base + p)
            a, b = scale[lv["name"]]
            D, S, B = _basis(lv, base + p)
            pred = B + a * D + b * S
            gy, gx = np.gradient(pred)
            w = 1 / lv["sd"][m]
            step, *_ = np.linalg.lstsq(np.c_[-gy[m], -gx[m]] * w[:, None],
                                       (lv["P"] - pred)[m] * w, rcond=None)
            dy, dx = float(np.clip(dy + step[0], -3, 3)), float(np.clip(dx + step[1], -3, 3))
        shifts[lv["name"]] = (dy, dx)
    params = {"shift_px": shifts}
    params["scale"] = _scaled_sse(train, base + [("misregistration", params)])[1]
    return params


def _fit_vignetting(train, chosen):
    """The falloff 1 - c rho^2 - c2 rho^4 with the scales re-fitted.

    Two terms of the even polynomial that real lenses' vignetting calibrations use (lensfun's
    'pa' model has three): fitted by least squares to the falloff alone of the 12,272 distinct
    lens profiles of the lensfun database (0.3.3), over a photo that spans the whole frame, one
    term leaves a median 0.56 % (95th percentile 3.3 %) of the luminance RMS, two terms 0.15 %
    (1.2 %); over half the frame's radius one term suffices (0.05 %, 0.34 %). On photos of 300
    of those lenses, this fit: tests/analysis/gap/test_render_vignetting_lenses.py.
    Fitted by nonlinear least squares (trust region) on the weighted residuals with the scales
    solved at each point (variable projection): rho^2 and rho^4 are strongly collinear over a
    photo and coupled to the scales, so alternating the two converges too slowly. The
    parameters searched are c and the corners' darkening c + c2, the latter bounded to
    [-2, 0.95] (c to [-2, 2]): the corners keep at least 5 % of the centre's light, and the
    falloff stays above 4 % everywhere between (its least value inside, where c2 < 0, is
    1 - c^2 / (4 (c - d)) with d = c + c2), so no fit darkens a photo below zero."""
    base = [f for f in chosen if f[0] != "vignetting"]

    def params(x):
        return {"c": float(x[0]), "c2": float(x[1] - x[0])}

    def residuals(x):
        return _scaled_residuals(train, base + [("vignetting", params(x))])
    fit = optimize.least_squares(residuals, np.zeros(2), bounds=([-2.0, -2.0], [2.0, 0.95]),
                                 x_scale=0.1, diff_step=1e-4)
    q = params(fit.x)
    q["scale"] = _scaled_sse(train, base + [("vignetting", q)])[1]
    return q


def _fit_long_tail(train, chosen):
    """Amplitude and wing form per gloss level: the tails' width follows the lobe's, which
    differs between the levels (each level's loss depends on its own parameters only)."""
    base = [f for f in chosen if f[0] != "long_tail"]
    cs, widths = {}, {}
    for lv in train.levels:
        name, one, fast = lv["name"], RenderData([lv]), {}

        def sse(c, g, name=name, one=one, fast=fast):
            def params(c):
                return {"c": {name: c}, "width": {name: g}}
            if g not in fast:  # the tail S + c (W - S) is affine in c (see _affine_sse)
                fast[g] = _affine_sse(one, base, "long_tail", params, 0.0, 1.0)
            if fast[g] is not None:
                return fast[g](c)
            return _scaled_sse(one, base + [("long_tail", params(c))])[0]
        c, g = _best_on_grid(sse, 0.0, 1.0, _TAIL_WIDTHS + tuple(lv.get("wider", {})))
        cs[name], widths[name] = c, g if isinstance(g, str) else float(g)
    params = {"c": cs, "width": widths}
    params["scale"] = _scaled_sse(train, base + [("long_tail", params)])[1]
    return params


def _remembered_fit(fit):
    """``fit(train, chosen)``, computed once per training data and chosen list: the engine
    fits every candidate alone when it scores them and again, given nothing chosen, at the
    greedy combination's first step, and backfitting re-fits the candidate just added given
    the same others; each fit is deterministic, so the second is the first's copy. Held per
    training view (a weak reference: dropped with it); ``chosen`` compared by its repr (floats
    to the last bit)."""
    memo: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    def remembered(train, chosen):
        table = memo.setdefault(train, {})
        key = repr(chosen)
        if key not in table:
            table[key] = fit(train, chosen)
        return copy.deepcopy(table[key])
    return remembered


# --- the catalogue: each effect's fit, term, injector, default strength and truth -----------
# An injector makes the photo's noiseless luminance of one gloss level with the effect:
# ``inject(studio, level, strength, rng)``. ``studio`` is the benchmark's renderer (Mitsuba
# scenes of the gloss fit's sphere, analysis.gapbench.inject): ``level(k)`` -> (rho_d, rho_s,
# alpha), ``base(k)`` -> the plain diffuse and specular renders, ``background(shift)``,
# ``render(material, seed, shift)``, ``ward(...)``, ``rgb(v)``, ``sphere_r()``,
# ``mean_ratio(a, b, where)``, ``plain(k)`` (background + diffuse + specular). The effect is
# built into the material or the camera with Mitsuba's own plugins, never with the forms
# of the terms above (model.py).

def _inject_fresnel(studio, level, s, rng):
    """The Ward lobe with Schlick's term on the half vector, F0 = 1 / (1 + s)."""
    _, rho_s, alpha = studio.level(level)
    d0, _ = studio.base(level)
    # The same sampler seed as the plain lobe: the Fresnel term does not change sampling.
    return studio.background() + d0 + studio.render(
        studio.ward(0.0, rho_s, alpha, fresnel_f0=1 / (1 + s)), 21 + level)


def _inject_clearcoat(studio, level, s, rng):
    """A share ``s`` of the diffuse light through a clear coat (``plastic``, IOR 1.5)."""
    rho_d, _, _ = studio.level(level)
    d0, s0 = studio.base(level)
    coat = studio.render({"type": "plastic", "diffuse_reflectance": studio.rgb(rho_d),
                          "specular_reflectance": studio.rgb(0.0), "int_ior": 1.5,
                          "nonlinear": False}, 31 + level)
    # The coat's light loss at normal view is absorbed by the fit's rho_d: match the centre.
    coat *= studio.mean_ratio(d0, coat, studio.sphere_r() < 0.3)
    return studio.background() + ((1 - s) * d0 + s * coat) + s0


def _inject_long_tail(studio, level, s, rng):
    """A share ``s`` of the lobe's energy in a GGX haze of 2.5 times the Ward alpha."""
    _, rho_s, alpha = studio.level(level)
    d0, s0 = studio.base(level)
    ggx = studio.render({"type": "roughconductor", "distribution": "ggx", "alpha": 2.5 * alpha,
                         "material": "none", "specular_reflectance": studio.rgb(rho_s)},
                        41 + level)
    ggx *= studio.mean_ratio(s0, ggx, studio.sphere_r() < 1)
    return studio.background() + d0 + ((1 - s) * s0 + s * ggx)


def _inject_vignetting(studio, level, s, rng):
    """cos^4-like natural vignetting of the photo, 1 / (1 + (s rho)^2)^2."""
    img = studio.plain(level)
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    rho = np.hypot(yy - (h - 1) / 2, xx - (w - 1) / 2) / np.hypot(h / 2, w / 2)
    return img / (1 + (s * rho) ** 2) ** 2


def _inject_glare(studio, level, s, rng):
    """A long-tailed (Cauchy-like) lens PSF carrying a share ``s`` of the light."""
    from scipy.signal import fftconvolve

    img = studio.plain(level)
    h, w = img.shape
    k = 2 * max(h, w) + 1
    yy, xx = np.mgrid[0:k, 0:k] - k // 2
    psf = 1 / (1 + (np.hypot(yy, xx) / (0.03 * w)) ** 2) ** 1.5
    psf /= psf.sum()
    return img + s * fftconvolve(img, psf, mode="same")


def _inject_misregistration(studio, level, s, rng):
    """The camera moved by ``s`` px in a random direction, the scene rendered there."""
    rho_d, rho_s, alpha = studio.level(level)
    ang = rng.uniform(0, 2 * np.pi)
    shift = (s * np.cos(ang), s * np.sin(ang))
    return (studio.background(shift)
            + studio.render(studio.ward(rho_d, 0.0, alpha), 11 + level, shift=shift)
            + studio.render(studio.ward(0.0, rho_s, alpha), 21 + level, shift=shift))


def _tail_width_unit(width) -> str:
    """What the long tail's wing form is (:data:`_TAIL_WIDTHS`, ``_wings``, ``_wider_lobe``)."""
    if isinstance(width, str):
        return "the wider lobe of this less glossy level"
    if width >= 1:
        return "px, SD of a Gaussian blur of the lobe"
    if width > 0:
        return "power the lobe is raised to (a wider Ward lobe)"
    return "px, half width w of a GTR1 haze kernel 1 / (1 + (r / w)²)"


def _glare_unit(spread) -> str:
    """What the veiling glare's spread is (:data:`_GLARE_SIGMAS`, ``_glare_blur``)."""
    if isinstance(spread, Number) and spread < 0:
        return "× image width, core w of a power-law kernel (1 + (r / w)²)^(−3/2)"
    return "× image width, SD of a Gaussian kernel"


def _magnitude(code):
    """A width as the table shows it: the fits code the kernel's form in the width's sign
    (``_TAIL_WIDTHS``, ``_GLARE_SIGMAS``), the unit names the form, the value is its size."""
    return abs(code) if isinstance(code, Number) else code


#: Where the diffuse light entered the coat (``_COAT_ENTRY``), in words.
_ENTRY_WORDS = {"surround": "a uniform surround (its entry loss in the diffuse albedo)",
                "view": "along the view (a light at the camera)",
                "lights": "the lights fitted to the diffuse shading (or each photo's own light)",
                "mirror": "the room as the glossiest level's specular render mirrors it"}


def _entry_unit(entry) -> str:
    return f"form chosen from {len(_COAT_ENTRY)}: {_ENTRY_WORDS.get(entry, entry)}"


#: Every render candidate refits the gloss fit's diffuse and specular scales per level.
_SCALE = ParamDoc("scale", "× the gloss fit's component",
                  parts=("diffuse scale", "specular scale"))


# Registered in the order their terms apply (_basis): the material's terms on the specular
# and diffuse components, then the camera's glare and vignetting, then the shift.
register("render", Candidate(
    "fresnel", _remembered_fit(_fit_amp("fresnel", 0.0, 50.0, "kappa", _FRESNEL_CAPS)),
    "specular reflectance rising towards grazing angles (Schlick)", apply=_apply_fresnel,
    inject=_inject_fresnel, default_strength=6.0, units="Schlick gain (1 - F0) / F0",
    truth=lambda s: {"c": float(s)},
    params={"kappa": ParamDoc("cap on the view cosine (0: plain Schlick)", "cosine"),
            "c": ParamDoc("Fresnel rise", "Schlick gain (1 − F0) / F0"), "scale": _SCALE}))
register("render", Candidate(
    "long_tail", _remembered_fit(_fit_long_tail), "highlight lobe with longer tails than Ward's",
    apply=_apply_long_tail, inject=_inject_long_tail, default_strength=0.6,
    units="share of the lobe's energy in the haze",
    # The amount per level; the form (blur or power) has no counterpart in the injector.
    truth=lambda s: {"c": float(s)},
    params={"c": ParamDoc("haze share", "share of the lobe's energy in the haze"),
            "width": ParamDoc("wing form", _tail_width_unit, shown=_magnitude),
            "scale": _SCALE}))
register("render", Candidate(
    "clearcoat", _remembered_fit(_fit_clearcoat),
    "diffuse light leaving through a clear coat, dimmed towards grazing view (Fresnel)",
    apply=_apply_clearcoat, inject=_inject_clearcoat, default_strength=0.6,
    units="share of the diffuse light through the coat", truth=lambda s: {"c": float(s)},
    params={"entry": ParamDoc("where the diffuse light entered the coat", _entry_unit),
            "c": ParamDoc("diffuse light through the coat", "fraction"),
            "alpha2": ParamDoc("second lobe's width (directional lights)", "Ward alpha"),
            "k": ParamDoc("second lobe's albedo (directional lights)",
                          "× the fitted diffuse albedo"),
            "scale": _SCALE}))
register("render", Candidate(
    "veiling_glare",
    _remembered_fit(_fit_amp("veiling_glare", 0.0, 1.0, "sigma_frac", _GLARE_SIGMAS)),
    "lens glare: a blurred copy of the image added", apply=_apply_glare,
    inject=_inject_glare, default_strength=0.15, units="share of the light in the glare",
    truth=lambda s: {"c": float(s)},
    params={"sigma_frac": ParamDoc("glare spread", _glare_unit, shown=_magnitude),
            "c": ParamDoc("light in the glare", "fraction"), "scale": _SCALE}))
register("render", Candidate(
    "vignetting", _remembered_fit(_fit_vignetting),
    "the camera darkens towards the image corners",
    apply=_apply_vignetting, inject=_inject_vignetting, default_strength=0.5,
    units="vignetting coefficient",
    # 1 / (1 + (s rho)^2)^2 = 1 - 2 s^2 rho^2 + O(rho^4).
    truth=lambda s: {"c": 2 * float(s) ** 2},
    params={"c": ParamDoc("darkening ∝ ρ²",
                          "fraction (ρ: distance from the image centre, 1 at the corners)"),
            "c2": ParamDoc("darkening ∝ ρ⁴", "fraction (ρ as above)"), "scale": _SCALE}))
register("render", Candidate(
    "misregistration", _remembered_fit(_fit_misregistration),
    "photo and render still offset after registration",
    apply=_apply_misregistration, inject=_inject_misregistration, default_strength=0.6,
    units="px", truth=lambda s: {"shift_norm_px": float(s)},
    params={"shift_px": ParamDoc("shift", "px", parts=("render shift down",
                                                       "render shift right")),
            "scale": _SCALE}))



# --- under directional lights only (analysis.gap.render.lights) -----------------------------

def _apply_broad_lobe(lv, im, q):
    return im | {"S": im["S"] + q["c"] * lv["lobes"][q["alpha2"]]}


def _inject_broad_lobe(studio, level, s, rng):
    """A share ``s`` of the diffuse albedo moved into a second, broad Ward lobe (alpha 0.5):
    a rough or hazy surface's light scattered near the mirror direction, not evenly."""
    rho_d, _, _ = studio.level(level)
    d0, s0 = studio.base(level)
    broad = studio.render(studio.ward(0.0, s * rho_d, 0.5), 71 + level)
    return studio.background() + (1 - s) * d0 + s0 + broad


#: Registered apart ("render_lights"): its form needs each photo's light direction, which
#: only a directional-light set has; a panorama's levels keep the render catalogue.
register("render_lights", Candidate(
    "broad_lobe", _remembered_fit(_fit_amp("broad_lobe", 0.0, 3.0, "alpha2", BROAD_ALPHAS)),
    "a second, broad specular lobe beside the fitted one (light scattered about the mirror "
    "direction, not evenly as Lambert's)", apply=_apply_broad_lobe, inject=_inject_broad_lobe,
    default_strength=0.1, units="share of the diffuse albedo in the broad lobe",
    # The lobe's albedo in units of the fitted diffuse one: s / (1 - s) once the diffuse scale
    # has given up the share s.
    truth=lambda s: {"c": float(s) / (1 - float(s)), "alpha2": 0.5},
    params={"alpha2": ParamDoc("broad lobe's width", "Ward alpha"),
            "c": ParamDoc("broad lobe's albedo", "× the fitted diffuse albedo"),
            "scale": _SCALE}))

RENDER_CANDIDATES = catalogue("render")
