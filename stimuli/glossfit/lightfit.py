"""The gloss fit on a directional-light photo set: Ward parameters from some lights' photos,
through Mitsuba renders of the sphere under each light.

For each light k, Mitsuba renders the sphere (the ``ward`` plugin, an orthographic camera, a
directional emitter of unit irradiance along the light, the ``direct`` integrator) once with
``rho_d = 1, rho_s = 0`` (D_k) and once per lobe width with ``rho_d = 0, rho_s = 1``
(S_k(alpha)); renders are linear in the albedos (fixed lobe choice, one sampler seed), so the
photo's luminance L_k (each channel divided by the light's RGB intensity) is fitted as
``rho_d D_k + rho_s S_k(alpha)``: albedos by non-negative least squares over all fit lights
at once, alpha by a log-spaced scan and Brent's method in the best bracket. Pixels fitted:
inside the mask 1 px in from its edge, unsaturated in every channel, with n.l above
``min_cos`` (0.1: the terminator, where a real surface's shadowing and interreflection rule,
is left out).

``python -m stimuli fit-gloss BALL_DIR --lights 1-24 --out FIT`` writes::

    FIT/fit.json                 kind "lights", the photo set, the lights fitted, Ward's rho_d,
                                 rho_s (photo units per unit irradiance), alpha, the geometry,
                                 render settings, the in-sample misfit (% RMS), warnings
    FIT/residuals/light_NNN.npz  per fit light, the render layer's format (stimuli.glossfit.output)
                                 plus ``normals`` (h x w x 3) and ``light`` (3,)
    FIT/figures/light_NNN.png    photo | render | residual
    FIT/report.html

:func:`predict_lights` renders the fitted material under other lights of a set (the render
layer's held-out lights).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from scipy import ndimage, optimize

from stimuli.glossfit.lightset import LightSet, load_light_set, refuse_over_exposed
from stimuli.glossfit.output import write_json, write_level_figure, write_residuals
from stimuli.glossfit.photoset import GlossFitError
from stimuli.glossfit.scene import FIT_LOBE_PROBABILITY

__all__ = ["LightScene", "fit_lights", "light_arrays", "predict_lights"]

#: What fit_lights writes into its output folder.
OUTPUT_NAMES = ("fit.json", "residuals", "figures", "report.html")


class LightScene:
    """Mitsuba renders of the photo set's sphere under one directional light at a time.

    Parameters
    ----------
    shape : (h, w)
        The photos' size (px); renders match them pixel for pixel.
    geometry : (cy, cx, radius)
        The silhouette's centre and radius in photo pixels (y down).
    spp : int
        Samples per pixel (a square; anti-aliasing only: the light is a delta).
    seed : int
        Sampler seed of every render.
    """

    def __init__(self, shape, geometry, *, spp: int = 4, seed: int = 0) -> None:
        from stimuli.glossfit.mitsuba_setup import mitsuba, use_fit_variant

        self._mi = mitsuba()
        self._before = use_fit_variant()
        self.shape, self.geometry = tuple(shape), tuple(geometry)
        self.spp, self.seed = int(np.ceil(np.sqrt(spp)) ** 2), int(seed)
        self._scenes: dict = {}
        self.n_renders = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self._scenes.clear()
        if self._before is not None and self._mi.variant() != self._before:
            self._mi.set_variant(self._before)

    def _dict(self, light) -> dict:
        """The scene of the sphere (Ward, rho_d 1) under ``light`` as a Mitsuba dict."""
        mi = self._mi
        key = [float(v) for v in np.asarray(light, float)]
        h, w = self.shape
        cy, cx, radius = self.geometry
        half = w / 2 / radius  # the film's half width in sphere radii
        cam = (mi.ScalarTransform4f().look_at(origin=[0, 0, 10], target=[0, 0, 0],
                                              up=[0, 1, 0])
               @ mi.ScalarTransform4f().scale([half, half, 1]))
        return {
            "type": "scene",
            "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
            "sensor": {"type": "orthographic", "to_world": cam,
                       "film": {"type": "hdrfilm", "width": w, "height": h,
                                "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                       "sampler": {"type": "multijitter", "sample_count": self.spp}},
            "light": {"type": "directional", "direction": [-v for v in key],
                      "irradiance": 1.0},
            "sphere": {"type": "sphere", "radius": 1.0,
                       "center": [(cx - w / 2) / radius, -(cy - h / 2) / radius, 0.0],
                       "bsdf": {"type": "ward", "rho_d": 1.0, "rho_s": 0.0, "alpha": 0.1,
                                "lobe_probability": FIT_LOBE_PROBABILITY}}}

    def _scene(self, light):
        key = tuple(np.round(np.asarray(light, float), 9))
        if key not in self._scenes:
            scene = self._mi.load_dict(self._dict(key))
            self._scenes[key] = (scene, self._mi.traverse(scene))
        return self._scenes[key]

    def render_material(self, light, bsdf: dict, seed: int | None = None) -> np.ndarray:
        """The sphere with any Mitsuba BSDF ``bsdf`` under ``light`` (a scene of its own,
        not kept): luminance (h, w), y down."""
        mi = self._mi
        scene_dict = self._dict(light)
        scene_dict["sphere"] = dict(scene_dict["sphere"], bsdf=bsdf)
        scene = mi.load_dict(scene_dict)
        self.n_renders += 1
        img = mi.render(scene, seed=self.seed if seed is None else int(seed), spp=self.spp)
        return np.array(img, dtype=np.float64)[..., :3].mean(axis=-1)

    def render(self, light, rho_d: float, rho_s: float, alpha: float) -> np.ndarray:
        """The sphere under ``light`` (unit vector, x right, y up, z to the camera), unit
        irradiance: luminance (h, w), y down."""
        scene, params = self._scene(light)
        for k, v in (("rho_d", rho_d), ("rho_s", rho_s), ("alpha", alpha)):
            params[f"sphere.bsdf.{k}"] = float(v)
        params.update()
        self.n_renders += 1
        img = np.array(self._mi.render(scene, seed=self.seed, spp=self.spp), dtype=np.float64)
        return img[..., :3].mean(axis=-1)


def _fit_pixels(ls: LightSet, k: int, min_cos: float) -> np.ndarray:
    inner = ndimage.binary_erosion(ls.mask)
    return inner & ~ls.saturated[k] & (ls.normals @ ls.directions[k] > min_cos)


def _fit_alpha(lum: list, diffuse: list, spec_of, bounds) -> tuple[float, float, float, float]:
    """(rho_d, rho_s, alpha, sse): albedos by NNLS for each alpha, alpha scanned then refined."""
    y = np.concatenate(lum)
    d = np.concatenate(diffuse)
    cache: dict = {}

    def solve(alpha):
        alpha = round(float(alpha), 6)
        if alpha not in cache:
            a = np.c_[d, np.concatenate(spec_of(alpha))]
            coef, res = optimize.nnls(a, y)
            cache[alpha] = (float(coef[0]), float(coef[1]), float(res**2))
        return cache[alpha]
    scan = np.geomspace(*bounds, 13)
    errs = [solve(a)[2] for a in scan]
    i = int(np.argmin(errs))
    lo, hi = scan[max(i - 1, 0)], scan[min(i + 1, len(scan) - 1)]
    optimize.minimize_scalar(lambda a: solve(a)[2], bounds=(lo, hi), method="bounded",
                             options={"xatol": 1e-4})
    alpha = min(cache, key=lambda a: cache[a][2])
    return (*cache[alpha][:2], alpha, cache[alpha][2])


def light_arrays(ls: LightSet, k: int, scene: LightScene, ward: dict,
                 min_cos: float) -> dict:
    """Light ``k``'s residual-file arrays (the render layer's format) for the fitted ``ward``."""
    light = ls.directions[k]
    diffuse = ward["rho_d"] * scene.render(light, 1.0, 0.0, ward["alpha"])
    specular = ward["rho_s"] * scene.render(light, 0.0, 1.0, ward["alpha"])
    rgb = (lambda a: np.repeat(a[..., None], 3, axis=-1).astype(np.float32))
    cy, cx, radius = ls.geometry
    yy, xx = np.mgrid[0:ls.mask.shape[0], 0:ls.mask.shape[1]] + 0.5
    r = np.hypot(yy - cy, xx - cx) / radius
    sphere = ndimage.binary_erosion(ls.mask)
    valid = _fit_pixels(ls, k, min_cos)
    # The sphere's pixels the fit skips for want of direct light (attached shadow, grazing
    # light): the render predicts them (nearly) dark, so light there -- a floor's bounce, a
    # lens's glare -- is a misfit the gap diagnosis sizes.
    shadow = sphere & ~ls.saturated[k] & ~valid
    inner = sphere & (r < 0.85)
    spec = np.where(inner, specular, 0.0)
    highlight = inner & (spec >= 0.5 * spec.max()) if spec.max() > 0 else np.zeros_like(inner)
    return {"photo": ls.photos[k].astype(np.float32), "render": rgb(diffuse + specular),
            "residual": (ls.photos[k] - (diffuse + specular)[..., None]).astype(np.float32),
            "diffuse": rgb(diffuse), "specular": rgb(specular),
            "highlight": highlight, "body": inner & ~highlight, "rim": sphere & (r >= 0.85),
            "background": ~ls.mask, "sphere": sphere, "valid": valid, "shadow": shadow,
            "normals": ls.normals.astype(np.float32), "light": np.asarray(light, np.float64)}


def _misfit_pct(arrays: list[dict]) -> float:
    """RMS of photo - render luminance over the fit pixels, in % of the photos' RMS there."""
    from stimuli.glossfit.scene import luminance

    res = np.concatenate([luminance(a["photo"] - a["render"])[a["valid"]] for a in arrays])
    lum = np.concatenate([luminance(a["photo"])[a["valid"]] for a in arrays])
    return float(100 * np.sqrt(np.mean(res.astype(float) ** 2) / np.mean(lum.astype(float) ** 2)))


