"""Benchmark injectors: pseudo-real data with a hidden effect (observer, display, render).

The diagnosis never imports this module, nor the simulators used here (the experiment's
observers, calibration.SimulatedCRT); tests/analysis/gap/test_gap.py and
tests/analysis/gapbench/test_independence.py check the import graph."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.gap import OutOfCatalogue, catalogue, out_of_catalogue, strengths
from analysis.gap import effect as _effect
from analysis.gap import register_out_of_catalogue as _register_out
from studydesign import rec709_luminance

# Also public, derived when read (module __getattr__, see _DERIVED): OBSERVER_EFFECTS,
# OUT_OF_CATALOGUE, OUT_OF_CATALOGUE_STRENGTH, DISPLAY_EFFECTS, DISPLAY_OUT_OF_CATALOGUE,
# DISPLAY_STRENGTH, RENDER_EFFECTS, RENDER_OUT_OF_CATALOGUE, RENDER_STRENGTH.
__all__ = [
    "display_truth",
    "ideal_noise_sd",
    "lab_names",
    "observer_injector",
    "simulate_readings",
    "simulate_sessions",
    "write_calibration",
    "write_fit_setup",
    "write_light_set_with",
    "write_readings",
    "write_render_fit",
    "write_sessions",
]

#: The tables the benchmark reads, each derived from the effect objects (the candidates
#: registered with the engine by the layer modules, the out-of-catalogue effects registered
#: below), so that an effect's name and strength are written once, in its object.
_DERIVED = {
    "OBSERVER_EFFECTS": lambda: _names("observer"),
    "OUT_OF_CATALOGUE": lambda: _names("observer", out=True),
    "OUT_OF_CATALOGUE_STRENGTH": lambda: _strength("observer", out=True),
    "DISPLAY_EFFECTS": lambda: _names("display"),
    "DISPLAY_OUT_OF_CATALOGUE": lambda: _names("display", out=True),
    "DISPLAY_STRENGTH": lambda: strengths("display"),
    "RENDER_EFFECTS": lambda: _names("render"),
    "RENDER_OUT_OF_CATALOGUE": lambda: _names("render", out=True),
    "RENDER_STRENGTH": lambda: strengths("render"),
}


def __getattr__(name: str):
    """The derived tables (:data:`_DERIVED`), computed when read: the catalogues load their
    layer modules on first use."""
    if name in _DERIVED:
        return _DERIVED[name]()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _names(layer: str, *, out: bool = False) -> tuple[str, ...]:
    return tuple(e.name for e in (out_of_catalogue(layer) if out else catalogue(layer)))


def _strength(layer: str, *, out: bool) -> dict[str, float]:
    return {e.name: float(e.default_strength)
            for e in (out_of_catalogue(layer) if out else catalogue(layer))}


def ideal_noise_sd(design) -> dict:
    """The experiment's ideal observer's trial noise in slider units ({'gloss', 'depth'})."""
    from experiment import load_observer_params

    p = load_observer_params()["ideal"]
    return {"gloss": float(p["gloss_noise_pct"]) / design.slider.gloss_pct_per_unit,
            "depth": float(p["depth_noise_cm"]) / design.slider.depth_cm_per_unit}


def lab_names(design) -> dict:
    """Illumination names the benchmark's pseudo-real files use (not the design's)."""
    return {i.name: f"lab_probe_{k + 1}" for k, i in enumerate(design.illuminations)}


def _depth_noise_scaling(ctx, s, rng):
    """Noise SD growing with depth: x (1 + 3 s (depth - mid) / mid), at least 0.1."""
    scale = np.maximum(1 + s * 3 * (ctx["truth"]["depth"] - ctx["mid"]) / ctx["mid"], 0.1)
    return {r: np.clip(ctx["mu"][r] + scale * ctx["noise"][r], ctx["lo"], ctx["hi"])
            for r in ("gloss", "depth")}


def _stimulus_bias(ctx, s, rng):
    """A gloss bias of +-3 s slider units alternating between stimuli (a checkerboard)."""
    sign = np.where((ctx["gloss_level"] * 7 + ctx["depth_level"] * 3) % 2 == 1, 1.0, -1.0)
    mu = dict(ctx["mu"])
    mu["gloss"] = mu["gloss"] + s * 3 * sign
    return {r: np.clip(mu[r] + ctx["noise"][r], ctx["lo"], ctx["hi"]) for r in ("gloss", "depth")}


_register_out("observer", OutOfCatalogue(
    "depth_noise_scaling", _depth_noise_scaling, 0.3, "relative noise growth across depth",
    "response noise growing with depth (heteroscedastic)"))
_register_out("observer", OutOfCatalogue(
    "stimulus_bias", _stimulus_bias, 0.3, "x 3 slider units",
    "a gloss bias alternating between stimuli (a checkerboard)"))


def observer_injector(name: str):
    """The injector of an observer effect: the catalogue candidate's own or an
    out-of-catalogue effect's (:func:`analysis.gap.effect`). Raises GapError for an
    unknown name, listing the known ones."""
    return _effect("observer", name).inject


def simulate_sessions(design, n_participants: int, rng: np.random.Generator,
                      effect: str = "none", strength: float = 0.0, *,
                      lab_files: bool = False) -> pd.DataFrame:
    """Session rows (experiment.SESSION_COLUMNS) of the experiment's ``ideal`` observers
    (experiment.make_observer / simulate_dataset: the app's plans, noise and file format),
    with one effect added in slider units before the slider's clipping by the effect's
    injector (:func:`observer_injector`).

    ``lab_files``: rename illuminations (:func:`lab_names`) and stimulus ids as a lab's own
    files might, so the diagnosis cannot rely on the design's names.
    """
    from analysis.gap import to_slider_units
    from experiment import make_observer, simulate_dataset

    s = design.slider
    mid = 0.5 * (s.min + s.max)
    inject = None if effect == "none" else observer_injector(effect)
    names = lab_names(design) if lab_files else {i.name: i.name for i in design.illuminations}
    frames = []
    for p in range(n_participants):
        obs = make_observer("ideal", f"B{p:02d}", rng, design=design)
        frame = simulate_dataset(design, [obs], rng, calibration_id="bench")
        frame = frame.sort_values(["session", "trial"], ignore_index=True)
        tg = frame["true_gloss_pct"].to_numpy(float)
        td = frame["true_depth_cm"].to_numpy(float)
        eg, ed = obs.estimate(tg, td, rng)
        tgu, tdu = to_slider_units(s, tg, td)
        egu, edu = to_slider_units(s, eg, ed)
        truth = {"gloss": tgu, "depth": tdu}
        if inject is None:
            resp = {"gloss": np.clip(egu, s.min, s.max), "depth": np.clip(edu, s.min, s.max)}
        else:
            ses = frame["session"].to_numpy(int)
            ctx = {"truth": truth, "mu": dict(truth),
                   "noise": {"gloss": egu - tgu, "depth": edu - tdu},
                   "mid": mid, "lo": float(s.min), "hi": float(s.max),
                   "illumination": frame["illumination"].map(names).to_numpy(str),
                   "illuminations": [names[i.name] for i in design.illuminations],
                   "session_start": np.r_[True, ses[1:] != ses[:-1]],
                   "gloss_level": frame["gloss_level"].to_numpy(int),
                   "depth_level": frame["depth_level"].to_numpy(int)}
            resp = inject(ctx, float(strength), rng)
        frame["gloss_match"] = resp["gloss"]
        frame["depth_match"] = resp["depth"]
        frames.append(frame)
    out = pd.concat(frames, ignore_index=True)
    if lab_files:
        out["illumination"] = out["illumination"].map(lab_names(design))
        out["stimulus_id"] = [f"LAB-{i:05d}" for i in range(len(out))]
    return out


def write_sessions(frame: pd.DataFrame, folder: Path) -> None:
    """One CSV per participant and session, ``folder/<P>_s<N>.csv`` (the app's naming and
    columns, experiment.SESSION_COLUMNS); an existing file is never replaced."""
    from experiment import SESSION_COLUMNS
    from labfiles import write_new_file

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for (p, ses), grp in frame.groupby(["participant", "session"]):
        write_new_file(folder / f"{p}_s{ses}.csv",
                       grp[list(SESSION_COLUMNS)].to_csv(index=False))


# --- display layer ------------------------------------------------------------------------
# Pseudo-real photometer readings from calibration.SimulatedCRT with one effect changed; the
# diagnosis reads only readings.csv and calibration.json.

_SECONDS_PER_READING = 3.0
_BLEMISH_AT = (0.6, 0.6)


def display_schedule(rng: np.random.Generator, *, grid: int = 3, extent: float = 0.6,
                     n_levels: int = 17, n_uniformity: int = 5, repeats: int = 2):
    """Patches as the calibration procedure measures them: every level at the centre, a few
    levels elsewhere, each repeated, shuffled within each position."""
    v = np.linspace(-extent, extent, grid)
    rows = []
    for y in v[::-1]:
        for x in v:
            centre = abs(x) < 1e-9 and abs(y) < 1e-9
            n = n_levels if centre else n_uniformity
            lv = np.unique(np.round(np.linspace(0, 1, n) * 255)) / 255
            block = [(float(x), float(y), float(level), r) for r in range(repeats) for level in lv]
            rows += [block[i] for i in rng.permutation(len(block))]
    return pd.DataFrame(rows, columns=["x_norm", "y_norm", "level", "repeat"])


def display_crt(name: str = "none", strength: float = 0.0):
    """The benchmark's display: the shipped simulated CRT with one effect changed by its
    object's injector (a candidate's or an out-of-catalogue effect's, ``(crt, strength) ->
    display``; a display has ``luminance(level, x_norm, y_norm, t_s)``)."""
    from calibration import load_crt

    crt = load_crt()
    if name == "none":
        return crt
    return _effect("display", name).inject(crt, strength)


def _scaled_gamma(crt, strength):
    from dataclasses import replace

    return replace(crt, gamma=crt.gamma * (1 + strength))


class _Blemished:
    """The CRT with a blemish at one measured position (``_BLEMISH_AT``): the light above
    black there dimmed by a share ``strength``."""

    def __init__(self, crt, strength: float):
        self.crt, self.strength = crt, float(strength)

    def luminance(self, level, x_norm, y_norm, t_s):
        lum = self.crt.luminance(level, x_norm, y_norm, t_s)
        at = np.isclose(x_norm, _BLEMISH_AT[0]) & np.isclose(y_norm, _BLEMISH_AT[1])
        black = self.crt.black_total_cd_m2
        return np.where(at, black + (lum - black) * (1 - self.strength), lum)


_register_out("display", OutOfCatalogue(
    "gamma_change", _scaled_gamma, 0.03, "relative change of the gamma exponent",
    "the display's gamma changed since the calibration"))
_register_out("display", OutOfCatalogue(
    "local_blemish", _Blemished, 0.03, "share of the light lost at one position",
    "a blemish dimming one measured position"))


def display_truth(name: str, strength: float, schedule: pd.DataFrame,
                  t_s: np.ndarray) -> np.ndarray:
    """Noiseless luminance (cd/m^2) of the benchmark's display with the effect."""
    crt = display_crt(name, strength)
    t = t_s if name == "warmup_drift" else np.full(len(schedule), np.inf)
    return crt.luminance(schedule["level"].to_numpy(float), schedule["x_norm"].to_numpy(float),
                         schedule["y_norm"].to_numpy(float), t)


