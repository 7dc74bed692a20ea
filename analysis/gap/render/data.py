"""The render layer's input: the gloss fit's residual files and fit.json, read and checked.

:func:`load_render` reads ``OUT_DIR/residuals/*.npz`` (photos from REAL, renders and their
components from SIM) into :class:`RenderData`, one dict per gloss level in Rec. 709 luminance,
with what the candidates' forms need computed once here: the sphere's centre and radius from
its mask, the view cosine and the sub-pixel Fresnel and coat factors (``_subpixel_factors``),
the camera's distance from fit.json's setup (``_camera_distance``, checked), normals and view
directions (``_sphere_view``), the coat's entry factors from the lights fitted to the diffuse
shading (``_coat_lights``) or seen in the glossiest level's specular render (``_mirror_light``,
``_coat_mirror``), the less glossy levels' lobes on each level's sphere (``_aligned_lobe``),
the photo's noise (``model.noise_model``) and the checkerboard of held-out blocks.
"""

from __future__ import annotations

import functools
import json
import re
from pathlib import Path

import numpy as np
from scipy import ndimage, optimize

from analysis.gap.engine import GapError
from analysis.gap.render.optics.sphere import (
    _coat_entry_ratios,
    _coat_t,
    _fill,
    _sharpness,
    _unit_at_centre,
    noise_model,
    noise_sd,
    ward_lobe,
)
from studydesign import rec709_luminance

NPZ_ARRAYS = ("photo", "render", "diffuse", "specular")
NPZ_MASKS = ("highlight", "body", "rim", "background", "sphere")
REGIONS = ("highlight", "body", "rim", "background")
_BLOCK = 4
#: Caps kappa on the view cosine of the Fresnel rise (a grid; 0 = plain Schlick at the view
#: angle): near the silhouette the lobe's reflected directions that fall below the horizon do
#: not reflect, so the half vectors that do tilt towards the camera and the rise saturates.
_FRESNEL_CAPS = (0.0, 0.15, 0.3)
_COAT_PATHS = {"surround": 1.0, "view": 2.0}  # passes through the coat at the view angle
#: The coat's key light (see _fit_shading): a round lamp of half-angle up to 40 deg, drawn as
#: this many directions.
_KEY_MAX_RAD, _KEY_SAMPLES = 0.7, 48
#: The 'mirror' coat entry (see _mirror_light, _coat_mirror): at most about this many light
#: directions, and pixels summed over in blocks of this many (memory: 8 bytes x the product).
_MIRROR_LIGHTS, _MIRROR_CHUNK = 4096, 1024
#: Widths (Ward alpha) of the broad_lobe candidate's second lobe under directional lights, a
#: grid: broad (a resin's haze), or sharp where the fitted lobe took the broad light.
BROAD_ALPHAS = (0.05, 0.1, 0.15, 0.25, 0.4, 0.6, 0.9, 1.3)


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
            levels.append(make_level(f.stem, {k: a[k] for k in a.files},
                                     {k: b[k] for k in b.files}, distance))
    return _across_levels(levels)


def load_lighting(real, sim, lighting: str) -> tuple[RenderData, RenderData, str]:
    """(train, test, split in words) of a panorama fit of one lighting (SIM) with REAL's
    photos in another, ``lighting``, held out (:mod:`stimuli.glossfit.lightings`): train =
    SIM's fitted pixels, test = the held-out photos against the fitted levels rendered in
    that lighting's panorama, by the same level names (per-level terms carry over)."""
    from stimuli.glossfit import GlossFitError, predict_lighting

    try:
        held = predict_lighting(sim, real, lighting)
    except (GlossFitError, ValueError, OSError) as exc:
        raise GapError(str(exc)) from None
    distance = _camera_distance(Path(sim))
    test = [make_level(name, a, a, distance) for name, a in held.items()]
    for lv in test:
        lv["train"] = np.zeros_like(lv["fit"])
    fitted = json.loads((Path(sim) / "fit.json").read_text())["lighting"]
    return load_render(sim, sim), _across_levels(test), f"held-out lighting {lighting} (fit: {fitted})"