def fit_lights(photo_set_dir, out_dir, lights, *, spp: int = 4, seed: int = 0,
               min_cos: float = 0.1, alpha_bounds=(0.01, 0.6), progress=None) -> dict:
    """Fit Ward's rho_d, rho_s and alpha to the photos under ``lights`` (module docstring).

    Parameters
    ----------
    photo_set_dir : str or Path
        A directional-light photo set (stimuli.glossfit.lightset).
    out_dir : str or Path
        New output folder (none of ``OUTPUT_NAMES`` may exist in it).
    lights : str or tuple of int
        The lights to fit, e.g. ``"1-24"``.
    spp, seed : int
        Samples per pixel and sampler seed of the renders.
    min_cos : float
        Pixels with n.l at or below this are not fitted.
    alpha_bounds : (float, float)
        Range of the lobe width searched.
    progress : callable(str), optional

    Returns
    -------
    dict
        fit.json's contents.

    Raises
    ------
    GlossFitError
        A bad photo set or light list; FileExistsError if ``out_dir`` holds a fit.
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    taken = [n for n in OUTPUT_NAMES if (out / n).exists()]
    if taken:
        raise FileExistsError(f"{out} already holds a fit's output ({', '.join(taken)}); give a "
                              "new output folder (nothing is overwritten)")
    ls = load_light_set(photo_set_dir, lights)
    saturation = refuse_over_exposed(ls)
    with LightScene(ls.mask.shape, ls.geometry, spp=spp, seed=seed) as scene:
        px = {k: _fit_pixels(ls, k, min_cos) for k in ls.lights}
        few = [k for k in ls.lights if px[k].sum() < 20]
        if few:
            raise GlossFitError(f"lights {few} light fewer than 20 usable pixels (n.l > "
                                f"{min_cos}, unsaturated); leave them out of --lights")
        lum = [ls.luminance(k)[px[k]] for k in ls.lights]
        diffuse = [scene.render(ls.directions[k], 1.0, 0.0, 0.1)[px[k]] for k in ls.lights]

        def spec_of(alpha):
            return [scene.render(ls.directions[k], 0.0, 1.0, alpha)[px[k]] for k in ls.lights]
        rho_d, rho_s, alpha, _ = _fit_alpha(lum, diffuse, spec_of, alpha_bounds)
        ward = {"rho_d": rho_d, "rho_s": rho_s, "alpha": alpha}
        warnings = list(ls.warnings) + saturation
        if alpha <= alpha_bounds[0] * 1.001 or alpha >= alpha_bounds[1] * 0.999:
            warnings.append(f"alpha {alpha:.4g} at the search bound {tuple(alpha_bounds)}")
        (out / "residuals").mkdir(parents=True, exist_ok=True)
        (out / "figures").mkdir(exist_ok=True)
        arrays = []
        for k in ls.lights:
            a = light_arrays(ls, k, scene, ward, min_cos)
            stem = f"light_{k:03d}"
            write_residuals(out / "residuals" / f"{stem}.npz", a)
            write_level_figure(out / "figures" / f"{stem}.png", a["photo"], a["render"],
                               a["residual"], a["sphere"], f"light {k}: {ls.names[k]}")
            arrays.append(a)
        n_renders = scene.n_renders
    info = {"kind": "lights", "photo_set": str(Path(photo_set_dir).resolve()),
            "lights": list(ls.lights), "n_lights": ls.n_lights, "ward": ward,
            "ward_units": "photo units (each channel / its light's intensity) per unit "
                          "irradiance; rho_d, rho_s as in stimuli.ward",
            "camera": "orthographic", "geometry_px": dict(zip(("cy", "cx", "radius"),
                                                              ls.geometry)),
            "normals": ls.normals_source, "min_cos": min_cos, "spp": scene.spp, "seed": seed,
            "alpha_bounds": list(alpha_bounds), "saturated_px": {
                str(k): int((ls.saturated[k] & ls.mask).sum()) for k in ls.lights},
            "misfit_pct_fit": _misfit_pct(arrays), "n_renders": n_renders,
            "wall_s": time.perf_counter() - t0, "warnings": warnings}
    write_json(out / "fit.json", info)
    _write_report(out / "report.html", info)
    if progress:
        progress(f"lights {_ranges(ls.lights)}: rho_d {rho_d:.4g} rho_s {rho_s:.4g} alpha "
                 f"{alpha:.4g}; in-sample misfit {info['misfit_pct_fit']:.2f} % "
                 f"({n_renders} renders)")
    return info


def _ranges(lights) -> str:
    """(1, 2, 3, 7) -> '1-3,7'."""
    parts, start = [], None
    for i, k in enumerate(lights):
        if start is None:
            start = k
        if i + 1 == len(lights) or lights[i + 1] != k + 1:
            parts.append(f"{start}-{k}" if k != start else f"{k}")
            start = None
    return ",".join(parts)


def _write_report(path: Path, info: dict) -> None:
    import html

    from stimuli.glossfit.output import _atomic

    w = info["ward"]
    parts = ["<!doctype html><meta charset='utf-8'><title>gloss fit (lights)</title>",
             f"<h1>Gloss fit: {html.escape(info['photo_set'])}</h1>",
             (f"<p>Lights fitted: {_ranges(info['lights'])} of {info['n_lights']}. Ward rho_d "
             f"{w['rho_d']:.4g}, rho_s {w['rho_s']:.4g}, alpha {w['alpha']:.4g} "
             f"({html.escape(info['ward_units'])}); in-sample RMS misfit "
             f"{info['misfit_pct_fit']:.2f} % of the photos' RMS luminance (pixels with n.l &gt; "
             f"{info['min_cos']:g}, unsaturated). Normals: {html.escape(info['normals'])}; "
             f"{info['n_renders']} renders, {info['wall_s']:.1f} s.</p>")]
    if info["warnings"]:
        parts.append("<ul>" + "".join(f"<li>{html.escape(x)}</li>" for x in info["warnings"])
                     + "</ul>")
    parts += [f"<img src='figures/light_{k:03d}.png' width='600'>" for k in info["lights"]]
    _atomic(path, lambda tmp: tmp.write_text("\n".join(parts)))


def read_light_fit(fit_dir) -> dict:
    """A directional-light fit's fit.json; GlossFitError naming the fix when it is none."""
    path = Path(fit_dir) / "fit.json"
    try:
        info = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise GlossFitError(f"{path}: no readable fit.json ({exc}); run python -m stimuli "
                            "fit-gloss BALL_DIR --lights 1-24 --out FIT first") from exc
    if info.get("kind") != "lights":
        raise GlossFitError(f"{path} is a panorama gloss fit, not a directional-light fit; "
                            "held-out lights need python -m stimuli fit-gloss BALL_DIR "
                            "--lights ... --out FIT")
    return info


