"""Benchmark injectors of the render layer: pseudo-real photos of the gloss spheres with a hidden
effect, rendered with Mitsuba (re-exported by :mod:`analysis.gapbench.inject`).

The diagnosis never imports this module; tests/analysis/gap/test_gap.py and
tests/analysis/gapbench/test_independence.py check the import graph."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.gap import OutOfCatalogue, catalogue
from analysis.gap import effect as _effect
from analysis.gap import register_out_of_catalogue as _register_out
from studydesign import rec709_luminance

__all__ = ["write_fit_setup", "write_light_set_with", "write_render_fit"]


# --- render layer -------------------------------------------------------------------------
# Pseudo-real photos of the gloss spheres rendered with Mitsuba (stimuli.glossfit.SphereScene,
# the gloss fit's own scene: a sphere in the room panorama), written in the gloss fit's
# residual-file format. The sim renders are the plain Ward fit's diffuse and specular basis
# renders; the photos are rendered with the effect built into the material or the camera, with
# Mitsuba's own plugins where it has one, never with the diagnosis's image-space forms:
#
# fresnel         the Ward lobe with a Schlick term on the half vector (plugin ward, fresnel_f0
#                 = 1 / (1 + strength))
# clearcoat       a share ``strength`` of the diffuse light through a clear coat (Mitsuba's
#                 ``plastic``, IOR 1.5: Fresnel on the way in and out, internal reflections)
# long_tail       a share ``strength`` of the lobe's energy moved into a haze: a GGX lobe
#                 (Mitsuba's ``roughconductor``) of 2.5 times the Ward alpha, as in two-lobe
#                 fits of measured gloss (a sharp core and a broad, long-tailed haze)
# vignetting      cos^4-like natural vignetting 1 / (1 + (strength rho)^2)^2 of the photo
# veiling_glare   a long-tailed (Cauchy-like) lens PSF, a share ``strength`` of the light
# misregistration a sub-pixel shift of ``strength`` px in a random direction, rendered (the
#                 camera's principal point moved: every pixel integrates the shifted scene)
# albedo_texture  (outside the catalogue) a surface texture: the diffuse albedo times
#                 1 + strength sin(6 pi u) sin(4 pi v) in the sphere's uv
# anisotropy      (outside the catalogue) the lobe made anisotropic: alpha_u = alpha (1 + s),
#                 alpha_v = alpha / (1 + s) (Beckmann ``roughconductor`` renders, the change only)
#
# The panorama is the synthetic photo sets' room, its lamp softened (Gaussian, 1.5 px) so that
# 4,096 samples per pixel leave Monte-Carlo noise well below the photos' camera noise (1 % of
# the sphere's mean). Photos and sim share the effect-free renders, so effects made in the
# camera carry no render noise at all.

#: (rho_d, rho_s, alpha) of the benchmark's three spheres: the synthetic Ward sets' 20, 50 and
#: 80 % gloss levels (stimuli.glossfit.synth: rho_s = 0.01 + 0.09 g, alpha 0.30 -> 0.04).
_LEVELS = ((0.4, 0.028, 0.200), (0.4, 0.055, 0.110), (0.4, 0.082, 0.060))
_RENDER_SPP = 4096
_SIZE, _PAD = 64, 8  # the residual files' size; rendered 8 px larger, cropped off-centre
_OFFSET = (2, 6)  # crop origin (y, x): the sphere sits off the image centre, as in a fit crop
_SPHERE_RADIUS_PX = 23.0
_PHOTONS, _READ_REL = 10_000.0, 0.003  # 1.04 % noise at the sphere's mean, 4.5 % at 20x it
_base_cache: dict = {}


def _render_camera(shift=(0.0, 0.0)):
    """A camera whose sphere spans 23 px in radius on a 72 px square image, its content
    shifted by ``shift`` (x, y) px."""
    import math

    from stimuli.glossfit import Camera

    size = _SIZE + _PAD
    focal = _SPHERE_RADIUS_PX / math.tan(math.asin(2.0 / 27.5))
    fov = 2 * math.degrees(math.atan(size / 2 / focal))
    return Camera(fov, (size, size), 27.5, 2.0, shift_px=tuple(float(v) for v in shift))


def _render(material: dict, spp: int, seed: int, *, background: bool = False,
            shift=(0.0, 0.0)) -> np.ndarray:
    """Luminance of the sphere with a Mitsuba material, cropped to the residual files' size,
    minus the background (the panorama around a black sphere) unless ``background``."""
    from scipy import ndimage as ndi

    from stimuli.glossfit import SphereScene, room_panorama

    env = ndi.gaussian_filter(room_panorama(), (1.5, 1.5, 0), mode="wrap")
    with warnings.catch_warnings():
        # Dr.Jit warns once a process has traced the Python Ward plugin 1,000 times (a
        # benchmark loads hundreds of scenes); the cost is known (protocol.md, section 4).
        warnings.filterwarnings("ignore", message="The AST-transforming decorator",
                                category=RuntimeWarning)
        with SphereScene(env, _render_camera(shift), spp=spp, seed=seed,
                         bsdf=lambda *_a: material) as scene:
            img = rec709_luminance(scene.render(0.0, 0.0, 0.0))
    img = _crop(img).astype(float)
    return img if background else img - _background(spp, shift)


def _background(spp: int, shift=(0.0, 0.0)) -> np.ndarray:
    """B: the render of a black sphere (cached per process and camera shift)."""
    shift = tuple(float(v) for v in shift)
    key = ("B", spp) if shift == (0.0, 0.0) else ("B", spp, shift)
    if key not in _base_cache:
        _base_cache[key] = _render(_ward(0.0, 0.0, 0.1), spp, 7, background=True, shift=shift)
    return _base_cache[key]


def _ward(rho_d, rho_s, alpha, **extra):
    return {"type": "ward", "rho_d": rho_d, "rho_s": rho_s, "alpha": alpha,
            "lobe_probability": 0.5, **extra}


def _rgb(v):
    return {"type": "rgb", "value": float(v)}


def _base(level: int, spp: int) -> tuple[np.ndarray, np.ndarray]:
    """The plain Ward fit's diffuse and specular renders of one level, each minus the
    background (cached per process)."""
    key = (level, spp)
    if key not in _base_cache:
        rho_d, rho_s, alpha = _LEVELS[level]
        _base_cache[key] = (_render(_ward(rho_d, 0.0, alpha), spp, 11 + level),
                            _render(_ward(0.0, rho_s, alpha), spp, 21 + level))
    return _base_cache[key]


def write_fit_setup(folder: Path) -> None:
    """The gloss fit's ``fit.json`` for the studio's renders, holding what a fit records of its
    photo set's setup (camera distance and sphere radius, cm; stimuli.glossfit.fit): the render
    layer reads the camera's perspective from it."""
    import json

    from labfiles import atomic_write_text

    cam = _render_camera()
    atomic_write_text(Path(folder) / "fit.json", json.dumps({"setup": {
        "camera_distance_cm": cam.distance_cm, "sphere_radius_cm": cam.radius_cm,
        "fov_deg": cam.fov_deg, "resolution_px": list(cam.resolution_px)}}, indent=2))


