"""Photo sets lit by directional lights: one sphere, one photo per known light.

Photometric-stereo rigs and light stages record a sphere under many calibrated distant lights.
The layout read here is DiLiGenT's (Shi et al. 2016), as it is::

    BALL_DIR/
        filenames.txt          one image name per line, in light order (e.g. 001.png)
        images/NNN.png         linear (raw) photos, 16-bit RGB PNG (8-bit accepted, warned)
        light_directions.txt   one unit vector per line: x right, y up, z towards the camera
        light_intensities.txt  one RGB intensity per line (each photo is divided by its own)
        mask.png               the sphere's pixels (non-zero)
        normal_gt.npy          optional: the normals (h x w x 3, same frame); else from the mask

The camera is orthographic, looking along -z (DiLiGenT's far-field approximation). Lights are
numbered from 1 in file order; ``--lights 1-24`` picks some (:func:`parse_lights`).

16-bit PNGs are decoded with Mitsuba's bitmap reader (libpng), which keeps all 16 bits; Pillow
(and imageio through it) returns 8 bits for 16-bit RGB. Pixels at the file's largest code
(65535, or 255) in any channel are saturated: censored, never fitted.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stimuli.glossfit.photoset import GlossFitError
from studydesign import rec709_luminance

__all__ = ["LightSet", "is_light_set", "load_light_set", "parse_lights", "read_png16",
           "sphere_geometry"]

LIGHT_FILES = ("filenames.txt", "light_directions.txt", "light_intensities.txt", "mask.png")


def is_light_set(folder: str | Path) -> bool:
    """True when ``folder`` holds a directional-light photo set (it has light_directions.txt)."""
    return (Path(folder) / "light_directions.txt").is_file()


def parse_lights(text: str, n_lights: int | None = None) -> tuple[int, ...]:
    """``"1-24"``, ``"1-8,12,30-33"`` -> sorted light numbers (1-based, no repeats).

    Raises
    ------
    GlossFitError
        On a malformed part, a reversed range, a number below 1 or above ``n_lights``.
    """
    out: set[int] = set()
    for part in filter(None, (p.strip() for p in str(text).split(","))):
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m:
            raise GlossFitError(f"--lights {text!r}: {part!r} is no light number or range; "
                                "write e.g. --lights 1-24 or --lights 1-8,12,30-33")
        lo, hi = int(m.group(1)), int(m.group(2) or m.group(1))
        if lo < 1 or hi < lo:
            raise GlossFitError(f"--lights {text!r}: {part!r} is not a range of lights counted "
                                "from 1 (low-high)")
        if n_lights is not None and hi > n_lights:
            raise GlossFitError(f"--lights {text!r}: the set has lights 1-{n_lights} only")
        out.update(range(lo, hi + 1))
    if not out:
        raise GlossFitError(f"--lights {text!r} names no light; write e.g. --lights 1-24")
    return tuple(sorted(out))


def read_png16(path: str | Path) -> tuple[np.ndarray, int]:
    """A PNG's pixels at their full bit depth.

    Returns
    -------
    (ndarray float64 (h, w, c), int)
        The raw codes and the file's largest code (65535 for 16 bits, 255 for 8).

    Raises
    ------
    GlossFitError
        If the file is missing or cannot be decoded.
    """
    from stimuli.glossfit.mitsuba_setup import mitsuba

    path = Path(path)
    if not path.is_file():
        raise GlossFitError(f"{path} not found; filenames.txt names it")
    try:
        bmp = mitsuba().Bitmap(str(path))
    except Exception as exc:  # Mitsuba raises RuntimeError on unreadable files
        raise GlossFitError(f"{path}: cannot be read as an image ({exc}); export it as a "
                            "16-bit PNG") from exc
    a = np.array(bmp)
    if a.ndim == 2:
        a = a[..., None]
    top = {np.dtype(np.uint16): 65535, np.dtype(np.uint8): 255}.get(a.dtype)
    if top is None:
        raise GlossFitError(f"{path}: pixels of type {a.dtype}; expected an 8- or 16-bit PNG")
    return a.astype(np.float64), top


def sphere_geometry(mask: np.ndarray) -> tuple[float, float, float]:
    """(cy, cx, radius) of the sphere's silhouette in pixels (y down, pixel centres at
    integers + 0.5): the mask's centroid, and the radius of a disc of its area."""
    yy, xx = np.nonzero(mask)
    if yy.size < 20:
        raise GlossFitError(f"the mask has {yy.size} pixels; a sphere needs at least 20")
    return float(yy.mean() + 0.5), float(xx.mean() + 0.5), float(np.sqrt(yy.size / np.pi))


