"""Panorama photo sets photographed in several lightings (the room lit two ways), one held out.

A lab that photographs each gloss sphere twice, in the room lit two ways, with a panorama of
each lighting, can fit the Ward parameters in one lighting and predict the photos in the other
(protocol.md 4.1). Layout (setup.toml as in :mod:`stimuli.glossfit.photoset`, one camera and
sphere geometry for all lightings)::

    PHOTO_SET/
        setup.toml
        lightings/NAME/envmap.exr             the room's panorama in lighting NAME
        lightings/NAME/photos/gloss_XXX.exr   the spheres' photos in lighting NAME

``python -m stimuli fit-gloss SET --lights day --out FIT`` fits lighting ``day`` (fit.json
records ``lighting`` and ``lightings``); ``python -m analysis gap diagnose --layer render
--real SET --lights lamp --sim FIT --out REPORT`` renders each level's fitted material in the
panorama of ``lamp``, registers that lighting's photos to it (:func:`predict_lighting`) and
diagnoses them as held out. A set without ``lightings/`` is today's layout, read as before.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np

from stimuli.glossfit.photoset import LIGHTINGS, GlossFitError, lighting_folder, lighting_names

__all__ = ["LIGHTINGS", "is_lighting_fit", "lighting_folder", "lighting_names",
           "predict_lighting", "synth_lightings", "turned_room"]

_PHOTO_RE = re.compile(r"^gloss_(\d{3})\.exr$")


def is_lighting_fit(fit_dir) -> bool:
    """True when ``fit_dir`` holds a panorama gloss fit of one lighting of several."""
    try:
        return "lighting" in json.loads((Path(fit_dir) / "fit.json").read_text())
    except (OSError, json.JSONDecodeError, TypeError):
        return False


def _fitted_levels(fit_dir: Path) -> tuple[dict, dict[float, tuple[float, float, float]]]:
    """(fit.json, gloss % -> (rho_d, rho_s, alpha)) of the levels the fit fitted."""
    import pandas as pd

    if not is_lighting_fit(fit_dir):
        raise GlossFitError(f"{fit_dir}: not a gloss fit of one lighting of several; fit one "
                            "first: python -m stimuli fit-gloss SET --lights NAME --out FIT")
    info = json.loads((fit_dir / "fit.json").read_text())
    fits = pd.read_csv(fit_dir / "fits.csv").dropna(subset=["rho_d", "rho_s", "alpha"])
    return info, {float(r.gloss_pct): (float(r.rho_d), float(r.rho_s), float(r.alpha))
                  for r in fits.itertuples()}


def predict_lighting(fit_dir, photo_set_dir, lighting: str) -> dict[str, dict]:
    """Each fitted level's material in the held-out ``lighting``: its photo registered to the
    prediction (the fit's camera, render size, samples and seed; geometry only, as in the
    fit), as the render layer's residual arrays (:func:`stimuli.glossfit.fit.fit_level`'s),
    by level name (``gloss_030``). Levels without a photo in ``lighting`` or without a fit are
    left out.

    Raises
    ------
    GlossFitError
        ``fit_dir`` is no fit of one lighting, ``lighting`` is the fitted one or not in the
        set, a photo is bad (:func:`stimuli.glossfit.photoset.load_photo_set`), or no level
        is left.
    """
    from stimuli.glossfit.methods import BasisCache
    from stimuli.glossfit.photoset import load_photo_set, photo_name
    from stimuli.glossfit.registration import register, warp_photo
    from stimuli.glossfit.residuals import region_masks
    from stimuli.glossfit.scene import SphereScene, fit_camera, luminance, sphere_distance_px

    fit_dir = Path(fit_dir)
    info, params = _fitted_levels(fit_dir)
    if lighting == info["lighting"]:
        others = [n for n in lighting_names(photo_set_dir) if n != lighting]
        raise GlossFitError(f"--lights {lighting} was fitted ({fit_dir}); hold out another "
                            f"lighting: {', '.join(others) or 'none in the set'}")
    photo_dir = lighting_folder(photo_set_dir, lighting) / "photos"
    present = sorted(float(m.group(1)) for p in photo_dir.glob("gloss_*.exr")
                     if (m := _PHOTO_RE.match(p.name)))
    ps = load_photo_set(photo_set_dir, tuple(present), lighting=lighting)
    cam = fit_camera(ps.setup, int(info["resolution_px"]))
    sphere = sphere_distance_px(cam) < 1.0 - 1.0 / cam.sphere_radius_px
    out = {}
    with SphereScene(ps.envmap, cam, spp=int(info["spp"]), seed=int(info["seed"]),
                     envmap_rotation_deg=ps.setup.envmap_rotation_deg) as scene:
        cache = BasisCache(scene)
        for pct in (p for p in ps.photos if p in params):
            rho_d, rho_s, alpha = params[pct]
            name, clipped = photo_name(pct), ps.clipped[pct]
            diffuse, specular = rho_d * cache.diffuse(), rho_s * cache.specular(alpha)
            render = cache.background() + diffuse + specular
            reg = register(ps.photos[pct], render, cam, ps.setup, valid=~clipped, name=name)
            photo = warp_photo(ps.photos[pct], reg, cam, ps.setup)
            valid = warp_photo((~clipped).astype(np.float32), reg, cam, ps.setup, order=1) > 0.999
            out[Path(name).stem] = {
                "photo": photo, "render": render.astype(np.float32),
                "residual": (photo - render).astype(np.float32),
                "diffuse": diffuse.astype(np.float32), "specular": specular.astype(np.float32),
                **region_masks(cam, luminance(specular)), "sphere": sphere, "valid": valid}
    if not out:
        raise GlossFitError(f"{photo_dir}: no photo of a level the fit fitted "
                            f"({', '.join(f'{p:g} %' for p in sorted(params))})")
    return out


def turned_room(envmap: np.ndarray, turn: float = 0.4, gain: float = 0.8) -> np.ndarray:
    """A second lighting of a panorama's room (tests, demo): turned by ``turn`` of a full
    circle about the vertical (lamp and window on another side of the sphere) and scaled by
    ``gain``."""
    envmap = np.asarray(envmap, np.float32)
    return (gain * np.roll(envmap, round(turn * envmap.shape[1]), axis=1)).astype(np.float32)


def synth_lightings(out, gloss_pct: tuple[float, ...], lightings: dict[str, np.ndarray], *,
                    seed: int = 0, **kwargs) -> Path:
    """A synthetic photo set in several lightings (``lightings/NAME/``, one
    :func:`stimuli.glossfit.synth.synth_photo_set` per panorama, seeds ``seed``, ``seed + 1``,
    ...; their truth.json in each lighting's folder), setup.toml at the top. ``kwargs`` go to
    ``synth_photo_set``."""
    from stimuli.glossfit.synth import synth_photo_set

    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out} exists and is not empty; choose a new folder")
    for i, (name, envmap) in enumerate(lightings.items()):
        sub = synth_photo_set(out / LIGHTINGS / name, gloss_pct, seed=seed + i, envmap=envmap,
                              **kwargs)
        if i == 0:
            shutil.move(sub / "setup.toml", out / "setup.toml")
        else:
            (sub / "setup.toml").unlink()
    return out
