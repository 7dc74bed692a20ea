"""Benchmark injectors: pseudo-real data with a hidden effect (observer, display, render).

The diagnosis never imports this module, nor the simulators used here (the experiment's
observers, calibration.SimulatedCRT); tests/analysis/gap/test_gap.py checks the import graph."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

__all__ = [
    "DISPLAY_EFFECTS",
    "DISPLAY_OUT_OF_CATALOGUE",
    "DISPLAY_STRENGTH",
    "OBSERVER_EFFECTS",
    "OUT_OF_CATALOGUE",
    "RENDER_EFFECTS",
    "RENDER_OUT_OF_CATALOGUE",
    "RENDER_STRENGTH",
    "display_truth",
    "ideal_noise_sd",
    "lab_names",
    "simulate_readings",
    "simulate_sessions",
    "write_calibration",
    "write_readings",
    "write_render_fit",
    "write_sessions",
]

OBSERVER_EFFECTS = ("crosstalk", "central_tendency", "illumination_gain", "label_rounding",
                    "lapses", "serial_dependence")
# Out of catalogue: heteroscedastic noise growing with depth, and a gloss bias on odd stimuli.
OUT_OF_CATALOGUE = ("depth_noise_scaling", "stimulus_bias")


def ideal_noise_sd(design) -> dict:
    """The experiment's ideal observer's trial noise in slider units ({'gloss', 'depth'})."""
    from experiment import load_observer_params

    p = load_observer_params()["ideal"]
    return {"gloss": float(p["gloss_noise_pct"]) / design.slider.gloss_pct_per_unit,
            "depth": float(p["depth_noise_cm"]) / design.slider.depth_cm_per_unit}


def lab_names(design) -> dict:
    """Illumination names the benchmark's pseudo-real files use (not the design's)."""
    return {i.name: f"lab_probe_{k + 1}" for k, i in enumerate(design.illuminations)}


def simulate_sessions(design, n_participants: int, rng: np.random.Generator,
                      effect: str = "none", strength: float = 0.0, *,
                      lab_files: bool = False) -> pd.DataFrame:
    """Session rows (experiment.SESSION_COLUMNS) of the experiment's ``ideal`` observers
    (experiment.make_observer / simulate_dataset: the app's plans, noise and file format),
    with one effect added in slider units before the slider's clipping.

    ``lab_files``: rename illuminations (:func:`lab_names`) and stimulus ids as a lab's own
    files might, so the diagnosis cannot rely on the design's names.
    """
    from experiment import make_observer, simulate_dataset

    s = design.slider
    mid = 0.5 * (s.min + s.max)
    ills = [i.name for i in design.illuminations]
    frames = []
    for p in range(n_participants):
        obs = make_observer("ideal", f"B{p:02d}", rng, design=design)
        frame = simulate_dataset(design, [obs], rng, calibration_id="bench")
        frame = frame.sort_values(["session", "trial"], ignore_index=True)
        tg = frame["true_gloss_pct"].to_numpy(float)
        td = frame["true_depth_cm"].to_numpy(float)
        eg, ed = obs.estimate(tg, td, rng)
        g0 = float(s.to_gloss_pct(s.min))
        truth = {"gloss": s.min + (tg - g0) / s.gloss_pct_per_unit,
                 "depth": td / s.depth_cm_per_unit}
        noise = {"gloss": s.min + (eg - g0) / s.gloss_pct_per_unit - truth["gloss"],
                 "depth": ed / s.depth_cm_per_unit - truth["depth"]}
        ill = frame["illumination"].astype(str).to_numpy()
        gl = frame["gloss_level"].to_numpy(int)
        dl = frame["depth_level"].to_numpy(int)
        ses = frame["session"].to_numpy(int)
        resp = {"gloss": np.empty(len(frame)), "depth": np.empty(len(frame))}
        prev = None
        for k in range(len(frame)):
            if k and ses[k] != ses[k - 1]:
                prev = None
            t = {r: truth[r][k] for r in resp}
            mu = dict(t)
            scale = 1.0
            if effect == "crosstalk":
                mu["gloss"] += strength * (t["depth"] - mid)
            elif effect == "central_tendency":
                mu = {r: v - strength * (v - mid) for r, v in mu.items()}
            elif effect == "illumination_gain":
                mu["gloss"] += (1 if ill[k] == ills[0] else -1) * strength * (t["gloss"] - mid)
            elif effect == "serial_dependence" and prev is not None:
                mu = {r: v + strength * (prev[r] - v) for r, v in mu.items()}
            elif effect == "depth_noise_scaling":
                scale = max(1 + strength * 3 * (t["depth"] - mid) / mid, 0.1)
            elif effect == "stimulus_bias":
                mu["gloss"] += strength * 3 * (1 if (gl[k] * 7 + dl[k] * 3) % 2 else -1)
            out = {}
            for r, column in resp.items():
                v = mu[r] + scale * noise[r][k]
                if effect == "label_rounding" and rng.random() < strength:
                    v = float(np.round(v))
                if effect == "lapses" and rng.random() < strength:
                    v = rng.uniform(s.min, s.max)
                out[r] = float(np.clip(v, s.min, s.max))
                column[k] = out[r]
            prev = out
        frame["gloss_match"] = resp["gloss"]
        frame["depth_match"] = resp["depth"]
        frames.append(frame)
    out = pd.concat(frames, ignore_index=True)
    if lab_files:
        out["illumination"] = out["illumination"].map(lab_names(design))
        out["stimulus_id"] = [f"LAB-{i:05d}" for i in range(len(out))]
    return out


def write_sessions(frame: pd.DataFrame, folder: Path) -> None:
    """One CSV per participant and session, ``folder/<P>_s<N>.csv`` (the app's naming)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for (p, ses), grp in frame.groupby(["participant", "session"]):
        grp.to_csv(folder / f"{p}_s{ses}.csv", index=False)


# --- display layer ------------------------------------------------------------------------
# Pseudo-real photometer readings from calibration.SimulatedCRT with one effect changed; the
# diagnosis reads only readings.csv and calibration.json.

DISPLAY_EFFECTS = ("black_offset", "nonuniformity", "warmup_drift", "quantisation")
DISPLAY_OUT_OF_CATALOGUE = ("gamma_change", "local_blemish")
#: Moderate strength of each display effect (the benchmark draws 0.5-1.5 times this).
DISPLAY_STRENGTH = {"black_offset": 0.05, "nonuniformity": 0.06, "warmup_drift": 0.03,
                    "quantisation": 2.0, "gamma_change": 0.03, "local_blemish": 0.03}
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


def display_crt(effect: str = "none", strength: float = 0.0):
    """The benchmark's display: the shipped simulated CRT with one effect changed."""
    from dataclasses import replace

    from calibration import load_crt

    crt = load_crt()
    if effect == "black_offset":
        return replace(crt, ambient_cd_m2=crt.ambient_cd_m2 + strength)
    if effect == "nonuniformity":
        return replace(crt, falloff=crt.falloff + strength, tilt_x=crt.tilt_x + strength / 2)
    if effect == "warmup_drift":
        return replace(crt, warmup_drift=strength)
    if effect == "quantisation":
        return replace(crt, bits=round(crt.bits - strength))
    if effect == "gamma_change":
        return replace(crt, gamma=crt.gamma * (1 + strength))
    return crt


def display_truth(effect: str, strength: float, schedule: pd.DataFrame,
                  t_s: np.ndarray) -> np.ndarray:
    """Noiseless luminance (cd/m^2) of the benchmark's display with the effect."""
    crt = display_crt(effect, strength)
    t = t_s if effect == "warmup_drift" else np.full(len(schedule), np.inf)
    lum = crt.luminance(schedule["level"].to_numpy(float), schedule["x_norm"].to_numpy(float),
                        schedule["y_norm"].to_numpy(float), t)
    if effect == "local_blemish":
        at = (np.isclose(schedule["x_norm"].to_numpy(float), _BLEMISH_AT[0])
              & np.isclose(schedule["y_norm"].to_numpy(float), _BLEMISH_AT[1]))
        lum = np.where(at, crt.black_total_cd_m2 + (lum - crt.black_total_cd_m2)
                       * (1 - strength), lum)
    return lum


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
# Pseudo-real photos of spheres from an analytic renderer (one directional light + ambient,
# Lambert diffuse, isotropic Ward specular), written in the gloss fit's residual-file format.
# The effects are computed physically here (half-vector Fresnel, coat transmission on the light
# and the view path, cos^4 vignetting, a long-tailed glare PSF, exact resampling, a GGX tail),
# not with the diagnosis's image-space approximations.

RENDER_EFFECTS = ("fresnel", "clearcoat", "vignetting", "veiling_glare", "misregistration",
                  "long_tail")
RENDER_OUT_OF_CATALOGUE = ("albedo_texture", "anisotropy")
RENDER_STRENGTH = {"fresnel": 6.0, "clearcoat": 0.6, "vignetting": 0.5, "veiling_glare": 0.15,
                   "misregistration": 0.6, "long_tail": 0.6, "albedo_texture": 0.06,
                   "anisotropy": 0.6}
_LIGHT = np.array([-0.45, 0.55, 0.70]) / np.linalg.norm([-0.45, 0.55, 0.70])
_LEVELS = ((0.55, 0.04, 0.20), (0.45, 0.08, 0.12), (0.35, 0.12, 0.07))  # rho_d, rho_s, alpha


def _schlick(cos, f0):
    return f0 + (1 - f0) * (1 - np.clip(cos, 0, 1)) ** 5


def _sphere_render(size, rho_d, rho_s, alpha, effect="none", strength=0.0, rng=None):
    """Diffuse and specular luminance of a sphere (radius 0.36 size, centred a little off the
    image centre), orthographic view along +z."""
    h = w = size
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    cy, cx, rad = 0.48 * h, 0.52 * w, 0.36 * size
    x, y = (xx - cx) / rad, -(yy - cy) / rad
    r2 = x**2 + y**2
    inside = r2 < 1
    z = np.sqrt(np.clip(1 - r2, 0, 1))
    n = np.stack([x, y, z], -1)
    v = np.array([0.0, 0.0, 1.0])
    cos_i = np.clip(n @ _LIGHT, 0, 1)
    cos_o = np.clip(z, 1e-3, 1)
    hv = (_LIGHT + v) / np.linalg.norm(_LIGHT + v)
    cos_h = np.clip(n @ hv, 1e-6, 1)
    tan2 = (1 - cos_h**2) / cos_h**2
    e_dir, e_amb = 1.0, 0.25
    diffuse = rho_d * (cos_i * e_dir + e_amb)
    if effect == "anisotropy":
        # Anisotropic Ward: alpha_x != alpha_y (out of the catalogue).
        ax, ay = alpha * (1 + strength), alpha / (1 + strength)
        tx = np.stack([np.ones_like(x), np.zeros_like(x), -x / np.maximum(z, 1e-3)], -1)
        tx /= np.linalg.norm(tx, axis=-1, keepdims=True)
        ty = np.cross(n, tx)
        hx, hy = tx @ hv, ty @ hv
        expo = -((hx / ax) ** 2 + (hy / ay) ** 2) / cos_h**2
        lobe = np.exp(expo) / (4 * np.pi * ax * ay * np.sqrt(cos_i * cos_o + 1e-9))
    else:
        lobe = np.exp(-tan2 / alpha**2) / (4 * np.pi * alpha**2 * np.sqrt(cos_i * cos_o + 1e-9))
    spec = rho_s * e_dir * cos_i * lobe
    env = rho_s * 0.3 * np.ones_like(z)  # the uniform surround, mirrored
    if effect == "fresnel":
        # Schlick on each path's own angle: the light's lobe at the half vector (fixed light
        # and view: a constant), the surround's mirror reflection at the view angle.
        f0 = 1 / (1 + strength)
        spec = spec * _schlick(float(hv @ v), f0) / f0
        env = env * _schlick(cos_o, f0) / f0
    if effect == "long_tail":
        a_t = 2.5 * alpha
        d_ggx = a_t**2 / (np.pi * (cos_h**2 * (a_t**2 - 1) + 1) ** 2)
        tail = rho_s * e_dir * cos_i * d_ggx / (4 * cos_o + 1e-9)
        spec = (1 - strength) * spec + strength * tail * (spec.sum() / max(tail.sum(), 1e-12))
    if effect == "clearcoat":
        # Light enters through the coat (its transmission averaged over the incident
        # directions, 1 - 0.09 for n = 1.5: the lab's surround is diffuse) and leaves towards
        # the camera through it at the view angle.
        t = (1 - 0.09) * (1 - _schlick(cos_o, 0.04))
        diffuse = diffuse * (1 - strength + strength * t)
    if effect == "albedo_texture":
        diffuse = diffuse * (1 + strength * np.sin(2 * np.pi * 3 * x) * np.sin(2 * np.pi * 2 * y))
    return (np.where(inside, diffuse, 0.0), np.where(inside, spec + env, 0.0), inside,
            np.sqrt(r2))


def _camera(img, effect, strength, rng):
    """Image-space effects of the camera and the residual registration."""
    from scipy import ndimage as ndi

    h, w = img.shape
    if effect == "veiling_glare":
        k = 2 * max(h, w) + 1
        yy, xx = np.mgrid[0:k, 0:k] - k // 2
        psf = 1 / (1 + (np.hypot(yy, xx) / (0.03 * w)) ** 2) ** 1.5
        psf /= psf.sum()
        from scipy.signal import fftconvolve

        img = img + strength * fftconvolve(img, psf, mode="same")
    if effect == "vignetting":
        yy, xx = np.mgrid[0:h, 0:w].astype(float)
        rho = np.hypot(yy - (h - 1) / 2, xx - (w - 1) / 2) / np.hypot(h / 2, w / 2)
        img = img / (1 + (strength * rho) ** 2) ** 2
    if effect == "misregistration":
        ang = rng.uniform(0, 2 * np.pi)
        img = ndi.shift(img, (strength * np.sin(ang), strength * np.cos(ang)), order=3,
                        mode="nearest")
    return img


def write_render_fit(folder: Path, rng: np.random.Generator, effect: str = "none",
                     strength: float = 0.0, size: int = 64, noise: float = 0.004) -> Path:
    """A gloss fit's output folder (fits.csv, residuals/gloss_XXX.npz in its format) whose
    photos carry the effect and whose renders are the plain analytic renders, scaled to the
    photos. Returns the noiseless photos {level name: luminance image} (the truth, kept from
    the diagnosis)."""
    folder = Path(folder)
    (folder / "residuals").mkdir(parents=True, exist_ok=True)
    rows = []
    truth = {}
    for k, (rho_d, rho_s, alpha) in enumerate(_LEVELS):
        d0, s0, _inside, r = _sphere_render(size, rho_d, rho_s, alpha)
        d1, s1, _, _ = _sphere_render(size, rho_d, rho_s, alpha, effect, strength, rng)
        clean = _camera(d1 + s1, effect, strength, rng)
        photo = clean + noise * rng.standard_normal(clean.shape)
        # The gloss fit scales the diffuse and specular renders to the photo (its basis fit is
        # linear in rho_d, rho_s); the same least-squares fit here, on the sphere.
        fitm = r < 1
        (a, b), *_ = np.linalg.lstsq(np.c_[d0[fitm], s0[fitm]], photo[fitm], rcond=None)
        d0, s0 = a * d0, b * s0
        render = d0 + s0
        spec_in = np.where(r < 0.85, s0, 0)
        hl = (r < 0.85) & (spec_in >= 0.5 * spec_in.max())
        edge = 1 + 1 / (0.36 * size)
        masks = {"highlight": hl, "body": (r < 0.85) & ~hl, "rim": (r >= 0.85) & (r < edge),
                 "background": r >= edge, "sphere": r < 1 - 1 / (0.36 * size),
                 "valid": np.ones_like(hl)}

        def rgb(a):
            return np.repeat(a[..., None], 3, axis=-1).astype(np.float32)

        gloss = 20 * (k + 1)
        np.savez_compressed(folder / "residuals" / f"gloss_{gloss:03d}.npz",
                            photo=rgb(photo), render=rgb(render), residual=rgb(photo - render),
                            diffuse=rgb(d0), specular=rgb(s0), **masks)
        rows.append({"gloss_pct": gloss, "method": "basis", "rho_d": rho_d, "rho_s": rho_s,
                     "alpha": alpha})
        truth[f"gloss_{gloss:03d}"] = clean
    pd.DataFrame(rows).to_csv(folder / "fits.csv", index=False)
    return truth
