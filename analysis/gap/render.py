"""Render layer: photos of the physical spheres vs their fitted Ward renders.

Input: the gloss fit's output folder (``OUT_DIR/residuals/*.npz``, one per gloss level, with
float32 ``photo``, ``render``, ``diffuse``, ``specular`` (h x w x 3, linear, photo units) and
boolean masks ``highlight``, ``body``, ``rim``, ``background``, ``sphere``, ``valid``), and, if
there, ``OUT_DIR/fit.json``, whose ``setup`` gives the camera's distance and the sphere's radius
(cm). Everything is compared in Rec. 709 luminance.

The plain simulation predicts the photo by the render ``R = B + D + S`` (background, the
panorama around the sphere, which reaches into the rim's edge pixels; diffuse; specular). Each
candidate is an image-space or component-space extension (approximations, documented):

=================  ===========================================================================
candidate          extension (c = fitted amplitude; geometry from the sphere mask, orthographic
                   unless noted)
=================  ===========================================================================
fresnel            S * (1 + c (1 - cos t)^5): Schlick's rise towards grazing view, with the
                   view angle t (cos t = sqrt(1 - r^2), r = distance from the sphere's centre in
                   radii) standing in for the half-vector angle
clearcoat          D * (1 + c (T(t) g - 1)), T = (1 - F(t)) / (1 - F(0)), F the exact
                   Fresnel reflectance of a coat of IOR 1.5: diffuse light leaves through the
                   coat at the view angle t, dimmed towards grazing, having entered it at the
                   light's angles: g = E_T / E, the irradiance weighted by T at entry over the
                   plain irradiance; g = 1 (entry "surround": a uniform surround, its entry
                   loss in rho_d), T(t) ("view": light along the view), ("lights") from the
                   diffuse shading fitted as a surround (spherical harmonics of bands 0-1) plus
                   a round key light (direction and half-angle searched from the highlight's
                   mirror direction), or ("mirror") from the room as the glossiest level's
                   specular render mirrors it (each pixel's light from its mirror direction);
                   T g normalised at the centre; the entry chosen by the fit. Normals and
                   view directions are a pinhole's when the folder's fit.json gives the
                   camera distance and sphere radius (the gloss fit's setup), else
                   orthographic
vignetting         R * (1 - c rho^2 - c2 rho^4), rho = distance from the image centre / half
                   diagonal (two terms of real lenses' calibration polynomial)
veiling_glare      R + c G_s * R: a blurred copy of the image spread by the lens (Gaussian, s
                   from a grid of large widths, or a power law (1 + (r / w)^2)^(-3/2) with a
                   narrow core w, from a grid)
misregistration    R shifted by (dx, dy) px per gloss level: the radiance by cubic splines, the
                   silhouette's pixel coverage recomputed at the shifted sphere
long_tail          S + c (W - S): highlight energy moved into wider wings W, either the lobe
                   blurred (Gaussian, 1-8 px, or a GTR1 haze's kernel 1 / (1 + (r / w)^2),
                   w 2-16 px), raised to a power k < 1 (a Ward lobe of alpha / sqrt(k)), or
                   a less glossy level's specular render (the same room through a wider
                   lobe: a haze reflects the room into the body, where the lobe itself shows
                   little of it), at the same energy; c and the form (from a grid) per
                   gloss level, as the tails' width follows the lobe's
=================  ===========================================================================

With every extension the Ward fit's diffuse and specular scales (its rho_d, rho_s) are fitted
again per level, as the gloss fit would have done had it known the effect.

Loss: Gaussian NLL per pixel on the sphere (highlight, body, rim; valid pixels) with a
Poisson-Gaussian noise model per level, ``sd^2 = a2 + b R`` (read noise and shot noise of the
camera; the render's Monte-Carlo noise grows with the signal too), measured from the second
differences of photo - render (:func:`noise_model`; a smooth misfit drops out), so the floor is
``0.5 log(2 pi sd^2) + 0.5`` per pixel. A constant SD would count a highlight's shot noise as a
gap. Held out: pixels in a checkerboard of 4 x 4 blocks (half train, half test) in every level.

Each candidate is one object registered with the engine (``register("render", ...)``): its fit,
its term (``apply``, in the registration order), its injector (the effect built into a Mitsuba
material or the camera, drawn with the benchmark's renderer), its default strength and the
parameters a right fit recovers. The ceiling (:func:`render_ceiling`) is the chosen model plus a
local smooth of what it leaves; a chosen model that stays significantly above it leaves a gap
outside the catalogue.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import ndimage, optimize, signal

from analysis.gap.engine import Candidate, GapError, catalogue, register
from studydesign import rec709_luminance

__all__ = [
    "NPZ_ARRAYS",
    "NPZ_MASKS",
    "RENDER_CANDIDATES",
    "RENDER_MIN_GAIN",
    "RENDER_MIN_SHARE",
    "RENDER_SIZE_UNIT",
    "RenderData",
    "load_render",
    "localise_render",
    "noise_model",
    "noise_sd",
    "render_ceiling",
    "render_floor",
    "render_loss",
    "render_misfit_pct",
    "render_unit_ids",
    "residual_maps",
    "split_render",
]

NPZ_ARRAYS = ("photo", "render", "diffuse", "specular")
NPZ_MASKS = ("highlight", "body", "rim", "background", "sphere")
REGIONS = ("highlight", "body", "rim", "background")
#: An attribution must remove >= 80 % of the held-out gap (as for the display layer).
RENDER_MIN_SHARE = 0.8
#: A step, or a gap left beyond the catalogue, counts only from 0.02 nats per pixel (the
#: observer layer's tolerance per trial): a misfit of about 0.2 noise SDs per pixel
#: (0.5 z^2 = 0.02). Photos of thousands of pixels make far smaller misfits significant --
#: an approximate form's leftovers, not an effect worth naming.
RENDER_MIN_GAIN = 0.02
#: How the render layer's remaining misfit is sized (see :func:`render_misfit_pct`); it is held
#: to the design's [gap] render_tolerance_pct.
RENDER_SIZE_UNIT = "% of the photos' RMS luminance"
_BLOCK = 4
#: Glare spreads (x image width): a Gaussian's SD (> 0) or a power-law kernel's core (< 0).
_GLARE_SIGMAS = (0.125, 0.25, 0.5, -0.015, -0.03, -0.06)
#: Caps kappa on the view cosine of the Fresnel rise (a grid; 0 = plain Schlick at the view
#: angle): near the silhouette the lobe's reflected directions that fall below the horizon do
#: not reflect, so the half vectors that do tilt towards the camera and the rise saturates.
_FRESNEL_CAPS = (0.0, 0.15, 0.3)
#: Where the diffuse light entered the coat (see _coat_t, _coat_lights and _coat_mirror): from
#: a uniform surround, along the view, from the lights seen in the shading and the highlight,
#: or from the room seen in the specular render.
_COAT_ENTRY = ("surround", "view", "lights", "mirror")
_COAT_PATHS = {"surround": 1.0, "view": 2.0}  # passes through the coat at the view angle
_COAT_IOR = 1.5  # a lacquer's or a plastic's refractive index (F0 = 0.04)
#: The coat's key light (see _fit_shading): a round lamp of half-angle up to 40 deg, drawn as
#: this many directions.
_KEY_MAX_RAD, _KEY_SAMPLES = 0.7, 48
#: The 'mirror' coat entry (see _mirror_light, _coat_mirror): at most about this many light
#: directions, and pixels summed over in blocks of this many (memory: 8 bytes x the product).
_MIRROR_LIGHTS, _MIRROR_CHUNK = 4096, 1024
#: Wing forms (see _wings): Gaussian blur px (>= 1), lobe power (in (0, 1)) or a GTR1 kernel
#: of that many px half width (< 0); besides these, each less glossy level's name (_wider_lobe).
_TAIL_WIDTHS = (1.0, 2.0, 4.0, 8.0, 0.5, 0.25, 0.12, -2.0, -4.0, -8.0, -16.0)


def _lum(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, float)
    return rec709_luminance(a) if a.ndim == 3 else a


class RenderData:
    """Per-level luminance images, geometry and the pixel units (a train or test view).

    Attributes
    ----------
    levels : list of dict
        One per gloss level: ``name``, ``P`` (photo), ``D``, ``S`` (h x w float), ``cos_t``
        (view cosine on the sphere), ``rho2`` (squared image radius), ``sd`` (noise SD),
        ``wider`` (the specular renders of the less glossy levels, on this level's sphere),
        masks ``regions`` (dict), ``fit`` (bool: pixels in the loss), ``use`` (bool: this view's
        pixels).
    """

    def __init__(self, levels: list[dict]):
        self.levels = levels

    def view(self, which: str) -> RenderData:
        out = []
        for lv in self.levels:
            lv2 = dict(lv)
            lv2["use"] = lv["fit"] & (lv["train"] if which == "train" else ~lv["train"])
            out.append(lv2)
        return RenderData(out)


def noise_model(resid: np.ndarray, render: np.ndarray, mask: np.ndarray,
                n_bins: int = 8) -> tuple[float, float]:
    """Poisson-Gaussian noise of a photo, ``var = a2 + b * max(render, 0)`` (photo units).

    A camera's raw values carry read noise (constant variance ``a2``) and shot noise (variance
    proportional to the signal, ``b``); a Monte-Carlo render's noise also grows with the
    signal. Both are measured without a model of the scene from the second differences of
    ``resid`` = photo - render along rows and columns (a smooth misfit drops out):
    ``d2 = r[i-1] - 2 r[i] + r[i+1]`` has variance ``6 a2 + b w``, ``w = R[i-1] + 4 R[i] +
    R[i+1]``. The variance of ``d2`` is measured robustly (MAD) in ``n_bins`` quantile bins of
    ``w`` and the line fitted by non-negative least squares weighted by each bin's count
    (a highlight's residual curvature affects a few pixels, which MAD ignores).

    Returns
    -------
    (a2, b) : tuple of float
        Read-noise variance (photo units^2) and shot-noise gain (photo units).

    Raises
    ------
    GapError
        If fewer than 10 stencils lie inside ``mask``, or the photo shows no noise at all.
    """
    d2s, ws = [], []
    rr = np.maximum(render, 0.0)
    for ax in (0, 1):
        lo, mid, hi = ((slice(None, -2), slice(1, -1), slice(2, None)) if ax == 0 else
                       ((slice(None), slice(None, -2)), (slice(None), slice(1, -1)),
                        (slice(None), slice(2, None))))
        m = mask[lo] & mask[mid] & mask[hi]
        d2s.append((resid[lo] - 2 * resid[mid] + resid[hi])[m])
        ws.append((rr[lo] + 4 * rr[mid] + rr[hi])[m])
    d2, w = np.concatenate(d2s), np.concatenate(ws)
    if d2.size < 10:
        raise GapError("too few valid sphere pixels to measure the photo's noise")
    edges = np.unique(np.quantile(w, np.linspace(0, 1, n_bins + 1)))
    which = np.clip(np.searchsorted(edges, w, side="right") - 1, 0, max(edges.size - 2, 0))
    rows, var, cnt = [], [], []
    for k in np.unique(which):
        sel = which == k
        if sel.sum() < 5:
            continue
        v = d2[sel]
        mad = 1.4826 * np.median(np.abs(v - np.median(v)))
        rows.append([6.0, float(np.mean(w[sel]))])
        var.append(mad**2)
        cnt.append(np.sqrt(sel.sum()))
    a_mat, var, cnt = np.asarray(rows), np.asarray(var), np.asarray(cnt)
    if a_mat.shape[0] >= 2 and np.ptp(a_mat[:, 1]) > 0:
        (a2, b), _ = optimize.nnls(a_mat * cnt[:, None], var * cnt)
    else:
        a2, b = float(np.average(var, weights=cnt)) / 6.0, 0.0
    if a2 <= 0 and b <= 0:
        raise GapError("the photo has no measurable noise (photo - render is smooth to the last "
                       "bit): was a render passed as the photo? Pass the camera's photos")
    return float(a2), float(b)


def noise_sd(render: np.ndarray, a2: float, b: float) -> np.ndarray:
    """Per-pixel noise SD of the Poisson-Gaussian model (:func:`noise_model`); the read-noise
    part keeps it above 0 where the render is black."""
    return np.sqrt(np.maximum(a2 + b * np.maximum(render, 0.0), 1e-30))


def load_render(real_path, sim_path=None) -> RenderData:
    """Read the gloss fit's residual files. Photos come from REAL, renders (and components)
    from SIM (the same folder when the fit's output holds both, the usual case); the camera's
    distance from SIM's fit.json when it has one (:func:`_camera_distance`)."""
    real = Path(real_path)
    sim = Path(sim_path) if sim_path is not None else real
    files = sorted((real / "residuals").glob("*.npz")) if real.is_dir() else []
    if not files:
        raise GapError(f"no residuals/*.npz under {real}; pass the gloss fit's output folder "
                       "(python -m stimuli fit-gloss PHOTO_SET --out DIR)")
    distance = _camera_distance(sim)
    levels = []
    for f in files:
        g = sim / "residuals" / f.name
        if not g.exists():
            raise GapError(f"{g} missing: the render for {f.name} is not in --sim")
        with np.load(f) as a, np.load(g) as b:
            need = [k for k in ("photo", *NPZ_MASKS) if k not in a.files]
            need += [f"{k} (sim)" for k in ("render", "diffuse", "specular") if k not in b.files]
            if need:
                raise GapError(f"{f.name}: arrays {need} missing; the residual files need "
                               f"{NPZ_ARRAYS} and masks {NPZ_MASKS}")
            P = _lum(a["photo"])
            D, S = _lum(b["diffuse"]), _lum(b["specular"])
            # The fit's render is B + D + S, B the panorama around the (black) sphere: it
            # reaches into the rim's edge pixels, which the sphere covers only in part.
            B = _lum(b["render"]) - D - S
            masks = {k: np.asarray(a[k], bool) for k in NPZ_MASKS}
            valid = np.asarray(a["valid"], bool) if "valid" in a.files else np.isfinite(P)
        if P.shape != D.shape:
            raise GapError(f"{f.name}: photo {P.shape} and render {D.shape} differ in size")
        h, w = P.shape
        sph = masks["sphere"]
        if sph.sum() < 20:
            raise GapError(f"{f.name}: the sphere mask has {int(sph.sum())} pixels (< 20)")
        yy, xx = np.mgrid[0:h, 0:w].astype(float)
        cy, cx = yy[sph].mean(), xx[sph].mean()
        # The fit's sphere mask stops 1 px inside the silhouette.
        radius = np.sqrt(sph.sum() / np.pi) + 1.0
        r = np.hypot(yy - cy, xx - cx) / radius
        cos_t = np.sqrt(np.clip(1 - r**2, 0.0, 1.0))
        fres5, coat, cover = _subpixel_factors(yy, xx, cy, cx, radius)
        coat["lights"] = _coat_lights(D, S, coat["surround"], (yy - cy) / radius,
                                      (xx - cx) / radius, cover, distance)
        rho2 = ((yy - (h - 1) / 2) ** 2 + (xx - (w - 1) / 2) ** 2) / ((h / 2) ** 2 + (w / 2) ** 2)
        fit = valid & (masks["highlight"] | masks["body"] | masks["rim"]) & np.isfinite(P)
        train = ((yy // _BLOCK + xx // _BLOCK) % 2 == 0)
        m = re.search(r"(\d+(?:\.\d+)?)", f.stem)
        R0 = B + D + S
        noise = noise_model(P - R0, R0, valid & sph)
        levels.append({"name": f.stem, "gloss": float(m.group(1)) if m else np.nan,
                       "P": P, "B": B, "D": D, "S": S, "cos_t": cos_t, "fres5": fres5,
                       "coat": coat, "cover": cover, "rho2": rho2,
                       "geometry": (cy, cx, radius), "distance": distance,
                       "regions": {k: masks[k] & valid for k in REGIONS}, "fit": fit,
                       "train": train, "use": fit, "width": w,
                       "noise": noise, "sd": noise_sd(R0, *noise)})
    # The long tail's wings may borrow the lobe of any less glossy level (see _wider_lobe),
    # brought onto this level's sphere.
    sharp = {lv["name"]: _sharpness(lv) for lv in levels}
    for lv in levels:
        lv["wider"] = {o["name"]: _aligned_lobe(o, lv) for o in levels
                       if sharp[o["name"]] < sharp[lv["name"]]}
    light = _mirror_light(max(levels, key=_sharpness))
    for lv in levels:
        lv["coat"]["mirror"] = _coat_mirror(light, lv)
    return RenderData(levels)


def _aligned_lobe(src: dict, dst: dict) -> np.ndarray:
    """``src``'s specular render on ``dst``'s sphere: each level is a photo of its own sphere,
    which may sit elsewhere in the frame, at another size, in an image of another size. The
    lobe's radiance (image / coverage, filled at the silhouette) is resampled (linear) at the
    point of ``src``'s sphere with the same position relative to its centre and radius, and
    multiplied by ``dst``'s coverage. Spheres that coincide (within 0.01 px) in images of one
    size get ``src``'s image unchanged."""
    (cy0, cx0, r0), (cy1, cx1, r1) = src["geometry"], dst["geometry"]
    S = src["S"]
    if S.shape == dst["S"].shape and max(abs(cy0 - cy1), abs(cx0 - cx1), abs(r0 - r1)) < 0.01:
        return S
    known = src["cover"] > 0.5
    rad = _fill(np.where(known, S / np.maximum(src["cover"], 1e-6), 0.0), known)
    yy, xx = np.mgrid[0:dst["S"].shape[0], 0:dst["S"].shape[1]].astype(float)
    k = r0 / r1
    coords = np.array([cy0 + (yy - cy1) * k, cx0 + (xx - cx1) * k])
    return dst["cover"] * ndimage.map_coordinates(rad, coords, order=1, mode="nearest")


def _subpixel_factors(yy, xx, cy, cx, radius, n: int = 8):
    """Per-pixel means of the Fresnel rise (1 - max(cos t, kappa))^5 (one image per kappa of
    ``_FRESNEL_CAPS``) and of the coat's transmission T(t) / T(0) over the part of each pixel
    the sphere covers (n x n sub-pixels): at the rim cos t changes steeply within one pixel,
    and the pixel's value averages it. Also returns the covered share of each pixel."""
    offs = (np.arange(n) + 0.5) / n - 0.5
    fres = {k: np.zeros(yy.shape) for k in _FRESNEL_CAPS}
    coat = {k: np.zeros(yy.shape) for k in _COAT_PATHS}
    cover = np.zeros(yy.shape)
    for dy in offs:
        for dx in offs:
            r2 = ((yy + dy - cy) ** 2 + (xx + dx - cx) ** 2) / radius**2
            inside = r2 < 1
            c = np.sqrt(np.clip(1 - r2, 0.0, 1.0))
            for k in _FRESNEL_CAPS:
                fres[k] += np.where(inside, (1 - np.maximum(c, k)) ** 5, 0.0)
            for k, paths in _COAT_PATHS.items():
                coat[k] += np.where(inside, _coat_t(c, paths), 0.0)
            cover += inside
    share = cover / n**2
    cover = np.maximum(cover, 1)
    return ({k: v / cover for k, v in fres.items()}, {k: v / cover for k, v in coat.items()},
            share)


def _coat_entry_ratios(n: int = 2000) -> tuple[float, float]:
    """Irradiance through the coat over the plain irradiance, per spherical-harmonic band
    0 and 1 of the light (a smooth surround): A_l^T / A_l with A_l = 2 pi int_0^1 k(mu) P_l(mu)
    dmu, k = mu (Lambert) or mu T(mu) (entry through the coat; Ramamoorthi & Hanrahan 2001,
    eq. 8, with the transmission in the kernel)."""
    mu = (np.arange(n) + 0.5) / n
    t = _coat_t(mu)
    return float(2 * np.mean(mu * t)), float(3 * np.mean(mu**2 * t))


def _sphere_view(y: np.ndarray, x: np.ndarray, distance: float | None = None):
    """Normals and view directions on the sphere, each (3, h, w) (x right, y up, z to the
    camera), from image coordinates ``y`` (down) and ``x`` in apparent sphere radii from its
    centre, clipped to the silhouette. ``distance``: the camera's distance from the sphere's
    centre in sphere radii (a pinhole looking at the centre, the gloss fit's camera); None: an
    orthographic view along z. Up close the silhouette's normals tilt towards the camera by
    asin(1 / distance) and the view turns across the image by as much (4 deg at 13.75 radii),
    which moves a mirror direction by up to twice that."""
    if distance is None:
        n = np.stack([x, -y, np.sqrt(np.clip(1 - y**2 - x**2, 0.0, 1.0))])
        return n, np.broadcast_to(np.array([0.0, 0.0, 1.0])[:, None, None], n.shape)
    # The ray through (x, y): tan of its angle off the axis is the image radius times tan of
    # the silhouette's angle, asin(1 / distance); it meets the sphere at the normal n.
    tan_edge = 1 / np.sqrt(distance**2 - 1)
    ray = np.stack([x * tan_edge, -y * tan_edge, -np.ones_like(x)])
    ray /= np.linalg.norm(ray, axis=0)
    along = distance * ray[2]  # camera at (0, 0, distance): its position dotted with the ray
    t = -along - np.sqrt(np.maximum(along**2 - distance**2 + 1, 0.0))
    n = np.array([0.0, 0.0, distance])[:, None, None] + t * ray
    return n / np.linalg.norm(n, axis=0), -ray


def _camera_distance(folder: Path) -> float | None:
    """The gloss fit's camera distance in sphere radii, from ``fit.json``'s ``setup``
    (camera_distance_cm / sphere_radius_cm, the photo set's setup.toml); None (an orthographic
    view) when the folder has no fit.json or it lacks them.

    Raises
    ------
    GapError
        If fit.json is torn (not JSON, or its setup not a table), its distance or radius is
        not a number, or it puts the camera inside the sphere."""
    path = Path(folder) / "fit.json"
    if not path.is_file():
        return None
    try:
        setup = json.loads(path.read_text()).get("setup") or {}
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError) as exc:
        setup = exc
    if not isinstance(setup, dict):
        raise GapError(f"{path}: not a gloss fit's fit.json (its 'setup' unreadable: {setup}); "
                       "pass the folder a whole gloss fit wrote (python -m stimuli fit-gloss "
                       "PHOTO_SET --out DIR), or run the fit again into a new folder")
    if "camera_distance_cm" not in setup or "sphere_radius_cm" not in setup:
        return None
    try:
        distance = float(setup["camera_distance_cm"]) / float(setup["sphere_radius_cm"])
    except (TypeError, ValueError, ZeroDivisionError) as exc:
        raise GapError(f"{path}: setup's camera_distance_cm {setup['camera_distance_cm']!r} "
                       f"and sphere_radius_cm {setup['sphere_radius_cm']!r} must be numbers "
                       "in cm, the radius above 0") from exc
    if not distance > 1:
        raise GapError(f"{path}: camera_distance_cm {setup['camera_distance_cm']} is not beyond "
                       f"sphere_radius_cm {setup['sphere_radius_cm']}")
    return distance


def _surround_bands(n: np.ndarray) -> list:
    """Real spherical harmonics of bands 0 and 1 in the normal (unnormalised): the smooth part
    of the surround's irradiance. Band 2 is left out: fitted beside the key light to a room's
    shading (a floor, a window) it takes up the light's terminator and misplaces the light
    (a Mitsuba coat left 1.2-1.7 nats/px with it, 0.9-1.1 without it; analytic coat equal)."""
    return [[np.ones(n.shape[1:])], [n[0], n[1], n[2]]]


def _cap_directions(light: np.ndarray, sigma: float) -> np.ndarray:
    """``_KEY_SAMPLES`` unit directions (k, 3) spread evenly in solid angle over a cone of
    half-angle ``sigma`` (rad) about the unit vector ``light`` (a Fibonacci spiral)."""
    i = np.arange(_KEY_SAMPLES) + 0.5
    cos_a = 1 - i / _KEY_SAMPLES * (1 - np.cos(sigma))
    sin_a = np.sqrt(np.clip(1 - cos_a**2, 0.0, 1.0))
    phi = np.pi * (1 + 5**0.5) * i
    e1 = np.cross(light, [1.0, 0.0, 0.0] if abs(light[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(light, e1)
    return (cos_a[:, None] * light
            + sin_a[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))


def _key_irradiance(n: np.ndarray, light: np.ndarray, sigma: float):
    """A round key light's irradiance on normals ``n`` (3, ...) per unit of its own, plain and
    through the coat: the means over :func:`_cap_directions` of max(n.w, 0) and of max(n.w, 0)
    T(n.w). A lamp of some size has a soft terminator, where the coat's entry loss is largest."""
    cos_w = np.tensordot(_cap_directions(light, sigma), n, axes=1)
    lam = np.maximum(cos_w, 0.0)
    return lam.mean(axis=0), (lam * _coat_t(np.clip(cos_w, 0.0, 1.0))).mean(axis=0)


def _fit_shading(D: np.ndarray, n: np.ndarray, inner: np.ndarray, start: np.ndarray):
    """Least-squares fit of the diffuse shading ``D`` on the ``inner`` pixels as a smooth
    surround (:func:`_surround_bands`) plus one round key light (:func:`_key_irradiance`), its
    direction and half-angle (0 to ``_KEY_MAX_RAD``) searched (Nelder-Mead) from ``start`` (a
    unit vector) and a small lamp.

    Returns (l, sigma, coef): the key light's unit direction, its half-angle (rad) and the
    coefficients (the bands' in order, then the key light's k >= 0)."""
    smooth = np.stack([b[inner] for band in _surround_bands(n) for b in band], axis=1)
    n_in = n[:, inner]

    def fit(p):
        el, az, q = p
        ell = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        sigma = _KEY_MAX_RAD * np.sin(q) ** 2  # bounded without constraints
        a = np.c_[smooth, _key_irradiance(n_in, ell, sigma)[0]]
        coef, *_ = np.linalg.lstsq(a, D[inner], rcond=None)
        return float(np.sum((D[inner] - a @ coef) ** 2)), ell, sigma, coef
    p0 = (np.arcsin(np.clip(start[2], -1, 1)), np.arctan2(start[1], start[0]), 0.3)
    best = optimize.minimize(lambda p: fit(p)[0], p0, method="Nelder-Mead",
                             options={"xatol": 1e-3, "fatol": 1e-12, "maxiter": 300})
    _, light, sigma, coef = fit(best.x)
    if coef[-1] < 0:  # no key light: the surround alone
        coef[-1] = 0.0
        coef[:-1], *_ = np.linalg.lstsq(smooth, D[inner], rcond=None)
    return light, sigma, coef


def _coat_lights(D: np.ndarray, S: np.ndarray, t_view: np.ndarray, y: np.ndarray,
                 x: np.ndarray, cover: np.ndarray, distance: float | None = None) -> np.ndarray:
    """The coat's factor on the diffuse light (per level, h x w), T(t) g normalised to mean 1
    within 0.3 radii of the centre, with the entry factor g = E_T / E (the irradiance
    weighted by the coat's transmission at its entry angle over the plain irradiance)
    estimated from the render itself.

    The diffuse shading is fitted as a surround plus a round key light (:func:`_fit_shading`),
    the search for the key light starting from the mirror of the view about the normal at the
    specular render's peak (where n = h). Through the coat the surround's bands are weighted
    by :func:`_coat_entry_ratios`, the key light by T at each of its directions. ``t_view``: T
    at the view angle (each pixel's sub-pixel mean); ``y``, ``x``: image coordinates from the
    sphere's centre in radii (y down); ``cover``: the share of each pixel the sphere covers;
    ``distance``: the camera's, in sphere radii (:func:`_sphere_view`)."""
    r2 = y**2 + x**2
    n, v = _sphere_view(y, x, distance)
    inner = (cover > 0.999) & (r2 < 0.9**2)
    peak = np.unravel_index(np.argmax(np.where(r2 < 0.85**2, ndimage.gaussian_filter(S, 1.0),
                                               -np.inf)), S.shape)
    nh, vh = n[(slice(None), *peak)], v[(slice(None), *peak)]
    mirror = 2 * (nh @ vh) * nh - vh
    light, sigma, coef = _fit_shading(D, n, inner, mirror / np.linalg.norm(mirror))
    key, key_t = _key_irradiance(n, light, sigma)
    e, e_t, j = coef[-1] * key, coef[-1] * key_t, 0
    for band, ratio in zip(_surround_bands(n), _coat_entry_ratios()):
        for b in band:
            e, e_t, j = e + coef[j] * b, e_t + ratio * coef[j] * b, j + 1
    # Where the fitted irradiance nears 0 (beyond the key light's terminator, a dark
    # surround) the ratio is noise: floor the denominator at 5 % of its peak.
    floor = 0.05 * float(np.max(np.abs(e[inner]))) if inner.any() else 1e-12
    factor = t_view * np.clip(e_t / np.maximum(e, floor), 0.0, 2.0)
    return _unit_at_centre(factor, r2, cover > 0)


def _unit_at_centre(factor: np.ndarray, r2: np.ndarray, on: np.ndarray) -> np.ndarray:
    """A coat factor scaled to mean 1 within 0.3 radii of the sphere's centre (``r2``: squared
    distance from it in radii; ``on``: the pixels the sphere covers), where the coat's entry
    and exit losses are smallest and its amplitude is read."""
    centre = (r2 < 0.3**2) & on
    return factor / max(float(factor[centre].mean()), 1e-12) if centre.any() else factor


def _sharpness(lv: dict) -> float:
    """How sharply a level's specular render images the surround: its peak over its mean on
    the sphere (the glossiest level's lobe blurs the reflected room least)."""
    s = lv["S"][lv["regions"]["highlight"] | lv["regions"]["body"]]
    return float(s.max() / max(s.mean(), 1e-12)) if s.size else 0.0


def _mirror_light(lv: dict) -> tuple[np.ndarray, np.ndarray]:
    """The surround as the level's specular render shows it: each pixel's mirror direction r
    = 2 (n.v) n - v (the gloss fit's camera, :func:`_sphere_view`) and the light from it,
    L dOmega = S 4 / radius^2 (a mirror ball seen orthographically maps every px^2 of the image
    to 4 / radius^2 sr; a pinhole at 13.75 radii maps 0.93 of that at the centre to 1.03 near
    the rim, a smooth weighting the ratio E_T / E barely feels; S is the fitted lobe's image of
    the room, blurred by the lobe, in arbitrary units).
    Returns (directions (3, m), power (m,)) over the pixels the sphere covers, every s-th pixel
    in each direction with s^2 times its power where the sphere covers more than
    ``_MIRROR_LIGHTS`` pixels (the lobe blurs the room over several pixels; a sphere of 200 px
    radius would otherwise make each pixel's irradiance a sum over 125 000 directions)."""
    cy, cx, radius = lv["geometry"]
    h, w = lv["S"].shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    on = lv["cover"] > 0
    stride = max(1, int(np.ceil(np.sqrt(on.sum() / _MIRROR_LIGHTS))))
    on &= (yy % stride == 0) & (xx % stride == 0)
    n, v = (a[:, on] for a in _sphere_view((yy - cy) / radius, (xx - cx) / radius,
                                           lv["distance"]))
    mirror = 2 * np.sum(n * v, axis=0) * n - v
    return mirror, np.maximum(lv["S"][on], 0.0) * 4 * stride**2 / radius**2


def _coat_mirror(light: tuple[np.ndarray, np.ndarray], lv: dict) -> np.ndarray:
    """The coat's factor on the diffuse light (h x w), T(t) g normalised to mean 1 within 0.3
    radii of the centre, the entry factor g = E_T / E summed over the surround seen in the
    glossiest level's specular render (:func:`_mirror_light`): no model of the lights, so a
    room's windows, lamps and floor enter at their own angles. The lobe's blur softens the
    lights' terminators: a point light is better served by :func:`_coat_lights`, and the fit
    picks the entry."""
    dirs, power = light
    cy, cx, radius = lv["geometry"]
    h, w = lv["D"].shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    y, x, cover = (yy - cy) / radius, (xx - cx) / radius, lv["cover"]
    on = cover > 0
    normals = _sphere_view(y, x, lv["distance"])[0][:, on]
    e_on, e_t_on = np.zeros(normals.shape[1]), np.zeros(normals.shape[1])
    for i in range(0, normals.shape[1], _MIRROR_CHUNK):  # (lights x pixels) bounded in memory
        cos_w = dirs.T @ normals[:, i:i + _MIRROR_CHUNK]
        lam = np.maximum(cos_w, 0.0)
        e_on[i:i + _MIRROR_CHUNK] = power @ lam
        e_t_on[i:i + _MIRROR_CHUNK] = power @ (lam * _coat_t(np.clip(cos_w, 0.0, 1.0)))
    e, e_t = np.zeros((h, w)), np.zeros((h, w))
    e[on], e_t[on] = e_on, e_t_on
    r2 = y**2 + x**2
    inner = (cover > 0.999) & (r2 < 0.9**2)
    peak = float(e[inner].max()) if inner.any() else 0.0
    if peak <= 0:  # no specular light to see the room by: the uniform surround's factor
        return lv["coat"]["surround"]
    factor = lv["coat"]["surround"] * np.clip(e_t / np.maximum(e, 0.05 * peak), 0.0, 2.0)
    return _unit_at_centre(factor, r2, on)


# --- the extended model -------------------------------------------------------------------

def _wings(S: np.ndarray, width: float, inside: np.ndarray) -> np.ndarray:
    """A wider lobe from the fitted one. ``width`` >= 1: Gaussian blur of that many px within
    the sphere (``inside``: the share of each pixel the sphere covers; a wider lobe moves light
    across the sphere, not onto the background); ``width`` in (0, 1): the lobe raised to that
    power (Ward's lobe exp(-tan^2 / alpha^2) raised to alpha^2 / alpha_t^2 is the lobe of the
    wider alpha_t), rescaled to the same energy; ``width`` < 0: the lobe spread within the
    sphere (as the Gaussian) by a kernel 1 / (1 + (r / w)^2), w = -width px: the GTR1 haze
    of Burley (2012, eq. 4), whose tails fall as the square of the angle (tan^-2) where a Ward
    lobe's fall as a Gaussian -- with angle ~ distance on the sphere near the highlight."""
    if width < 0:
        h, w = S.shape
        yy, xx = np.mgrid[-h:h + 1, -w:w + 1]
        kern = 1 / (1 + (yy**2 + xx**2) / width**2)
        kern /= kern.sum()
        blurred = signal.fftconvolve(S * inside, kern, mode="same")
        weight = signal.fftconvolve(inside, kern, mode="same")
        return np.where(inside > 0, blurred / np.maximum(weight, 1e-6), 0.0) * inside
    if width >= 1:
        blurred = ndimage.gaussian_filter(S * inside, width)
        weight = ndimage.gaussian_filter(inside, width)
        return np.where(inside > 0, blurred / np.maximum(weight, 1e-6), 0.0) * inside
    top = float(S.max())
    if top <= 0:
        return S
    wide = top * np.clip(S / top, 0, None) ** width
    return wide * (S.sum() / max(wide.sum(), 1e-12))


def _fresnel_coat(cos_i, eta: float = _COAT_IOR):
    """Unpolarised Fresnel reflectance of a dielectric coat of index ``eta`` in air (exact;
    e.g. Walter et al. 2007, eq. 22). Schlick's approximation misses the transmission's fall
    at grazing angles by several per cent, which a coat over thousands of pixels shows."""
    c = np.clip(cos_i, 1e-6, 1.0)
    g = np.sqrt(eta**2 - 1 + c**2)
    return 0.5 * ((g - c) / (g + c)) ** 2 * (1 + ((c * (g + c) - 1) / (c * (g - c) + 1)) ** 2)


def _coat_t(cos_t, paths: float = 1.0):
    """Transmission of a clear coat (exact Fresnel, IOR 1.5: F0 = 0.04) relative to normal
    view, on ``paths`` passes at the view angle: 1 when the light enters from a diffuse
    surround (its own transmission, averaged over the directions, goes into rho_d), 2 when it
    enters along the view (a light at the camera)."""
    return ((1 - _fresnel_coat(cos_t)) / (1 - _fresnel_coat(1.0))) ** paths


def _basis(lv: dict, fitted: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Diffuse, specular and background images after every fitted extension (before the
    diffuse and specular scales): each registered candidate's ``apply``, in the catalogue's
    order (material terms, then the camera's, then the shift)."""
    p = dict(fitted)
    unknown = set(p) - {c.name for c in catalogue("render")}
    if unknown:
        raise GapError(f"no render candidate(s) {sorted(unknown)}; known: "
                       f"{[c.name for c in catalogue('render')]}")
    images = {"D": lv["D"], "S": lv["S"], "B": lv["B"]}
    for cand in catalogue("render"):
        if cand.name in p:
            images = cand.apply(lv, images, p[cand.name])
    return images["D"], images["S"], images["B"]


def _apply_fresnel(lv, im, q):
    return im | {"S": im["S"] * (1 + q["c"] * lv["fres5"][q["kappa"]])}


def _apply_long_tail(lv, im, q):
    c, width = q["c"].get(lv["name"], 0.0), q["width"].get(lv["name"], 1.0)
    if isinstance(width, str):
        wide = _wider_lobe(lv, im["S"], width)
    else:
        wide = _wings(im["S"], width, lv["cover"])
    return im | {"S": im["S"] + c * (wide - im["S"])}


def _wider_lobe(lv: dict, S: np.ndarray, other: str) -> np.ndarray:
    """Wings from a less glossy level: ``other``'s specular render (the same room, camera and
    sphere through its wider Ward lobe) with the factor the material terms fitted before it
    put on this level's lobe (Fresnel's rise), at this lobe's energy on the sphere. A haze
    reflects the whole room into the body, where this level's own lobe shows little of it;
    the image-space forms (:func:`_wings`) can only spread what this lobe shows."""
    So = lv["wider"][other]
    base = lv["S"]
    ok = base > 1e-6 * max(float(base.max()), 1e-30)
    factor = np.where(ok, S / np.where(ok, base, 1.0), 1.0)
    wide = So * factor * lv["cover"]
    return wide * (float((S * lv["cover"]).sum()) / max(float(wide.sum()), 1e-30))


def _apply_clearcoat(lv, im, q):
    return im | {"D": im["D"] * (1 + q["c"] * (lv["coat"][q["entry"]] - 1))}


def _apply_glare(lv, im, q):
    # The image-space effects are linear: apply them to each component.
    return {k: v + q["c"] * _glare_blur(v, q["sigma_frac"] * lv["width"])
            for k, v in im.items()}


def _glare_blur(img: np.ndarray, width_px: float) -> np.ndarray:
    """``img`` spread by a unit-sum glare kernel, zero outside the frame: a Gaussian of SD
    ``width_px`` (> 0), or (< 0) a power law (1 + (r / w)^2)^(-3/2) of core w = -width_px: a
    lens's stray light falls off as a power of the angle with a narrow core (inverse-cube
    spread functions, e.g. the CIE 1999 glare spread function's dominant term), which no one
    Gaussian follows both near and far."""
    if width_px > 0:
        return ndimage.gaussian_filter(img, width_px, mode="constant")
    h, w = img.shape
    yy, xx = np.mgrid[-h:h + 1, -w:w + 1]
    kern = (1 + (yy**2 + xx**2) / width_px**2) ** -1.5
    return signal.fftconvolve(img, kern / kern.sum(), mode="same")


def _apply_vignetting(lv, im, q):
    rho2 = lv["rho2"]
    return {k: v * (1 - q["c"] * rho2 - q.get("c2", 0.0) * rho2**2) for k, v in im.items()}


def _apply_misregistration(lv, im, q):
    dy, dx = q["shift_px"].get(lv["name"], (0.0, 0.0))
    d, s, b = _shift_scene(lv, [im["D"], im["S"], im["B"]], dy, dx)
    return {"D": d, "S": s, "B": b}


def _coverage(shape, cy: float, cx: float, radius: float, n: int = 8) -> np.ndarray:
    """Share of each pixel (centres at integers) inside the sphere's silhouette (n x n
    sub-pixels)."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    offs = (np.arange(n) + 0.5) / n - 0.5
    cover = np.zeros(shape)
    for oy in offs:
        for ox in offs:
            cover += ((yy + oy - cy) ** 2 + (xx + ox - cx) ** 2) < radius**2
    return cover / n**2


def _fill(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``values`` with the pixels outside ``known`` set to their nearest known pixel's."""
    if known.all() or not known.any():
        return values
    idx = ndimage.distance_transform_edt(~known, return_distances=False, return_indices=True)
    return values[tuple(idx)]


def _shift_scene(lv: dict, images: list, dy: float, dx: float) -> list:
    """Diffuse, specular and background images of the scene shifted by (dy, dx) px.

    A pixel on the silhouette mixes the sphere and the background by the share it covers; a
    shift changes that share as geometry, not as an interpolation of a step. So each image is
    split into radiance (sphere parts: image / coverage; background: image / (1 - coverage),
    edge pixels filled from their nearest well-covered neighbour), the radiance shifted by
    cubic-spline interpolation, and the shares recomputed at the shifted silhouette."""
    cy, cx, radius = lv["geometry"]
    cov = lv["cover"]
    cov_s = _coverage(cov.shape, cy + dy, cx + dx, radius)
    out = []
    for k, img in enumerate(images):
        share, share_s = (cov, cov_s) if k < 2 else (1 - cov, 1 - cov_s)
        known = share > 0.5
        rad = _fill(np.where(known, img / np.maximum(share, 1e-6), 0.0), known)
        out.append(share_s * ndimage.shift(rad, (dy, dx), order=3, mode="nearest"))
    return out


def _predict(lv: dict, fitted: list) -> np.ndarray:
    """The extended render: the Ward fit's diffuse and specular scales re-fitted with the
    extension (``scale`` of the last fitted step, per level; 1 for the plain render)."""
    D, S, B = _basis(lv, fitted)
    scale = next((q["scale"] for _, q in reversed(fitted) if "scale" in q), {})
    a, b = scale.get(lv["name"], (1.0, 1.0))
    return B + a * D + b * S


def render_loss(data: RenderData, fitted: list) -> np.ndarray:
    """Per-pixel Gaussian NLL (nats) on the view's pixels, levels concatenated."""
    out = []
    for lv in data.levels:
        m = lv["use"]
        r = (lv["P"] - _predict(lv, fitted))[m]
        sd = lv["sd"][m]
        out.append(0.5 * np.log(2 * np.pi * sd**2) + 0.5 * (r / sd) ** 2)
    return np.concatenate(out)


def render_floor(data: RenderData) -> np.ndarray:
    return np.concatenate([0.5 * np.log(2 * np.pi * lv["sd"][lv["use"]] ** 2) + 0.5
                           for lv in data.levels])


#: Widths (px) of the ceiling's local smooth, chosen by cross-validation per level.
_CEIL_SIGMAS_PX = (0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0)


def _local_mean(res: np.ndarray, w: np.ndarray, sigma: float) -> np.ndarray:
    """Normalised convolution: the ``w``-weighted Gaussian local mean of ``res`` (0 where no
    weight reaches)."""
    num = ndimage.gaussian_filter(res * w, sigma, mode="constant")
    den = ndimage.gaussian_filter(w, sigma, mode="constant")
    return np.where(den > 1e-12 * max(float(w.max()), 1e-30), num / np.maximum(den, 1e-300), 0.0)


def render_ceiling(train: RenderData, test: RenderData, fitted=()) -> np.ndarray:
    """Held-out loss of a flexible data-driven model of the photos: the ceiling.

    Per gloss level, the residual of the render extended by ``fitted`` (the chosen
    candidates, fitted on the training pixels; none: the plain render B + D + S) is smoothed
    locally over the training pixels (a Gaussian local mean weighted by 1 / sd^2, i.e.
    normalised convolution) and added to that render at the held-out pixels. Any systematic
    structure larger than the smooth's width that the render leaves (a texture, an
    anisotropic highlight, a second light, an effect outside the catalogue) is fitted by it.
    Starting from the chosen model, not the plain render, matters when a catalogue effect
    leaves sharp structure (a shift, a Fresnel rim) that a local smooth cannot follow: the
    plain render's smooth then falls behind the chosen model and hides what remains beside
    it. The width is chosen per level from ``_CEIL_SIGMAS_PX`` by two-fold cross-validation
    within the training pixels (rows of 4 px blocks alternating between the folds).

    Returns
    -------
    ndarray
        Gaussian NLL (nats) per held-out pixel, in :func:`render_loss`'s order.
    """
    out = []
    for lt, le in zip(train.levels, test.levels):
        r0 = _predict(lt, list(fitted))
        res = lt["P"] - r0
        w = np.where(lt["use"], 1 / lt["sd"] ** 2, 0.0)
        yy = np.mgrid[0:res.shape[0], 0:res.shape[1]][0]
        fold = (yy // _BLOCK) % 2 == 0
        best = None
        for sigma in _CEIL_SIGMAS_PX:
            err = 0.0
            for f in (fold, ~fold):
                pred = _local_mean(res, np.where(f, w, 0.0), sigma)
                err += float(np.sum(np.where(~f, w, 0.0) * (res - pred) ** 2))
            if best is None or err < best[0]:
                best = (err, sigma)
        pred = r0 + _local_mean(res, w, best[1])
        m = le["use"]
        sd = le["sd"][m]
        z = (le["P"] - pred)[m] / sd
        out.append(0.5 * np.log(2 * np.pi * sd**2) + 0.5 * z**2)
    return np.concatenate(out)


def render_where(fits: list) -> str:
    """Words for where the chosen model falls short of the ceiling: the gloss level and the
    region of the sphere (highlight, body, rim, background) that carry most of the held-out
    excess loss, whether the photo is brighter or darker than the extended render there, and
    that cell's share of the excess. The misfit's size is :func:`render_misfit_pct`'s.

    ``fits``: ``[(train, test, fitted, ceiling_loss), ...]`` per fold (see
    engine.diagnose_losses; ``ceiling_loss`` from `render_ceiling`, in `render_loss`'s order).
    """
    cells: dict = {}
    for _train, test, fitted, ceiling_loss in fits:
        excess = render_loss(test, list(fitted)) - ceiling_loss
        start = 0
        for lv in test.levels:
            m = lv["use"]
            n = int(m.sum())
            ex = excess[start:start + n]
            res = (lv["P"] - _predict(lv, list(fitted)))[m]
            start += n
            for reg in REGIONS:
                r = lv["regions"][reg][m]
                if r.any():
                    c = cells.setdefault((lv["name"], reg), [0.0, 0.0])
                    c[0] += float(ex[r].sum())
                    c[1] += float(res[r].sum())
    total = sum(max(v[0], 0.0) for v in cells.values())
    if not cells or total <= 0:
        return ""
    (name, reg), (ex, res) = max(cells.items(), key=lambda kv: kv[1][0])
    side = "brighter" if res > 0 else "darker"
    return (f"mostly in the {reg} of level {name} (the photo {side} than the extended render "
            f"there; {100 * max(ex, 0.0) / total:.0f} % of the excess)")


#: Distance (px) between the held-out pixels whose residuals' products size the misfit (see
#: render_misfit_pct): 2, past the noise shared by immediate neighbours.
_SIZE_LAG_PX = 2


def render_misfit_pct(fits: list) -> float:
    """Size of what the chosen model leaves, in the photos' own units: its RMS systematic
    misfit on the held-out pixels, in % of the photos' RMS luminance.

    Per fold and level, the chosen model's residual at each held-out pixel is multiplied by
    the residual at the held-out pixels :data:`_SIZE_LAG_PX` to its right and below: noise
    independent between pixels that far apart drops out of the products' mean, which is the
    misfit's square, m_i m_j, with no noise model needed; for a misfit wider than a few px
    m_i m_j ~ m^2 (stripes of 16 px period keep 85 % of their square). Immediate neighbours
    share noise wherever a pixel's value is spread over its neighbours (Mitsuba's
    reconstruction filter in the renders, a camera's demosaicing): on the demo's photos
    against their low-spp Ward renders, shifted by the misregistration step, products at 1 px
    gave 4.5 %, at 2 px 1.5 %, at 3 px 0 %. Sizing from the excess loss over the ceiling
    instead (m^2 = 2 sd^2 x excess) underestimated known stripes of 0.96 % RMS as 0.82 %
    and 0.38 % as 0.23 %: the ceiling's own estimation noise and its cross-validated width
    both lower the excess. A negative mean (noise only) counts as none. Nats per pixel scale
    with how clean the photos are; this does not, so it can be held to a tolerance (the
    design's [gap] render_tolerance_pct).

    ``fits``: as :func:`render_where`'s.
    """
    cross = pairs = sq_photo = n_pixels = 0.0
    for _train, test, fitted, _ in fits:
        for lv in test.levels:
            m = lv["use"]
            res = np.where(m, lv["P"] - _predict(lv, list(fitted)), 0.0)
            k = _SIZE_LAG_PX
            for a, b, both in ((res[:, :-k], res[:, k:], m[:, :-k] & m[:, k:]),
                               (res[:-k, :], res[k:, :], m[:-k, :] & m[k:, :])):
                cross += float(np.sum((a * b)[both]))
                pairs += float(both.sum())
            sq_photo += float(np.sum(lv["P"][m] ** 2))
            n_pixels += float(m.sum())
    if sq_photo <= 0 or pairs == 0:
        return float("nan")
    return float(100 * np.sqrt(max(cross / pairs, 0.0) / (sq_photo / n_pixels)))


def render_unit_ids(data: RenderData) -> list[str]:
    """Pixel names ``level|y|x``."""
    ids = []
    for lv in data.levels:
        ys, xs = np.nonzero(lv["use"])
        ids += [f"{lv['name']}|{y}|{x}" for y, x in zip(ys, xs)]
    return ids


def split_render(data: RenderData, rng: np.random.Generator):
    """Held-out pixels: a checkerboard of 4 x 4 px blocks (``rng`` unused: fixed split)."""
    return data.view("train"), data.view("test")


def _scaled_fit(train: RenderData, fitted: list) -> tuple[list, dict]:
    """Weighted residuals per level with the diffuse and specular scales re-fitted per level
    (least squares), and the scales."""
    residuals, scale = [], {}
    for lv in train.levels:
        m = lv["use"]
        D, S, B = _basis(lv, fitted)
        w = 1 / lv["sd"][m]
        a = np.c_[D[m], S[m]] * w[:, None]
        y = (lv["P"] - B)[m] * w
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        scale[lv["name"]] = (float(coef[0]), float(coef[1]))
        residuals.append(y - a @ coef)
    return residuals, scale


def _scaled_sse(train: RenderData, fitted: list):
    """Weighted SSE with the diffuse and specular scales re-fitted per level (least squares)."""
    residuals, scale = _scaled_fit(train, fitted)
    return sum(float(np.sum(r**2)) for r in residuals), scale


def _scaled_residuals(train: RenderData, fitted: list) -> np.ndarray:
    """The weighted residuals behind :func:`_scaled_sse` (scales re-fitted per level)."""
    return np.concatenate(_scaled_fit(train, fitted)[0])


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
    re-fitted."""
    def fit(train, chosen):
        base = [f for f in chosen if f[0] != name]

        def params_of(c, g):
            if key is None:
                return {"c": c}
            return {key: g if isinstance(g, str) else float(g), "c": c}
        c, g = _best_on_grid(
            lambda c, g: _scaled_sse(train, base + [(name, params_of(c, g))])[0], lo, hi, grid)
        params = params_of(c, g)
        params["scale"] = _scaled_sse(train, base + [(name, params)])[1]
        return params
    return fit


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
        name, one = lv["name"], RenderData([lv])
        c, g = _best_on_grid(lambda c, g, name=name, one=one: _scaled_sse(
            one, base + [("long_tail", {"c": {name: c}, "width": {name: g}})])[0],
            0.0, 1.0, _TAIL_WIDTHS + tuple(lv.get("wider", {})))
        cs[name], widths[name] = c, g if isinstance(g, str) else float(g)
    params = {"c": cs, "width": widths}
    params["scale"] = _scaled_sse(train, base + [("long_tail", params)])[1]
    return params


# --- the catalogue: each effect's fit, term, injector, default strength and truth -----------
# An injector makes the photo's noiseless luminance of one gloss level with the effect:
# ``inject(studio, level, strength, rng)``. ``studio`` is the benchmark's renderer (Mitsuba
# scenes of the gloss fit's sphere, analysis.gap.inject): ``level(k)`` -> (rho_d, rho_s,
# alpha), ``base(k)`` -> the plain diffuse and specular renders, ``background(shift)``,
# ``render(material, seed, shift)``, ``ward(...)``, ``rgb(v)``, ``sphere_r()``,
# ``mean_ratio(a, b, where)``, ``plain(k)`` (background + diffuse + specular). The effect is
# built into the material or the camera with Mitsuba's own plugins, never with the forms
# above.

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


# Registered in the order their terms apply (_basis): the material's terms on the specular
# and diffuse components, then the camera's glare and vignetting, then the shift.
register("render", Candidate(
    "fresnel", _fit_amp("fresnel", 0.0, 50.0, "kappa", _FRESNEL_CAPS),
    "specular reflectance rising towards grazing angles (Schlick)", apply=_apply_fresnel,
    inject=_inject_fresnel, default_strength=6.0, units="Schlick gain (1 - F0) / F0",
    truth=lambda s: {"c": float(s)}))
register("render", Candidate(
    "long_tail", _fit_long_tail, "highlight lobe with longer tails than Ward's",
    apply=_apply_long_tail, inject=_inject_long_tail, default_strength=0.6,
    units="share of the lobe's energy in the haze",
    # The amount per level; the form (blur or power) has no counterpart in the injector.
    truth=lambda s: {"c": float(s)}))
register("render", Candidate(
    "clearcoat", _fit_amp("clearcoat", 0.0, 1.0, "entry", _COAT_ENTRY),
    "diffuse light leaving through a clear coat, dimmed towards grazing view (Fresnel)",
    apply=_apply_clearcoat, inject=_inject_clearcoat, default_strength=0.6,
    units="share of the diffuse light through the coat", truth=lambda s: {"c": float(s)}))
register("render", Candidate(
    "veiling_glare", _fit_amp("veiling_glare", 0.0, 1.0, "sigma_frac", _GLARE_SIGMAS),
    "lens glare: a blurred copy of the image added", apply=_apply_glare,
    inject=_inject_glare, default_strength=0.15, units="share of the light in the glare",
    truth=lambda s: {"c": float(s)}))
register("render", Candidate(
    "vignetting", _fit_vignetting, "the camera darkens towards the image corners",
    apply=_apply_vignetting, inject=_inject_vignetting, default_strength=0.5,
    units="vignetting coefficient",
    # 1 / (1 + (s rho)^2)^2 = 1 - 2 s^2 rho^2 + O(rho^4).
    truth=lambda s: {"c": 2 * float(s) ** 2}))
register("render", Candidate(
    "misregistration", _fit_misregistration, "photo and render still offset after registration",
    apply=_apply_misregistration, inject=_inject_misregistration, default_strength=0.6,
    units="px", truth=lambda s: {"shift_norm_px": float(s)}))

RENDER_CANDIDATES = catalogue("render")


def localise_render(data: RenderData, rng: np.random.Generator,
                    n_boot: int = 500) -> pd.DataFrame:
    """Mean residual (photo - render, % of the level's mean sphere luminance) per region and
    gloss level, 95 % CIs by a bootstrap over 4 x 4 px blocks (pixels within a block are not
    independent)."""
    rows = []
    for lv in data.levels:
        R = lv["B"] + lv["D"] + lv["S"]
        sph = lv["regions"]["highlight"] | lv["regions"]["body"] | lv["regions"]["rim"]
        scale = float(np.mean(lv["P"][sph])) if sph.any() else 1.0
        res = 100 * (lv["P"] - R) / max(scale, 1e-12)
        h, w = res.shape
        yy, xx = np.mgrid[0:h, 0:w]
        block = (yy // _BLOCK) * (w // _BLOCK + 1) + xx // _BLOCK
        for reg in REGIONS:
            m = lv["regions"][reg]
            if not m.any():
                continue
            frame = pd.DataFrame({"b": block[m], "r": res[m]})
            sums = frame.groupby("b")["r"].agg(["sum", "size"]).to_numpy()
            idx = rng.integers(0, len(sums), (n_boot, len(sums)))
            boot = sums[idx, 0].sum(axis=1) / sums[idx, 1].sum(axis=1)
            lo, hi = np.percentile(boot, [2.5, 97.5])
            rows.append({"axis": "region", "cell": f"{lv['name']}: {reg}", "n": int(m.sum()),
                         "mean_residual": float(res[m].mean()), "ci_low": float(lo),
                         "ci_high": float(hi), "unit": "% of mean sphere luminance"})
    return pd.DataFrame(rows)


def residual_maps(data: RenderData, fitted: list) -> dict:
    """Residual maps in noise SDs, (photo - render) / sd, per gloss level: of the plain render
    and of the render extended by ``fitted`` (the diagnosis's chosen steps, parameters as in
    ``Diagnosis.steps``). NaN outside the pixels the loss uses (the sphere's valid pixels).

    Returns
    -------
    dict
        ``{level name: {"photo": P, "before": z, "after": z}}``, each (h, w) float.
    """
    out = {}
    for lv in data.levels:
        valid = lv["fit"]
        maps = {"photo": lv["P"]}
        for key, steps in (("before", []), ("after", fitted)):
            z = (lv["P"] - _predict(lv, steps)) / lv["sd"]
            maps[key] = np.where(valid, z, np.nan)
        out[lv["name"]] = maps
    return out