def _crop(img: np.ndarray) -> np.ndarray:
    """The residual files' window of a full (uncropped) image."""
    y0, x0 = _OFFSET
    return img[y0:y0 + _SIZE, x0:x0 + _SIZE]


def _sphere_r() -> np.ndarray:
    """Distance from the sphere's centre in sphere radii on the cropped grid (the gloss fit's
    own measure, stimuli.glossfit.sphere_distance_px)."""
    from stimuli.glossfit import sphere_distance_px

    return _crop(sphere_distance_px(_render_camera()))


def _masks(specular: np.ndarray) -> dict:
    """The gloss fit's region masks (stimuli.glossfit.region_masks, on the full image) and its
    sphere mask (1 px inside the silhouette), cropped like the images."""
    from stimuli.glossfit import region_masks

    cam = _render_camera()
    full = np.zeros((_SIZE + _PAD,) * 2)
    y0, x0 = _OFFSET
    full[y0:y0 + _SIZE, x0:x0 + _SIZE] = specular
    masks = {k: _crop(v) for k, v in region_masks(cam, full).items()}
    masks["sphere"] = _sphere_r() < 1 - 1 / cam.sphere_radius_px
    masks["valid"] = np.ones((_SIZE, _SIZE), bool)
    return masks


def _mean_ratio(a, b, where):
    return float(a[where].sum() / max(b[where].sum(), 1e-12))


