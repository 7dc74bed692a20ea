"""Synthetic photo sets: "photos" of the gloss spheres, for tests and the demo.

The lab's photos are not in the repository, so the fit is tested on renders. Two materials:

* ``rich`` (default): Mitsuba's ``roughplastic``, a dielectric clear coat (IOR 1.5, GGX
  microfacets, with Fresnel) over a Lambertian base. Physically richer than Ward, as a varnished
  ball is: the fit cannot match it exactly, so it tests stability, not recovery.
* ``ward``: the Ward BSDF the fit uses (stimuli.ward), with known parameters, to test recovery.

Per gloss level g (0-1 = 0-100 %): rich, clear-coat weight g and GGX alpha log-linear from 0.35
to 0.04 over a base of albedo 0.5; Ward, rho_d = 0.4, rho_s = 0.01 + 0.09 g (a line in gloss, as
the source study's table), alpha log-linear from 0.30 to 0.04.

Camera effects, each switchable and parameterised (``EFFECTS``), applied in this order:
misregistration (an affine warp: shift and scale of the sphere), veiling glare (a share of the
light spread by a wide Gaussian), vignetting (radial gain 1 - strength (r / r_corner)^2),
sensor noise (Poisson shot noise with ``photons`` at the mean level, plus Gaussian read noise
``read_sd`` relative to the mean) and clipping (values above a level, given as a quantile of the
photo, set to that level; off by default). Ground truth, effects and every drawn value go into
``truth.json`` beside the photos.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy import ndimage

from labfiles import atomic_open
from stimuli.glossfit.exr import write_exr
from stimuli.glossfit.photoset import PhotoSetup, photo_name, write_setup
from stimuli.glossfit.scene import SphereScene, photo_camera, ward_bsdf

__all__ = ["EFFECTS", "MATERIALS", "material_params", "room_panorama", "synth_photo_set"]

MATERIALS = ("rich", "ward")

#: Camera effects and their default parameters (``--effects noise,glare:fraction=0.05``).
EFFECTS = {
    "misregistration": {"shift_px": 1.5, "scale": 0.02},
    "glare": {"fraction": 0.02, "sigma_px": 12.0},
    "vignetting": {"strength": 0.15},
    "noise": {"photons": 4000.0, "read_sd": 0.002},
    "clipping": {"quantile": 0.999},
}
DEFAULT_EFFECTS = ("misregistration", "glare", "vignetting", "noise")

#: The synthetic sets' geometry: the source study's 27.5 cm and 2 cm; a 20 degree, 96 px camera.
DEFAULT_SETUP = PhotoSetup(camera_distance_cm=27.5, sphere_radius_cm=2.0, fov_deg=20.0,
                           resolution_px=(96, 96))


def room_panorama(height_px: int = 64) -> np.ndarray:
    """A procedural lat-long room: walls, floor, a ceiling lamp, a window, furniture.

    Deterministic; a stand-in for the lab's measured panorama with a compact bright source
    (sharp highlights), a broad one (the window) and texture behind the sphere (registration).

    Returns
    -------
    ndarray, float32, shape (height_px, 2 height_px, 3)
        Linear radiance (relative units).
    """
    h, w = height_px, 2 * height_px
    v = (np.arange(h) + 0.5)[:, None] / h  # 0 zenith, 1 nadir
    u = (np.arange(w) + 0.5)[None, :] / w  # 0.5 behind the sphere, as the camera sees it
    env = np.empty((h, w, 3), np.float32)
    wall = 0.35 + 0.1 * np.cos(2 * np.pi * u)
    env[...] = np.where(v < 0.5, wall, 0.12 + 0.03 * ((np.floor(u * 16) + np.floor(v * 8)) % 2))[
        ..., None] * np.array([1.0, 0.97, 0.9], np.float32)
    env[(v < 0.2) & np.ones_like(u, bool)] = np.array([0.5, 0.5, 0.5], np.float32)

    def box(u0, u1, v0, v1, rgb):
        sel = (u >= u0) & (u < u1) & (v >= v0) & (v < v1)
        env[sel] = np.asarray(rgb, np.float32)

    box(0.08, 0.16, 0.10, 0.18, [60.0, 58.0, 52.0])  # ceiling lamp, behind-left of the camera
    box(0.30, 0.42, 0.28, 0.48, [6.0, 7.0, 8.0])  # window, to the left
    box(0.47, 0.53, 0.38, 0.72, [0.08, 0.05, 0.04])  # dark door frame behind the sphere
    box(0.56, 0.66, 0.50, 0.62, [0.6, 0.25, 0.2])  # a red cabinet
    box(0.80, 0.95, 0.22, 0.40, [1.2, 1.2, 1.1])  # a lit poster
    return env


def material_params(material: str, gloss_pct: float) -> dict:
    """Ground-truth material of one gloss level (module docstring); a Mitsuba-ready dict."""
    g = gloss_pct / 100.0
    if material == "ward":
        alpha = math.exp(math.log(0.30) + (math.log(0.04) - math.log(0.30)) * g)
        return ward_bsdf(0.4, 0.01 + 0.09 * g, alpha)
    if material == "rich":
        alpha = math.exp(math.log(0.35) + (math.log(0.04) - math.log(0.35)) * g)
        return {"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "int_ior": 1.5,
                "diffuse_reflectance": {"type": "rgb", "value": 0.5},
                "specular_reflectance": {"type": "rgb", "value": g}, "nonlinear": False}
    raise ValueError(f"material {material!r}; choose one of {list(MATERIALS)}")


def parse_effects(text: str | None) -> dict[str, dict]:
    """Parse ``--effects``: ``none``, or a comma list of names with optional ``:key=value;...``.

    ``None`` gives the defaults (``DEFAULT_EFFECTS``). Example:
    ``noise:photons=1000,glare:fraction=0.05;sigma_px=8,vignetting``.

    Raises
    ------
    ValueError
        For an unknown effect or parameter, or a value that is not a number.
    """
    if text is None:
        return {name: dict(EFFECTS[name]) for name in DEFAULT_EFFECTS}
    if text.strip() in ("", "none"):
        return {}
    out: dict[str, dict] = {}
    for item in text.split(","):
        name, _, params = item.strip().partition(":")
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; choose from {list(EFFECTS)} or 'none'")
        values = dict(EFFECTS[name])
        for pair in filter(None, params.split(";")):
            key, _, value = pair.partition("=")
            if key not in values:
                raise ValueError(f"effect {name} has no parameter {key!r}; it has {list(values)}")
            try:
                values[key] = float(value)
            except ValueError:
                raise ValueError(f"effect {name}: {key}={value!r} is not a number") from None
        out[name] = values
    return out


def _apply_effects(image: np.ndarray, effects: dict, rng: np.random.Generator,
                   setup: PhotoSetup) -> tuple[np.ndarray, dict]:
    drawn: dict = {}
    img = image.astype(np.float64)
    h, w = img.shape[:2]
    if "misregistration" in effects:
        p = effects["misregistration"]
        dx, dy = rng.uniform(-p["shift_px"], p["shift_px"], 2)
        s = 1 + rng.uniform(-p["scale"], p["scale"])
        cx, cy = setup.centre_px
        # Output pixel x shows the scene at cx + (x - cx - dx)/s: the sphere moves by dx, grows by s.
        matrix = np.diag([1 / s, 1 / s])
        offset = np.array([cy - (cy + dy) / s, cx - (cx + dx) / s])
        img = np.stack([ndimage.affine_transform(img[..., c], matrix, offset=offset, order=1,
                                                 mode="nearest") for c in range(3)], axis=-1)
        drawn["misregistration"] = {"dx_px": float(dx), "dy_px": float(dy), "scale": float(s)}
    if "glare" in effects:
        p = effects["glare"]
        spread = ndimage.gaussian_filter(img, sigma=(p["sigma_px"], p["sigma_px"], 0),
                                         mode="nearest")
        img = (1 - p["fraction"]) * img + p["fraction"] * spread
    if "vignetting" in effects:
        y, x = np.mgrid[0:h, 0:w] + 0.5
        r2 = ((x - w / 2) ** 2 + (y - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        img = img * (1 - effects["vignetting"]["strength"] * r2)[..., None]
    if "noise" in effects:
        p = effects["noise"]
        mean = img.mean()
        gain = p["photons"] / mean
        img = rng.poisson(np.clip(img, 0, None) * gain) / gain
        img = np.clip(img + rng.normal(0, p["read_sd"] * mean, img.shape), 0, None)
    if "clipping" in effects:
        level = float(np.quantile(img, effects["clipping"]["quantile"]))
        img = np.minimum(img, level)
        drawn["clipping"] = {"level": level}
    return img.astype(np.float32), drawn


def synth_photo_set(out: str | Path, gloss_pct: tuple[float, ...], *, material: str = "rich",
                    effects: dict[str, dict] | None = None, seed: int = 0, spp: int = 64,
                    setup: PhotoSetup = DEFAULT_SETUP, envmap: np.ndarray | None = None,
                    exposure: float = 1.0) -> Path:
    """Render a synthetic photo set (layout of stimuli.glossfit.photoset).

    Parameters
    ----------
    out : str or Path
        New folder (must not exist, or be empty); nothing is overwritten.
    gloss_pct : tuple of float
        Gloss levels (%) to photograph.
    material : {"rich", "ward"}
    effects : dict
        Effect name -> parameters (``parse_effects``); the defaults when None, none when {}.
    seed : int
        Seeds the effects' random draws and the render samplers; recorded in truth.json.
    spp : int
        Samples per pixel of the photo renders.
    setup : PhotoSetup
        Camera geometry, written as setup.toml.
    envmap : ndarray, optional
        Lat-long panorama; ``room_panorama()`` when None.
    exposure : float
        Photo units per panorama unit (1: the photos and panorama share units).

    Returns
    -------
    Path
        ``out``.
    """
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out} exists and is not empty; choose a new folder")
    if material not in MATERIALS:
        raise ValueError(f"material {material!r}; choose one of {list(MATERIALS)}")
    effects = parse_effects(None) if effects is None else effects
    envmap = room_panorama() if envmap is None else np.asarray(envmap, np.float32)
    rng = np.random.default_rng(seed)
    (out / "photos").mkdir(parents=True, exist_ok=True)
    write_exr(out / "envmap.exr", envmap)
    write_setup(out / "setup.toml", setup)
    truth = {"material": material, "effects": effects, "seed": seed, "spp": spp,
             "exposure": exposure, "setup": setup.to_dict(), "levels": []}
    for i, pct in enumerate(gloss_pct):
        params = material_params(material, pct)
        with SphereScene(envmap, photo_camera(setup), spp=spp, seed=seed * 1000 + 17 + i,
                         envmap_rotation_deg=setup.envmap_rotation_deg,
                         bsdf=lambda *_a, p=params: p) as scene:
            image = scene.render(0.0, 0.0, 0.0) * exposure
        photo, drawn = _apply_effects(image, effects, rng, setup)
        write_exr(out / "photos" / photo_name(pct), photo)
        truth["levels"].append({"gloss_pct": pct, "material": params, "drawn": drawn})
    with atomic_open(out / "truth.json", "w", encoding="utf-8") as fh:
        fh.write(json.dumps(truth, indent=2))
    return out