def normals_geometry(normals: np.ndarray, mask: np.ndarray) -> tuple[float, float, float]:
    """(cy, cx, radius) of an orthographic sphere from its normals: each pixel centre lies at
    x = cx + R n_x, y = cy - R n_y (least squares over the mask's pixels facing the camera,
    n_z > 0.3). Sub-pixel where the mask's area is not: a disc of radius 16 px holds 804 +- 6
    pixel centres, which moves its area's radius by up to 0.07 px (2 % in n_z at 0.9 radii)."""
    on = mask & (normals[..., 2] > 0.3)
    if on.sum() < 20:
        raise GlossFitError("normal_gt.npy: fewer than 20 mask pixels face the camera (n_z > "
                            "0.3); check its frame (x right, y up, z to the camera)")
    yy, xx = np.nonzero(on)
    nx, ny = normals[on][:, 0], normals[on][:, 1]
    ones, zeros = np.ones_like(nx), np.zeros_like(nx)
    a = np.r_[np.c_[zeros, ones, nx], np.c_[ones, zeros, -ny]]
    b = np.r_[xx + 0.5, yy + 0.5]
    (cy, cx, radius), *_ = np.linalg.lstsq(a, b, rcond=None)
    return float(cy), float(cx), float(radius)


def mask_normals(shape, geometry) -> np.ndarray:
    """Normals of an orthographic sphere (h, w, 3), x right, y up, z to the camera; 0 off it."""
    cy, cx, radius = geometry
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float) + 0.5
    x, y = (xx - cx) / radius, -(yy - cy) / radius
    z2 = 1 - x**2 - y**2
    on = z2 > 0
    return np.where(on[..., None], np.stack([x, y, np.sqrt(np.clip(z2, 0, 1))], -1), 0.0)


@dataclass
class LightSet:
    """A loaded, checked directional-light photo set (only the lights asked for are read).

    Attributes
    ----------
    folder : Path
    lights : tuple of int
        The light numbers loaded (1-based, file order).
    names : dict of int -> str
        Image file name per light.
    directions, intensities : dict of int -> ndarray (3,)
        Unit light direction (x right, y up, z to the camera) and RGB intensity per light.
    photos : dict of int -> ndarray float64 (h, w, 3)
        Each photo divided by its light's RGB intensity (linear).
    saturated : dict of int -> ndarray of bool (h, w)
        Pixels at the file's largest code in any channel (censored).
    mask : ndarray of bool (h, w)
    normals : ndarray (h, w, 3)
        From normal_gt.npy when the set has it, else from the mask's disc.
    geometry : (cy, cx, radius)
        The silhouette's centre and radius (px): from the normals when the set has them
        (:func:`normals_geometry`), else from the mask's centroid and area.
    normals_source : str
    warnings : list of str
    """

    folder: Path
    lights: tuple[int, ...]
    names: dict
    directions: dict
    intensities: dict
    photos: dict
    saturated: dict
    mask: np.ndarray
    normals: np.ndarray
    geometry: tuple[float, float, float]
    normals_source: str
    n_lights: int
    warnings: list[str] = field(default_factory=list)

    def luminance(self, k: int) -> np.ndarray:
        """Rec. 709 luminance of light ``k``'s normalised photo (h, w)."""
        return rec709_luminance(self.photos[k])