def display_noise_sd(lum: np.ndarray) -> np.ndarray:
    from calibration import load_crt

    crt = load_crt()
    return np.sqrt((crt.noise_rel * lum) ** 2 + crt.noise_abs**2)


def simulate_readings(rng: np.random.Generator, effect: str = "none", strength: float = 0.0,
                      calibration_id: str = "bench", repeats: int = 2) -> pd.DataFrame:
    """A readings.csv frame: the schedule measured on the display with the effect (warm-up
    drift: measured from switch-on; otherwise warmed up)."""
    from calibration import READINGS_COLUMNS

    sched = display_schedule(rng, repeats=repeats)
    t_s = np.arange(len(sched)) * _SECONDS_PER_READING
    lum = display_truth(effect, strength, sched, t_s)
    lum = lum + display_noise_sd(lum) * rng.standard_normal(lum.shape)
    t0 = pd.Timestamp("2026-01-05T09:00:00Z")
    out = sched.copy()
    out["calibration_id"] = calibration_id
    out["timestamp_utc"] = [(t0 + pd.Timedelta(seconds=float(s))).strftime(
        "%Y-%m-%dT%H:%M:%S.%fZ") for s in t_s]
    out["device"] = "pr655"
    out["luminance_cd_m2"] = lum
    out["raw_reply"] = [f"0,{v:.4f}" for v in lum]
    out.attrs["t_s"] = t_s
    return out[list(READINGS_COLUMNS)]