class _Studio:
    """The renderer the render candidates' injectors draw with (see analysis.gap.render):
    Mitsuba scenes of the gloss fit's sphere at ``spp`` samples per pixel."""

    def __init__(self, spp: int):
        self.spp = spp

    def level(self, k: int):
        return _LEVELS[k]

    def base(self, k: int):
        return _base(k, self.spp)

    def background(self, shift=(0.0, 0.0)):
        return _background(self.spp, shift)

    def render(self, material: dict, seed: int, shift=(0.0, 0.0)):
        return _render(material, self.spp, seed, shift=shift)

    def plain(self, k: int):
        d0, s0 = self.base(k)
        return self.background() + d0 + s0

    ward = staticmethod(_ward)
    rgb = staticmethod(_rgb)
    sphere_r = staticmethod(_sphere_r)
    mean_ratio = staticmethod(_mean_ratio)


class _LightStudio:
    """The renderer the injectors draw with on a directional-light set (the render layer's
    held-out lights, analysis.gap.render.lights): Mitsuba renders of one Ward sphere under
    light ``level`` of the set (stimuli.glossfit.lightfit.LightScene), no background."""

    WARD = (0.5, 0.04, 0.08)

    def __init__(self, scene, directions):
        self.scene, self.directions = scene, directions
        self._at = 0

    def at(self, k: int) -> _LightStudio:
        """Draw under light ``k`` (0-based) from here on."""
        self._at = k
        return self

    def level(self, k: int):
        return self.WARD

    def base(self, k: int):
        rho_d, rho_s, alpha = self.WARD
        light = self.directions[k]
        return (rho_d * self.scene.render(light, 1.0, 0.0, alpha),
                rho_s * self.scene.render(light, 0.0, 1.0, alpha))

    def background(self, shift=(0.0, 0.0)):
        return 0.0

    def render(self, material: dict, seed: int, shift=(0.0, 0.0)):
        return self.scene.render_material(self.directions[self._at], material, seed)

    def plain(self, k: int):
        d0, s0 = self.base(k)
        return d0 + s0

    ward = staticmethod(_ward)
    rgb = staticmethod(_rgb)


def write_light_set_with(folder, effects: dict, *, seed: int = 0, size: int = 40,
                         n_lights: int = 12, spp: int = 16) -> dict:
    """A synthetic directional-light set (stimuli.glossfit.lightsynth) of a Ward sphere with
    ``effects`` ``{name: strength}`` drawn by their injectors (the render catalogue's and
    ``render_lights``'), added to the plain photo. Returns the truth, with ``effects``."""
    from stimuli.glossfit import synth_light_set

    rng = np.random.default_rng(seed)

    def images(scene, light, k):
        studio = _LightStudio(scene, {k: light}).at(k)
        plain = studio.plain(k)
        extra = sum(_light_effect(name).inject(studio, k, s, rng) - plain
                    for name, s in effects.items())
        return plain + extra
    truth = synth_light_set(folder, size=size, n_lights=n_lights, seed=seed, spp=spp,
                            images=images)
    truth["effects"] = dict(effects)
    return truth


def _light_effect(name: str):
    """A render candidate by name, from the render catalogue or the directional lights' one."""
    table = {c.name: c for c in catalogue("render") + catalogue("render_lights")}
    if name not in table:
        raise ValueError(f"no render candidate {name!r}; known: {', '.join(table)}")
    return table[name]


def _inject_albedo_texture(studio, level, s, rng):
    """(Out of catalogue.) The diffuse albedo times 1 + s sin(6 pi u) sin(4 pi v)."""
    import mitsuba as mi

    rho_d, _, _ = studio.level(level)
    d0, s0 = studio.base(level)
    u = (np.arange(256) + 0.5) / 256
    v = (np.arange(128) + 0.5)[:, None] / 128
    half = 0.5 * (1 + np.sin(6 * np.pi * u)[None, :] * np.sin(4 * np.pi * v))
    tex = np.repeat((rho_d * half)[..., None], 3, axis=-1).astype(np.float32)
    # Rendered linearly: albedo rho_d (1 + s p) = (1 - s) rho_d + 2 s rho_d (1 + p) / 2.
    textured = studio.render({"type": "diffuse", "reflectance": {
        "type": "bitmap", "bitmap": mi.Bitmap(tex), "raw": True,
        "filter_type": "bilinear"}}, 51 + level)
    return studio.background() + ((1 - s) * d0 + 2 * s * textured) + s0


