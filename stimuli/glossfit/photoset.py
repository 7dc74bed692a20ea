"""The gloss-fit input: a photo set folder (envmap, one HDR photo per gloss level, setup.toml).

Layout (protocol.md, "Gloss fitting")::

    PHOTO_SET/
        setup.toml            camera and sphere geometry (below)
        envmap.exr            the room's lat-long HDR panorama, taken from the sphere's position
        photos/gloss_000.exr  linear HDR photo of the 0 % sphere ... photos/gloss_100.exr

``setup.toml`` (flat keys)::

    camera_distance_cm = 27.5     # camera centre of projection to sphere centre
    sphere_radius_cm = 2.0
    fov_deg = 20.0                # horizontal field of view of the photos
    resolution_px = [96, 96]      # width, height of every photo
    sphere_centre_px = [48, 48]   # optional: x (right), y (down) of the sphere centre in the photos
    envmap_rotation_deg = 0.0     # optional: azimuth of the panorama about the vertical axis
    saturation_level = 60000.0    # optional: photo value at which the camera clipped
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from labfiles import LabFileError, read_toml
from stimuli.glossfit.exr import read_exr

__all__ = [
    "LIGHTINGS",
    "GlossFitError",
    "PhotoSet",
    "PhotoSetup",
    "clipped_mask",
    "lighting_folder",
    "lighting_names",
    "load_photo_set",
    "load_setup",
    "photo_name",
]

_PHOTO_RE = re.compile(r"^gloss_(\d{3})\.exr$")


class GlossFitError(ValueError):
    """A photo set or fit that cannot be used; the message names the file and the fix."""


@dataclass(frozen=True)
class PhotoSetup:
    """Camera and sphere geometry of a photo set (``setup.toml``).

    Attributes
    ----------
    camera_distance_cm : float
        Distance from the camera's centre of projection to the sphere centre (cm).
    sphere_radius_cm : float
        Sphere radius (cm).
    fov_deg : float
        Horizontal field of view of the photos (degrees).
    resolution_px : (int, int)
        Width and height of every photo (pixels).
    sphere_centre_px : (float, float) or None
        Where the sphere centre lies in the photos, x right and y down from the top-left pixel's
        corner (pixels); the image centre when None.
    envmap_rotation_deg : float
        Rotation of the panorama about the vertical axis (degrees, right-handed about +y).
    saturation_level : float or None
        Photo value at which the camera clipped; pixels at or above 99.9 % of it count as clipped.
        When None, clipping is detected as a plateau at the photo's maximum.
    """

    camera_distance_cm: float
    sphere_radius_cm: float
    fov_deg: float
    resolution_px: tuple[int, int]
    sphere_centre_px: tuple[float, float] | None = None
    envmap_rotation_deg: float = 0.0
    saturation_level: float | None = None

    def __post_init__(self) -> None:
        if not self.sphere_radius_cm > 0:
            raise GlossFitError(f"sphere_radius_cm = {self.sphere_radius_cm}; must be > 0")
        if not self.camera_distance_cm > 1.05 * self.sphere_radius_cm:
            raise GlossFitError(
                f"camera_distance_cm = {self.camera_distance_cm} is not beyond the sphere "
                f"(radius {self.sphere_radius_cm} cm); give the distance to the sphere centre")
        if not 0 < self.fov_deg < 170:
            raise GlossFitError(f"fov_deg = {self.fov_deg}; must lie in (0, 170) degrees")
        w, h = self.resolution_px
        if w < 16 or h < 16:
            raise GlossFitError(f"resolution_px = {self.resolution_px}; need at least 16 x 16")
        if self.sphere_diameter_px < 8:
            raise GlossFitError(
                f"the sphere spans {self.sphere_diameter_px:.1f} px in the photos; need >= 8 px "
                f"(check fov_deg, camera_distance_cm and resolution_px)")
        if self.saturation_level is not None and not self.saturation_level > 0:
            raise GlossFitError(f"saturation_level = {self.saturation_level}; must be > 0")

    @property
    def sphere_half_angle_deg(self) -> float:
        """Half the angle the sphere subtends at the camera (degrees)."""
        return math.degrees(math.asin(self.sphere_radius_cm / self.camera_distance_cm))

    @property
    def focal_px(self) -> float:
        """Focal length in pixels of the photos' pinhole camera."""
        return 0.5 * self.resolution_px[0] / math.tan(math.radians(self.fov_deg) / 2)

    @property
    def sphere_diameter_px(self) -> float:
        """Diameter of the sphere's silhouette in the photos, at the image centre (pixels)."""
        return 2 * self.focal_px * math.tan(math.radians(self.sphere_half_angle_deg))

    @property
    def centre_px(self) -> tuple[float, float]:
        """The sphere centre guess (x, y) in photo pixels."""
        if self.sphere_centre_px is not None:
            return self.sphere_centre_px
        return (self.resolution_px[0] / 2, self.resolution_px[1] / 2)

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