def _refuse_other_sphere(info: dict, ls: LightSet, fit_dir) -> None:
    """Refuse a fit of another sphere than the photos': its silhouette (fit.json's
    geometry_px) is not theirs within 1 px (or 2 % of the radius). Its albedos are in another
    camera's and exposure's units, its photos of another ball: the misfit would be a verdict
    on nothing."""
    g = info.get("geometry_px") or {}
    fitted = tuple(float(g.get(k, np.nan)) for k in ("cy", "cx", "radius"))
    cy, cx, radius = ls.geometry
    tol = max(1.0, 0.02 * radius)
    if all(abs(a - b) <= tol for a, b in zip(fitted, (cy, cx, radius))):
        return
    show = lambda v: f"centre ({v[0]:.1f}, {v[1]:.1f}) px, radius {v[2]:.1f} px"
    raise GlossFitError(
        f"{fit_dir} was fitted to the sphere of {info.get('photo_set', '?')} ({show(fitted)}), "
        f"but the photos of {ls.folder} show a sphere at {show(ls.geometry)}: a fit of another "
        f"sphere cannot predict these photos. Fit this set's other lights: python -m stimuli "
        f"fit-gloss {ls.folder} --lights LIGHTS --out FIT, then pass --sim FIT")


def predict_lights(fit_dir, photo_set_dir, lights) -> dict[int, dict]:
    """The fitted material (``fit_dir``'s fit.json) under ``lights`` of the photo set: per
    light, the residual-file arrays (:func:`light_arrays`), rendered with the fit's settings.

    Raises
    ------
    GlossFitError
        If ``fit_dir`` is not a directional-light fit, or a light asked for was fitted (a
        held-out light must be one the fit never saw).
    """
    info = read_light_fit(fit_dir)
    ls = load_light_set(photo_set_dir, lights)
    seen = sorted(set(ls.lights) & set(info["lights"]))
    if seen:
        raise GlossFitError(f"lights {seen} were fitted ({fit_dir}); held-out lights must be "
                            f"others, e.g. --lights {_ranges(sorted(set(range(1, ls.n_lights + 1)) - set(info['lights'])))}")
    _refuse_other_sphere(info, ls, fit_dir)
    with LightScene(ls.mask.shape, ls.geometry, spp=info["spp"], seed=info["seed"]) as scene:
        return {k: light_arrays(ls, k, scene, info["ward"], info["min_cos"])
                for k in ls.lights}