def _across_levels(levels: list[dict]) -> RenderData:
    """The levels with what each takes from the others: the long tail's wings may borrow the
    lobe of any less glossy level (see _wider_lobe), brought onto this level's sphere; the
    coat's mirror entry from the glossiest level's view of the room."""
    sharp = {lv["name"]: _sharpness(lv) for lv in levels}
    for lv in levels:
        lv["wider"] = {o["name"]: _aligned_lobe(o, lv) for o in levels
                       if sharp[o["name"]] < sharp[lv["name"]]}
    light = _mirror_light(max(levels, key=_sharpness))
    for lv in levels:
        lv["coat"]["mirror"] = _coat_mirror(light, lv)
    return RenderData(levels)


def make_level(name: str, a: dict, b: dict, distance: float | None = None, *,
               coat_lights: bool = True) -> dict:
    """One level's dict (:class:`RenderData`) from a residual file's arrays: the photo and
    masks from ``a`` (REAL's), the render's components from ``b`` (SIM's). ``coat_lights``:
    fit the coat's lights to the diffuse shading (a panorama's levels; a directional light's
    level knows its light, :mod:`analysis.gap.render.lights`)."""
    need = [k for k in ("photo", *NPZ_MASKS) if k not in a]
    need += [f"{k} (sim)" for k in ("render", "diffuse", "specular") if k not in b]
    if need:
        raise GapError(f"{name}: arrays {need} missing; the residual files need "
                       f"{NPZ_ARRAYS} and masks {NPZ_MASKS}")
    P = _lum(a["photo"])
    D, S = _lum(b["diffuse"]), _lum(b["specular"])
    # The fit's render is B + D + S, B the panorama around the (black) sphere: it
    # reaches into the rim's edge pixels, which the sphere covers only in part.
    B = _lum(b["render"]) - D - S
    masks = {k: np.asarray(a[k], bool) for k in NPZ_MASKS}
    valid = np.asarray(a["valid"], bool) if "valid" in a else np.isfinite(P)
    if P.shape != D.shape:
        raise GapError(f"{name}: photo {P.shape} and render {D.shape} differ in size")
    h, w = P.shape
    sph = masks["sphere"]
    if sph.sum() < 20:
        raise GapError(f"{name}: the sphere mask has {int(sph.sum())} pixels (< 20)")
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    cy, cx = yy[sph].mean(), xx[sph].mean()
    # The fit's sphere mask stops 1 px inside the silhouette.
    radius = np.sqrt(sph.sum() / np.pi) + 1.0
    r = np.hypot(yy - cy, xx - cx) / radius
    cos_t = np.sqrt(np.clip(1 - r**2, 0.0, 1.0))
    fres5, coat, cover = _subpixel_factors((h, w), float(cy), float(cx), float(radius))
    fres5, coat = dict(fres5), dict(coat)
    if coat_lights:
        coat["lights"] = _coat_lights(D, S, coat["surround"], (yy - cy) / radius,
                                      (xx - cx) / radius, cover, distance)
    rho2 = ((yy - (h - 1) / 2) ** 2 + (xx - (w - 1) / 2) ** 2) / ((h / 2) ** 2 + (w / 2) ** 2)
    fit = valid & (masks["highlight"] | masks["body"] | masks["rim"]) & np.isfinite(P)
    train = ((yy // _BLOCK + xx // _BLOCK) % 2 == 0)
    m = re.search(r"(\d+(?:\.\d+)?)", name)
    R0 = B + D + S
    noise = noise_model(P - R0, R0, valid & sph)
    for image in (P, B, D, S):  # never changed: the fits' blurs remember them by identity
        image.flags.writeable = False
    return {"name": name, "gloss": float(m.group(1)) if m else np.nan,
            "P": P, "B": B, "D": D, "S": S, "cos_t": cos_t, "fres5": fres5,
            "coat": coat, "cover": cover, "rho2": rho2,
            "geometry": (cy, cx, radius), "distance": distance,
            "regions": {k: masks[k] & valid for k in REGIONS}, "fit": fit,
            "train": train, "use": fit, "width": w,
            "noise": noise, "sd": noise_sd(R0, *noise)}


def load_lights(real, sim, lights=None) -> tuple[RenderData, RenderData, str]:
    """(train, test, split in words) of a directional-light fit (SIM; None: REAL). With
    ``lights``: train = SIM's fitted pixels, test = REAL's (the photo set's) photos under
    ``lights`` against the fitted material rendered there. Without: each fitted light's photo
    split into a checkerboard of 4 x 4 px blocks. GapError: no such fit, a fitted light held
    out, a bad photo set."""
    from stimuli.glossfit import GlossFitError, predict_lights, read_light_fit

    sim = Path(sim if sim is not None else real)
    try:
        info = read_light_fit(sim)
        fitted = []
        for f in sorted((sim / "residuals").glob("light_*.npz")):
            with np.load(f) as a:
                fitted.append(_light_level(f.stem, {k: a[k] for k in a.files}))
        if lights is None:
            data = RenderData(fitted)
            return data.view("train"), data.view("test"), "checkerboard of 4 x 4 px blocks"
        test = [_light_level(f"light_{k:03d}", a, held_out=True)
                for k, a in predict_lights(sim, real, lights).items()]
    except (GlossFitError, ValueError) as exc:
        raise GapError(str(exc)) from None
    split = (f"held-out lights {', '.join(lv['name'][6:].lstrip('0') for lv in test)} (the "
             f"fit's lights: {', '.join(str(k) for k in info['lights'])})")
    return RenderData(fitted), RenderData(test), split


def _light_level(name: str, arrays: dict, held_out: bool = False) -> dict:
    """A level under one directional light: :func:`make_level`'s with the light, the normals
    (3, h, w), shared scales, the coat's exact entry T(n.l) beside its exit (mean 1 within 0.3
    radii of the centre) and the broad lobes (``rho_d f n.l = pi D f``, per BROAD_ALPHAS);
    every fitted pixel used (``held_out``: as the test)."""
    if "light" not in arrays or "normals" not in arrays:
        raise GapError(f"{name}: no light or normals in the residual file; fit the set with "
                       "python -m stimuli fit-gloss SET --lights 1-24 --out FIT")
    lv = make_level(name, arrays, arrays, None, coat_lights=False)
    if held_out and "shadow" in arrays:  # sized over the unlit pixels too (sized_pixels)
        lv["sized"] = lv["fit"] | (np.asarray(arrays["shadow"], bool) & np.isfinite(lv["P"]))
    lv["light"] = light = np.asarray(arrays["light"], float)
    lv["normals"] = n = np.moveaxis(np.asarray(arrays["normals"], float), -1, 0)
    lv["shared"], lv["wider"], lv["use"] = True, {}, lv["fit"]
    ndl = np.tensordot(light, n, axes=([0], [0]))
    cy, cx, radius = lv["geometry"]
    yy, xx = np.mgrid[0:ndl.shape[0], 0:ndl.shape[1]].astype(float)
    r2 = ((yy - cy) ** 2 + (xx - cx) ** 2) / radius**2
    lv["coat"]["lights"] = lv["coat"]["mirror"] = _unit_at_centre(
        lv["coat"]["surround"] * _coat_t(np.clip(ndl, 0.0, 1.0)), r2, lv["cover"] > 0)
    per_ndl = np.pi * np.where(lv["D"] > 0, lv["D"], 0.0) / np.where(ndl > 1e-6, ndl, 1.0)
    lv["lobes"] = {a: per_ndl * ward_lobe(n, light, a) for a in BROAD_ALPHAS}
    if held_out:
        lv["train"] = np.zeros_like(lv["fit"])
    return lv


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


@functools.lru_cache(maxsize=8)
def _subpixel_factors(shape: tuple, cy: float, cx: float, radius: float, n: int = 8):
    """Per-pixel means of the Fresnel rise (1 - max(cos t, kappa))^5 (one image per kappa of
    ``_FRESNEL_CAPS``) and of the coat's transmission T(t) / T(0) over the part of each pixel
    the sphere covers (n x n sub-pixels): at the rim cos t changes steeply within one pixel,
    and the pixel's value averages it. Also returns the covered share of each pixel. Computed
    once per sphere (a set under many lights shows one): the images are read-only, and the
    caller copies the dicts before adding to them."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
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
    out = ({k: v / cover for k, v in fres.items()}, {k: v / cover for k, v in coat.items()},
           share)
    for image in (*out[0].values(), *out[1].values(), share):
        image.flags.writeable = False
    return out


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