_SETUP_KEYS = {"camera_distance_cm", "sphere_radius_cm", "fov_deg", "resolution_px",
               "sphere_centre_px", "envmap_rotation_deg", "saturation_level"}


def load_setup(path: str | Path) -> PhotoSetup:
    """Read ``setup.toml``.

    Raises
    ------
    GlossFitError
        If the file is missing, is not TOML, lacks a required key, has an unknown key (a typo), or
        a value is out of range.
    """
    path = Path(path)
    if not path.is_file():
        raise GlossFitError(f"{path} not found; a photo set needs setup.toml (protocol.md, "
                            f"'Gloss fitting')")
    try:
        raw = read_toml(path)
    except LabFileError as exc:
        raise GlossFitError(str(exc)) from None
    except tomllib.TOMLDecodeError as exc:
        raise GlossFitError(f"{path}: not valid TOML ({exc})") from exc
    unknown = set(raw) - _SETUP_KEYS
    if unknown:
        raise GlossFitError(f"{path}: unknown keys {sorted(unknown)}; allowed: {sorted(_SETUP_KEYS)}")
    required = ("camera_distance_cm", "sphere_radius_cm", "fov_deg", "resolution_px")
    missing = [k for k in required if k not in raw]
    if missing:
        raise GlossFitError(f"{path}: missing keys {missing}")

    def pair(key, kind):
        value = raw.get(key)
        if value is None:
            return None
        if not (isinstance(value, list) and len(value) == 2):
            raise GlossFitError(f"{path}: {key} = {value!r}; expected [x, y]")
        return tuple(kind(v) for v in value)

    try:
        return PhotoSetup(
            camera_distance_cm=float(raw["camera_distance_cm"]),
            sphere_radius_cm=float(raw["sphere_radius_cm"]),
            fov_deg=float(raw["fov_deg"]),
            resolution_px=pair("resolution_px", int),
            sphere_centre_px=pair("sphere_centre_px", float),
            envmap_rotation_deg=float(raw.get("envmap_rotation_deg", 0.0)),
            saturation_level=(None if raw.get("saturation_level") is None
                              else float(raw["saturation_level"])),
        )
    except GlossFitError as exc:
        raise GlossFitError(f"{path}: {exc}") from None


def write_setup(path: str | Path, setup: PhotoSetup) -> None:
    """Write ``setup.toml`` (used by the synthetic photo sets)."""
    lines = []
    for key, value in setup.to_dict().items():
        if value is None:
            continue
        if isinstance(value, list):
            value = "[" + ", ".join(repr(v) for v in value) + "]"
        lines.append(f"{key} = {value}")
    Path(path).write_text("\n".join(lines) + "\n")


def photo_name(gloss_pct: float) -> str:
    """File name of a gloss level's photo, e.g. ``gloss_030.exr`` for 30 %."""
    if abs(gloss_pct - round(gloss_pct)) > 1e-9 or not 0 <= gloss_pct <= 100:
        raise GlossFitError(f"gloss level {gloss_pct} % has no photo name; levels must be whole "
                            f"percentages in 0-100")
    return f"gloss_{round(gloss_pct):03d}.exr"