def _table(path: Path, n: int, what: str) -> np.ndarray:
    if not path.is_file():
        raise GlossFitError(f"{path} not found; a directional-light photo set needs {what}")
    try:
        a = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise GlossFitError(f"{path}: not a table of numbers ({exc})") from exc
    if a.shape != (n, 3):
        raise GlossFitError(f"{path} has {a.shape[0]} rows of {a.shape[1]} numbers; "
                            f"filenames.txt names {n} images: give one row of 3 per image")
    return a


def load_light_set(folder: str | Path, lights: tuple[int, ...] | str | None = None) -> LightSet:
    """Read a directional-light photo set (module docstring), the lights ``lights`` only
    (all when None).

    Raises
    ------
    GlossFitError
        A missing file, tables whose rows do not match filenames.txt, a light direction that
        is not a unit vector or points away from the camera's side... (each message names the
        file and the fix).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise GlossFitError(f"photo set {folder} is not a folder")
    names_path = folder / "filenames.txt"
    if not names_path.is_file():
        raise GlossFitError(f"{names_path} not found; list the images, one per light, in the "
                            "order of light_directions.txt")
    names = names_path.read_text().split()
    n = len(names)
    dirs = _table(folder / "light_directions.txt", n, "one light direction per image")
    ints = _table(folder / "light_intensities.txt", n,
                  "one RGB intensity per image (1 1 1 if the lights are equal)")
    if isinstance(lights, str):
        lights = parse_lights(lights, n)
    lights = tuple(range(1, n + 1)) if lights is None else tuple(lights)
    if max(lights) > n:
        raise GlossFitError(f"{folder}: lights {lights} asked for; the set has 1-{n}")
    norms = np.linalg.norm(dirs, axis=1)
    bad = [i + 1 for i in range(n) if abs(norms[i] - 1) > 0.01]
    if bad:
        raise GlossFitError(f"{folder / 'light_directions.txt'}: lights {bad} are not unit "
                            "vectors; normalise each row")
    if (ints <= 0).any():
        raise GlossFitError(f"{folder / 'light_intensities.txt'}: intensities must be > 0")
    mask_codes, _ = read_png16(folder / "mask.png")
    mask = mask_codes.max(axis=-1) > 0
    geometry = sphere_geometry(mask)
    warnings: list[str] = []
    photos, saturated = {}, {}
    for k in lights:
        codes, top = read_png16(folder / "images" / names[k - 1]) if (
            folder / "images" / names[k - 1]).exists() else read_png16(folder / names[k - 1])
        if codes.shape[:2] != mask.shape:
            raise GlossFitError(f"{names[k - 1]} is {codes.shape[1]} x {codes.shape[0]} px, "
                                f"mask.png {mask.shape[1]} x {mask.shape[0]}; they must match")
        if codes.shape[2] == 1:
            codes = np.repeat(codes, 3, axis=-1)
        codes = codes[..., :3]
        if top == 255:
            warnings.append(f"{names[k - 1]}: an 8-bit image; 16-bit raw photos keep the "
                            "highlight's and the shadow's levels")
        saturated[k] = np.any(codes >= top, axis=-1)
        photos[k] = codes / ints[k - 1]
    normals_path = folder / "normal_gt.npy"
    if normals_path.is_file():
        normals = np.load(normals_path).astype(np.float64)
        if normals.shape != (*mask.shape, 3):
            raise GlossFitError(f"{normals_path}: shape {normals.shape}; expected "
                                f"{(*mask.shape, 3)} (h x w x 3, as mask.png)")
        source = "normal_gt.npy"
        geometry = normals_geometry(normals, mask)
    else:
        normals, source = mask_normals(mask.shape, geometry), "the mask's disc (orthographic)"
    return LightSet(folder=folder, lights=lights, names={k: names[k - 1] for k in lights},
                    directions={k: dirs[k - 1] / norms[k - 1] for k in lights},
                    intensities={k: ints[k - 1] for k in lights}, photos=photos,
                    saturated=saturated, mask=mask, normals=normals, geometry=geometry,
                    normals_source=source, n_lights=n, warnings=warnings)