def _inject_anisotropy(studio, level, s, rng):
    """(Out of catalogue.) The lobe made anisotropic, alpha (1 + s) and alpha / (1 + s)."""
    _, rho_s, alpha = studio.level(level)
    d0, s0 = studio.base(level)

    def beckmann(au, av):
        return studio.render({"type": "roughconductor", "distribution": "beckmann",
                              "alpha_u": au, "alpha_v": av, "material": "none",
                              "specular_reflectance": studio.rgb(rho_s)}, 61 + level)
    change = beckmann(alpha * (1 + s), alpha / (1 + s)) - beckmann(alpha, alpha)
    return studio.background() + d0 + (s0 + change)


_register_out("render", OutOfCatalogue(
    "albedo_texture", _inject_albedo_texture, 0.06, "relative albedo modulation",
    "a surface texture: the diffuse albedo times 1 + s sin(6 pi u) sin(4 pi v)"))
_register_out("render", OutOfCatalogue(
    "anisotropy", _inject_anisotropy, 0.6, "alpha_u / alpha - 1",
    "an anisotropic lobe: alpha (1 + s) along u, alpha / (1 + s) along v"))


def _clean_photo(level: int, name: str, strength: float, spp: int,
                 rng: np.random.Generator) -> np.ndarray:
    """The noiseless photo of one level with the effect, drawn by its object's injector (a
    candidate's or an out-of-catalogue effect's)."""
    studio = _Studio(spp)
    if name == "none":
        return studio.plain(level)
    return _effect("render", name).inject(studio, level, float(strength), rng)


def write_render_fit(folder: Path, rng: np.random.Generator, effect: str = "none",
                     strength: float = 0.0, spp: int = _RENDER_SPP) -> dict:
    """A gloss fit's output folder (fits.csv, residuals/gloss_XXX.npz written with the gloss
    fit's own writer and region masks) whose photos are Mitsuba renders with the effect (plus a
    camera's shot and read noise) and whose renders are the plain Ward renders, their diffuse
    and specular scales fitted to the photos by least squares (as the fit's basis method
    does). Returns the noiseless photos {level name: luminance} (the truth, kept from the
    diagnosis)."""
    from stimuli.glossfit import write_residuals

    folder = Path(folder)
    (folder / "residuals").mkdir(parents=True, exist_ok=True)
    r = _sphere_r()
    rows, truth = [], {}
    for k, (rho_d, rho_s, alpha) in enumerate(_LEVELS):
        d0, s0 = _base(k, spp)
        bg = _background(spp)
        clean = _clean_photo(k, effect, strength, spp, rng)
        # A camera's Poisson-Gaussian noise: shot noise of _PHOTONS photons at the sphere's
        # mean level, read noise _READ_REL of that level.
        mean = float(clean[r < 1].mean())
        var = (_READ_REL * mean) ** 2 + mean * np.maximum(clean, 0.0) / _PHOTONS
        photo = clean + np.sqrt(var) * rng.standard_normal(clean.shape)
        fitm = _masks(s0)["sphere"]
        (a, b), *_ = np.linalg.lstsq(np.c_[d0[fitm], s0[fitm]], (photo - bg)[fitm], rcond=None)
        d, s = a * d0, b * s0
        masks = _masks(s)  # the highlight is where the fitted lobe is bright

        def rgb(img):
            return np.repeat(img[..., None], 3, axis=-1).astype(np.float32)

        gloss = (20, 50, 80)[k]
        write_residuals(folder / "residuals" / f"gloss_{gloss:03d}.npz",
                        {"photo": rgb(photo), "render": rgb(bg + d + s),
                         "residual": rgb(photo - bg - d - s), "diffuse": rgb(d),
                         "specular": rgb(s), **masks})
        rows.append({"gloss_pct": gloss, "method": "basis", "rho_d": rho_d * a,
                     "rho_s": rho_s * b, "alpha": alpha})
        truth[f"gloss_{gloss:03d}"] = clean
    pd.DataFrame(rows).to_csv(folder / "fits.csv", index=False)
    write_fit_setup(folder)
    return truth