def clipped_mask(photo: np.ndarray, saturation_level: float | None) -> np.ndarray:
    """Pixels that the camera clipped.

    Parameters
    ----------
    photo : ndarray, shape (h, w, 3)
        Linear HDR photo.
    saturation_level : float or None
        The clipping value when known: pixels with any channel >= 99.9 % of it are clipped.
        When None, a plateau at the maximum (>= 4 pixels within 0.1 % of it in one channel) is
        taken as clipping; an unclipped HDR photo has a single brightest pixel.

    Returns
    -------
    ndarray of bool, shape (h, w)
    """
    if saturation_level is not None:
        return np.any(photo >= 0.999 * saturation_level, axis=-1)
    mask = np.zeros(photo.shape[:2], dtype=bool)
    for c in range(photo.shape[2]):
        channel = photo[..., c]
        top = float(channel.max())
        if top <= 0:
            continue
        plateau = channel >= 0.999 * top
        if plateau.sum() >= 4:
            mask |= plateau
    return mask


@dataclass
class PhotoSet:
    """A loaded, validated photo set.

    Attributes
    ----------
    folder : Path
    setup : PhotoSetup
    envmap : ndarray, float32, shape (h, 2h, 3)
        Lat-long panorama (linear radiance).
    photos : dict of float -> ndarray, float32, shape (height, width, 3)
        Photos by gloss level (%), in increasing order.
    clipped : dict of float -> ndarray of bool, shape (height, width)
        Clipped pixels of each photo (excluded from the fit).
    missing_pct : list of float
        Gloss levels of the design without a photo.
    warnings : list of str
        Problems that do not stop the fit (missing levels, clipping); copied into the outputs.
    """

    folder: Path
    setup: PhotoSetup
    envmap: np.ndarray
    photos: dict[float, np.ndarray]
    clipped: dict[float, np.ndarray]
    missing_pct: list[float] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def clipped_fraction(self, gloss_pct: float) -> float:
        """Share of a photo's pixels that are clipped (0-1)."""
        return float(self.clipped[gloss_pct].mean())


def _check_finite(image: np.ndarray, path: Path) -> None:
    bad = ~np.isfinite(image)
    if bad.any():
        n = int(np.any(bad, axis=-1).sum())
        raise GlossFitError(
            f"{path}: {n} pixels are NaN or infinite; re-export the HDR merge (a NaN usually "
            f"comes from a division by a zero exposure weight) or fill those pixels")
    if (image < 0).any():
        n = int(np.any(image < 0, axis=-1).sum())
        raise GlossFitError(f"{path}: {n} pixels are negative; a linear HDR image has values "
                            f">= 0 (check the black-level subtraction)")


