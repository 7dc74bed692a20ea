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
(65535, or 255) in any channel are saturated: censored, never fitted; so are pixels at a clip
level below it (a pile-up of equal top codes: a camera or converter that clipped there), with a
warning. A set that mixes 8- and 16-bit PNGs is refused (their codes are on other scales), as
is a frame with y (or x) flipped: in the normals (they disagree with the mask's silhouette) or
in the light directions (the photos' shading agrees with n.l only with the axis negated).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stimuli.glossfit.photoset import GlossFitError
from studydesign import rec709_luminance

__all__ = ["LightSet", "is_light_set", "load_light_set", "parse_lights", "read_png16",
           "refuse_over_exposed", "sphere_geometry"]

LIGHT_FILES = ("filenames.txt", "light_directions.txt", "light_intensities.txt", "mask.png")
#: Pixels at one code below the file's top that make a clip level: with a camera's noise on
#: 16 bits the brightest code of a photo recurs by chance in a pixel or two, a clip in many.
_CLIP_PILE = 4
#: Shading check: a flipped frame is refused when the photos' median correlation with n.l
#: (diffuse shading) is above _SHADING_R with an axis of the lights negated and beats the
#: given frame's by _FLIP_MARGIN (DiLiGenT's ball: r 0.98 as given, 0.70 with y negated).
_SHADING_R = 0.5
_FLIP_MARGIN = 0.15


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


def _png_bit_depth(path: Path) -> int | None:
    """A PNG's bit depth from its header (IHDR byte 24), without decoding; None if no PNG."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(26)
    except OSError:
        return None
    if len(head) < 25 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return head[24]


def _refuse_mixed_depths(folder: Path, names: list[str]) -> None:
    """Refuse a set whose PNGs differ in bit depth (all of the set's, not only the lights
    loaded: held-out photos must be on the fitted ones' scale)."""
    depth = {}
    for name in names:
        path = folder / "images" / name
        depth[name] = _png_bit_depth(path if path.exists() else folder / name)
    found = {d for d in depth.values() if d is not None}
    if len(found) < 2:
        return
    common = max(found, key=lambda d: (sum(v == d for v in depth.values()), d))
    odd = [n for n, d in depth.items() if d is not None and d != common]
    bits = sorted({depth[n] for n in odd})
    raise GlossFitError(
        f"{folder}: images {odd[:8]}{' ...' if len(odd) > 8 else ''} are {bits}-bit PNGs, the "
        f"set's other {len(names) - len(odd)} are {common}-bit: their codes are on another "
        f"scale (top {2 ** bits[0] - 1} vs {2 ** common - 1}); export them again as "
        f"{common}-bit raw PNGs from the camera's files, or leave the set's lights on one "
        "bit depth")


def _clip_level(codes: np.ndarray, top: int) -> float | None:
    """The code a photo was clipped at below the file's top (a pile-up of at least
    :data:`_CLIP_PILE` pixels at a channel's largest code), else None."""
    levels = []
    for c in range(codes.shape[-1]):
        m = float(codes[..., c].max())
        if 0 < m < top and int((codes[..., c] == m).sum()) >= _CLIP_PILE:
            levels.append(m)
    return min(levels) if levels else None


def _check_normals_frame(normals: np.ndarray, mask: np.ndarray, path: Path) -> None:
    """Refuse normals whose x or y runs against the mask's silhouette (a flipped axis): on an
    orthographic sphere x - cx grows with n_x and y - cy with -n_y (y down in the image)."""
    on = mask & (normals[..., 2] > 0.3)
    if on.sum() < 20:
        return
    yy, xx = np.nonzero(on)
    flipped = []
    for axis, pos, n in (("x", xx, normals[on][:, 0]), ("y", -yy, normals[on][:, 1])):
        if np.std(n) > 0 and np.corrcoef(pos, n)[0, 1] < 0:
            flipped.append(axis)
    if flipped:
        axes = " and ".join(flipped)
        raise GlossFitError(
            f"{path}: the normals' {axes} run against mask.png's sphere (n_{flipped[0]} falls "
            f"where the silhouette's {flipped[0]} rises): {axes} flipped. Negate the normals' "
            f"{axes} component(s) (the frame is x right, y up, z towards the camera)")


def _shading_r(photos: dict, saturated: dict, mask: np.ndarray, normals: np.ndarray,
               directions: dict, flip: np.ndarray) -> float:
    """Median over the photos of the correlation of their luminance with max(n.l, 0), the
    light directions multiplied by ``flip`` (unsaturated pixels inside the mask)."""
    rs = []
    for k, photo in photos.items():
        use = mask & ~saturated[k]
        if use.sum() < 20:
            continue
        lum = rec709_luminance(photo)[use]
        shade = np.clip(normals[use] @ (directions[k] * flip), 0, None)
        if np.std(lum) > 0 and np.std(shade) > 0:
            rs.append(float(np.corrcoef(lum, shade)[0, 1]))
    return float(np.median(rs)) if rs else float("nan")


def _check_light_frame(photos, saturated, mask, normals, directions, path: Path) -> None:
    """Refuse light directions whose x or y is flipped against the photos: their shading
    agrees with n.l much better with that axis negated."""
    given = _shading_r(photos, saturated, mask, normals, directions, np.ones(3))
    if not np.isfinite(given) or given >= 1 - _FLIP_MARGIN:
        return
    for axis, flip in (("y", np.array([1.0, -1, 1])), ("x", np.array([-1.0, 1, 1])),
                       ("x and y", np.array([-1.0, -1, 1]))):
        r = _shading_r(photos, saturated, mask, normals, directions, flip)
        if r > _SHADING_R and r > given + _FLIP_MARGIN:
            raise GlossFitError(
                f"{path}: the photos' shading agrees with n.l at r = {given:.2f}, but at r = "
                f"{r:.2f} with the lights' {axis} negated: {axis} flipped (in "
                "light_directions.txt, or in normal_gt.npy's frame). Negate that column of "
                "light_directions.txt (the frame is x right, y up, z towards the camera)")


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
    _refuse_mixed_depths(folder, names)
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
        clip = _clip_level(codes, top)
        if clip is not None:
            n_clip = int(np.any(codes >= clip, axis=-1).sum())
            warnings.append(f"{names[k - 1]}: {n_clip} pixels at or above code {clip:.0f}, "
                            f"below the file's top ({top}): the photo was clipped there (an "
                            "over-exposure, or a converter's white point); censored as "
                            "saturated. Export the raw codes unclipped to fit them")
        saturated[k] = np.any(codes >= (top if clip is None else clip), axis=-1)
        photos[k] = codes / ints[k - 1]
    normals_path = folder / "normal_gt.npy"
    if normals_path.is_file():
        normals = np.load(normals_path).astype(np.float64)
        if normals.shape != (*mask.shape, 3):
            raise GlossFitError(f"{normals_path}: shape {normals.shape}; expected "
                                f"{(*mask.shape, 3)} (h x w x 3, as mask.png)")
        source = "normal_gt.npy"
        _check_normals_frame(normals, mask, normals_path)
        geometry = normals_geometry(normals, mask)
    else:
        normals, source = mask_normals(mask.shape, geometry), "the mask's disc (orthographic)"
    _check_light_frame(photos, saturated, mask, normals,
                       {k: dirs[k - 1] / norms[k - 1] for k in lights},
                       folder / "light_directions.txt")
    return LightSet(folder=folder, lights=lights, names={k: names[k - 1] for k in lights},
                    directions={k: dirs[k - 1] / norms[k - 1] for k in lights},
                    intensities={k: ints[k - 1] for k in lights}, photos=photos,
                    saturated=saturated, mask=mask, normals=normals, geometry=geometry,
                    normals_source=source, n_lights=n, warnings=warnings)


#: A set whose median photo has more of the sphere saturated than this is over-exposed (a
#: well-exposed photo saturates its highlight only: about 1 % of the sphere in the synthetic
#: sets; 2x over-exposed: 8-44 %, 8x: 70-92 %).
OVER_EXPOSED_FRACTION = 0.25
#: A photo with more of the sphere saturated than this is named in a warning.
SATURATED_WARN_FRACTION = 0.05


def refuse_over_exposed(ls: LightSet) -> list[str]:
    """Refuse an over-exposed set; warn of single photos with much of the sphere saturated.

    Saturated pixels are censored, so an over-exposed set leaves the fit the sphere's dim edge
    and shadow: its Ward parameters come out wrong with nothing but "alpha at the search bound"
    to say so.

    Returns
    -------
    list of str
        Warnings, one per photo above :data:`SATURATED_WARN_FRACTION`.

    Raises
    ------
    GlossFitError
        If the median photo has more than :data:`OVER_EXPOSED_FRACTION` of the sphere saturated.
    """
    n = max(int(ls.mask.sum()), 1)
    frac = {k: float((ls.saturated[k] & ls.mask).sum()) / n for k in ls.lights}
    if np.median(list(frac.values())) > OVER_EXPOSED_FRACTION:
        worst = sorted(frac, key=frac.get, reverse=True)[:4]
        raise GlossFitError(
            f"{ls.folder}: the photos are over-exposed: {100 * min(frac.values()):.0f}-"
            f"{100 * max(frac.values()):.0f} % of the sphere is saturated (at the top code or "
            f"the clip level) in lights {_span(ls.lights)} (most: "
            + ", ".join(f"{ls.names[k]} {100 * frac[k]:.0f} %" for k in worst)
            + "); a well-exposed photo saturates its highlight only (about 1 %). Saturated "
            "pixels are left out, so the fit would rest on the sphere's dim edge and its Ward "
            "parameters would be wrong. Re-shoot at a shorter exposure (the brightest "
            "highlight below the top code), or export the raw codes unclipped")
    return [f"{ls.names[k]}: {100 * f:.0f} % of the sphere saturated (left out of the fit); "
            "a shorter exposure keeps it" for k, f in frac.items()
            if f > SATURATED_WARN_FRACTION]


def _span(lights) -> str:
    return f"{lights[0]}-{lights[-1]}" if len(lights) > 1 else f"{lights[0]}"

