"""Synthetic directional-light photo sets (tests, demo), in DiLiGenT's layout
(stimuli.glossfit.lightset): Mitsuba renders of a sphere under a ring of lights, with camera
noise, written as 16-bit raw PNGs that saturate at 65535.

``python -m stimuli synth-lights OUT --size 48 --lights 12`` writes a set whose sphere is a
clear-coated plastic (with its true normals, as DiLiGenT gives them; Mitsuba's ``roughplastic``: GGX lobe, Fresnel, the coat's transmission
on the diffuse light), not the fit's Ward: its held-out lights show a gap (``--material ward``:
the fit's own model, none).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from labfiles import atomic_path

__all__ = ["box_averaged_copy", "ring_lights", "synth_light_set", "write_light_set"]

#: Photo codes per unit of the brightest plain render (the highlight may saturate above it).
_PEAK_CODE = 40000.0


def ring_lights(n: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """``n`` unit light directions (n, 3) spread over the camera's hemisphere, 15-60 deg off
    the view axis, alternating in elevation so that any half of them spans the ring."""
    k = np.arange(n)
    phi = 2 * np.pi * (k * 0.618034 % 1.0)
    theta = np.radians(np.where(k % 2 == 0, 25.0, 50.0))
    if rng is not None:
        theta = theta + np.radians(rng.uniform(-8, 8, n))
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                     np.cos(theta)], axis=1)


def _write_png16(path: Path, codes: np.ndarray) -> None:
    from stimuli.glossfit.mitsuba_setup import mitsuba

    mi = mitsuba()
    img = np.ascontiguousarray(np.clip(np.round(codes), 0, 65535).astype(np.uint16))
    bmp = mi.Bitmap(img, mi.Bitmap.PixelFormat.RGB if img.ndim == 3 else mi.Bitmap.PixelFormat.Y)
    with atomic_path(path) as tmp:
        bmp.write(str(tmp))  # the temporary name keeps the suffix, which names the format


def write_light_set(folder, photos: list, directions, intensities, mask) -> Path:
    """Write a directional-light photo set: ``photos`` (raw codes, (h, w, 3) each, light
    order), unit ``directions`` (n, 3), RGB ``intensities`` (n, 3), the sphere's ``mask``.

    Raises
    ------
    FileExistsError
        If ``folder`` already holds a photo set (nothing is overwritten).
    """
    folder = Path(folder)
    if (folder / "filenames.txt").exists():
        raise FileExistsError(f"{folder} already holds a photo set; give a new folder")
    (folder / "images").mkdir(parents=True, exist_ok=True)
    names = [f"{k + 1:03d}.png" for k in range(len(photos))]
    for name, img in zip(names, photos):
        _write_png16(folder / "images" / name, img)
    m = np.repeat(np.where(mask, 255, 0).astype(np.uint8)[..., None], 3, axis=-1)
    from stimuli.glossfit.mitsuba_setup import mitsuba

    mi = mitsuba()
    with atomic_path(folder / "mask.png") as tmp:
        mi.Bitmap(np.ascontiguousarray(m), mi.Bitmap.PixelFormat.RGB).write(str(tmp))
    for name, table in (("light_directions.txt", directions),
                        ("light_intensities.txt", intensities)):
        with atomic_path(folder / name) as tmp:
            np.savetxt(tmp, np.asarray(table, float), fmt="%.6f")
    with atomic_path(folder / "filenames.txt") as tmp:
        tmp.write_text("\n".join(names) + "\n")
    return folder


def synth_light_set(folder, *, size: int = 48, n_lights: int = 12, material: str = "rich",
                    seed: int = 0, spp: int = 16, photons: float = 3000.0,
                    images=None) -> dict:
    """Render and write a synthetic directional-light set (module docstring).

    Parameters
    ----------
    folder : str or Path
        New folder.
    size : int
        Width = height of the photos (px); the sphere's diameter is 80 % of it.
    n_lights : int
    material : {"rich", "ward"}
        rich: roughplastic (GGX alpha 0.12, IOR 1.5, grey 0.5); ward: Ward (0.5, 0.04, 0.08).
    seed : int
        Lights' jitter, intensities, noise and sampler seed.
    spp : int
    photons : float
        Photons at the plain render's peak: Poisson noise, plus read noise of 2 codes.
    images : callable ``images(scene, light, k) -> luminance (h, w)``, optional
        Draws the photo of light ``k`` instead of ``material`` (the benchmark's injectors).

    Returns
    -------
    dict
        The truth: material, lights, intensities (also written as truth.json).
    """
    from stimuli.glossfit.lightfit import LightScene
    from stimuli.glossfit.lightset import mask_normals

    rng = np.random.default_rng(seed)
    folder = Path(folder)
    geometry = (size / 2, size / 2, 0.4 * size)
    dirs = ring_lights(n_lights, rng)
    ints = rng.uniform(0.8, 1.2, (n_lights, 1)) * np.array([[1.0, 1.05, 1.2]])
    bsdf = ({"type": "roughplastic", "distribution": "ggx", "alpha": 0.12, "int_ior": 1.5,
             "diffuse_reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]},
             "nonlinear": False} if material == "rich" else
            {"type": "ward", "rho_d": 0.5, "rho_s": 0.04, "alpha": 0.08})
    if material not in ("rich", "ward"):
        raise ValueError(f"material {material!r}: use rich or ward")
    with LightScene((size, size), geometry, spp=spp, seed=seed) as scene:
        lum = [images(scene, d, k) if images else scene.render_material(d, bsdf)
               for k, d in enumerate(dirs)]
    scale = _PEAK_CODE / max(float(np.percentile(np.concatenate([x.ravel() for x in lum]),
                                                 99.0)), 1e-12)
    photos = []
    for x, i in zip(lum, ints):
        clean = np.clip(x, 0, None)[..., None] * scale * i
        gain = _PEAK_CODE / photons  # codes per photon
        noisy = gain * rng.poisson(clean / gain) + rng.normal(0, 2.0, clean.shape)
        photos.append(noisy)
    normals = mask_normals((size, size), geometry)
    mask = np.linalg.norm(normals, axis=-1) > 0
    write_light_set(folder, photos, dirs, ints, mask)
    with atomic_path(folder / "normal_gt.npy") as tmp, open(tmp, "wb") as fh:
        np.save(fh, normals.astype(np.float32))
    truth = {"material": material if images is None else "injected", "bsdf": bsdf,
             "geometry_px": geometry, "directions": dirs.tolist(), "intensities": ints.tolist(),
             "codes_per_unit": scale}
    with atomic_path(folder / "truth.json") as tmp:
        tmp.write_text(json.dumps(truth, indent=1))
    return truth


def box_averaged_copy(source, folder, k: int) -> Path:
    """A k x k box-averaged copy of a directional-light set (photos, mask, true normals), e.g.
    the 158 px ball at k = 3 as a 52 px set for a quick check; ``source`` is never changed.

    Parameters
    ----------
    source : path
        A set in DiLiGenT's layout with ``normal_gt.npy`` (stimuli.glossfit.lightset).
    folder : path
        Where the copy is written (a new folder).
    k : int
        The box's side, px (>= 1); the image is cropped centrally to a multiple of ``k``.
    """
    from stimuli.glossfit.lightset import read_png16

    source, k = Path(source), int(k)
    if k < 1:
        raise ValueError(f"box_averaged_copy: k = {k}; give a box of at least 1 px")

    def box(a):
        n = a.shape[0] // k
        o = (a.shape[0] - n * k) // 2
        a = a[o:o + n * k, o:o + n * k]
        return a.reshape(n, k, n, k, *a.shape[2:]).mean(axis=(1, 3))
    names = (source / "filenames.txt").read_text().split()
    photos = [box(read_png16(source / "images" / n)[0]) for n in names]
    mask = box(read_png16(source / "mask.png")[0][..., 0] > 0) > 0.5
    out = write_light_set(folder, photos, np.loadtxt(source / "light_directions.txt"),
                          np.loadtxt(source / "light_intensities.txt"), mask)
    normals = box(np.load(source / "normal_gt.npy").astype(float))
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    np.save(Path(folder) / "normal_gt.npy", normals.astype(np.float32))
    return out