def load_photo_set(folder: str | Path, gloss_pct: tuple[float, ...], *,
                   max_clipped_fraction: float = 0.05, lighting: str | None = None) -> PhotoSet:
    """Load and validate a photo set.

    Parameters
    ----------
    folder : str or Path
        The photo set folder (layout in the module docstring).
    gloss_pct : tuple of float
        The design's physical gloss levels (%), ``design.gloss.physical_pct``.
    max_clipped_fraction : float
        A photo with more clipped pixels than this share (0-1) is an error; fewer is a warning
        and those pixels are left out of the fit.
    lighting : str, optional
        A set photographed in several lightings (``lightings/NAME/envmap.exr`` and
        ``lightings/NAME/photos/``, :mod:`stimuli.glossfit.lightings`): the one to load.

    Returns
    -------
    PhotoSet

    Raises
    ------
    GlossFitError
        If the folder, setup.toml, envmap.exr or photos/ is missing; the envmap is not a lat-long
        panorama; a photo is named for no design level, has the wrong size, NaN, infinite or
        negative pixels, or too many clipped pixels; or no photo is present.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise GlossFitError(f"photo set {folder} is not a folder")
    setup = load_setup(folder / "setup.toml")
    base = lighting_folder(folder, lighting)
    env_path = base / "envmap.exr"
    if not env_path.is_file():
        raise GlossFitError(f"{env_path} not found; a photo set needs the room's lat-long "
                            f"panorama as envmap.exr")
    envmap = read_exr(env_path)
    _check_finite(envmap, env_path)
    eh, ew = envmap.shape[:2]
    if ew != 2 * eh:
        raise GlossFitError(f"{env_path} is {ew} x {eh} px; a lat-long panorama is twice as "
                            f"wide as high (re-project it to equirectangular)")
    if float(envmap.max()) <= 0:
        raise GlossFitError(f"{env_path} is black; it cannot light the sphere")

    photo_dir = base / "photos"
    if not photo_dir.is_dir():
        raise GlossFitError(f"{photo_dir} not found; put the photos in photos/gloss_XXX.exr")
    expected = {photo_name(p): float(p) for p in gloss_pct}
    strays = sorted(p.name for p in photo_dir.glob("gloss_*.exr") if p.name not in expected)
    if strays:
        raise GlossFitError(
            f"{photo_dir}: {strays} name no gloss level of the design "
            f"({sorted(expected)}); rename them or use a design with those levels")
    photos: dict[float, np.ndarray] = {}
    clipped: dict[float, np.ndarray] = {}
    warnings: list[str] = []
    missing: list[float] = []
    w, h = setup.resolution_px
    for name, pct in sorted(expected.items(), key=lambda kv: kv[1]):
        path = photo_dir / name
        if not path.is_file():
            missing.append(pct)
            continue
        photo = read_exr(path)
        if photo.shape[:2] != (h, w):
            raise GlossFitError(
                f"{path} is {photo.shape[1]} x {photo.shape[0]} px but setup.toml says "
                f"resolution_px = [{w}, {h}]; photos and setup must match")
        _check_finite(photo, path)
        clip = clipped_mask(photo, setup.saturation_level)
        fraction = float(clip.mean())
        if fraction > max_clipped_fraction:
            raise GlossFitError(
                f"{path}: {100 * fraction:.2f} % of pixels are clipped (limit "
                f"{100 * max_clipped_fraction:.1f} %); merge more (shorter) exposures into the "
                f"HDR photo")
        if fraction > 0:
            warnings.append(f"{name}: {100 * fraction:.3f} % of pixels clipped; left out of the fit")
        photos[pct] = photo
        clipped[pct] = clip
    if not photos:
        raise GlossFitError(f"{photo_dir} holds no photos named gloss_XXX.exr "
                            f"(expected {sorted(expected)})")
    if missing:
        warnings.append("missing gloss levels (no photo): "
                        + ", ".join(f"{p:g} %" for p in missing))
    return PhotoSet(folder=folder, setup=setup, envmap=envmap, photos=photos, clipped=clipped,
                    missing_pct=missing, warnings=warnings)


#: The folder of a photo set that holds one subfolder per lighting
#: (:mod:`stimuli.glossfit.lightings`).
LIGHTINGS = "lightings"


def lighting_names(folder) -> list[str]:
    """The lightings of a photo set (``lightings/NAME/`` folders), sorted; [] for today's
    single-panorama layout."""
    d = Path(folder) / LIGHTINGS
    return sorted(p.name for p in d.iterdir() if p.is_dir()) if d.is_dir() else []


def lighting_folder(folder, lighting: str | None) -> Path:
    """The folder holding ``envmap.exr`` and ``photos/`` of ``lighting`` (None: the set's
    own, today's layout).

    Raises
    ------
    GlossFitError
        A set of several lightings without ``lighting``, or a lighting it lacks.
    """
    folder = Path(folder)
    names = lighting_names(folder)
    if lighting is None:
        if names:
            raise GlossFitError(
                f"{folder} holds photos in {len(names)} lightings ({', '.join(names)}); name "
                f"the one to fit: python -m stimuli fit-gloss {folder} --lights {names[0]} "
                "--out FIT")
        return folder
    if not names:
        raise GlossFitError(f"--lights {lighting}: {folder} has one lighting (no {LIGHTINGS}/ "
                            "folder); leave --lights out")
    if lighting not in names:
        raise GlossFitError(f"--lights {lighting}: {folder} has no lighting of that name; its "
                            f"lightings: {', '.join(names)}")
    return folder / LIGHTINGS / lighting