def write_calibration(rng: np.random.Generator, folder: Path) -> Path:
    """The lab's calibration of the benchmark display (warmed up, no effect): readings
    measured and fitted with the calibration package's public fitting functions. The gamma
    model is the display's own family (extended power), so the plain simulation is right up to
    its estimation error; a lab's choice of a worse-fitting model would be a gap of its own."""
    from calibration import (
        Calibration,
        fit_gamma_models,
        fit_uniformity,
        save_calibration,
    )

    # Six repeats: the lab's calibration is better measured than a check's readings, so its
    # own estimation error stays small next to the effects the benchmark injects.
    r = simulate_readings(rng, repeats=6)
    centre = r[(r["x_norm"] == 0) & (r["y_norm"] == 0)]
    fits = fit_gamma_models(centre["level"].to_numpy(float),
                            centre["luminance_cd_m2"].to_numpy(float))
    best = next(f for f in fits if f.model == "extended_power")
    cal = Calibration(calibration_id="bench", created_utc="2026-01-05T08:00:00Z",
                      device="pr655", monitor_name="bench", resolution_px=(1280, 1024),
                      width_cm=40.0, distance_cm=57.0, refresh_hz=85.0,
                      gamma_model=best.model, gamma_params=dict(best.params),
                      min_luminance_cd_m2=float(best.luminance(0.0)),
                      max_luminance_cd_m2=float(best.luminance(1.0)), fits=fits,
                      uniformity=fit_uniformity(r))
    return save_calibration(cal, Path(folder) / "calibration.json")


def write_readings(frame: pd.DataFrame, folder: Path) -> Path:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    frame.to_csv(folder / "readings.csv", index=False)
    return folder / "readings.csv"


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
