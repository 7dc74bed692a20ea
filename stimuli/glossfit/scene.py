"""The gloss-fit scene: one sphere in the room's panorama, seen by a pinhole camera (Mitsuba 3).

Frame: the sphere sits at the origin; the camera sits at (0, 0, -distance) and looks along +z
with +y up, so the panorama's centre column (Mitsuba's +z) lies behind the sphere and the
panorama's u grows to the right in the image, as for a photographer facing the panorama's centre.
``envmap_rotation_deg`` turns the panorama about +y.

Renders use Mitsuba's ``path`` integrator with ``max_depth = 2`` (camera ray, one bounce to the
panorama): a convex sphere cannot see itself, so this is its exact light transport, and Russian
roulette never starts (``rr_depth`` above the depth). Every render uses the same sampler seed,
so with a BSDF whose lobe-selection probability does not depend on its albedos, renders are
linear in ``rho_d`` and ``rho_s`` (the basis fit relies on this; tests check it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stimuli.glossfit.mitsuba_setup import FIT_VARIANT
from stimuli.glossfit.photoset import PhotoSetup
from studydesign import rec709_luminance

__all__ = [
    "Camera",
    "SphereScene",
    "fit_binning",
    "fit_camera",
    "luminance",
    "photo_camera",
    "sphere_distance_px",
    "ward_bsdf",
]

def luminance(rgb: np.ndarray) -> np.ndarray:
    """Luminance (Rec. 709 weights) of a linear RGB image, shape (..., 3) -> (...)."""
    return rec709_luminance(rgb, dtype=np.float32)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera looking at the sphere centre.

    Attributes
    ----------
    fov_deg : float
        Horizontal field of view (degrees).
    resolution_px : (int, int)
        Width, height (pixels).
    distance_cm : float
        Centre of projection to sphere centre (cm).
    radius_cm : float
        Sphere radius (cm).
    shift_px : (float, float)
        Sub-pixel shift (x right, y down, px) of the image content, rendered by moving the
        principal point (Mitsuba's ``principal_point_offset_x/y``), so each pixel still
        integrates the scene over its own area; (0, 0) by default. ``centre_px`` does not
        include it.
    """

    fov_deg: float
    resolution_px: tuple[int, int]
    distance_cm: float
    radius_cm: float
    shift_px: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        shift = tuple(self.shift_px)
        if len(shift) != 2 or not all(math.isfinite(float(v)) for v in shift):
            raise ValueError(f"camera shift_px {self.shift_px!r}: give two finite numbers (x, y) "
                             "in pixels, e.g. (0.3, -0.2)")

    @property
    def focal_px(self) -> float:
        return 0.5 * self.resolution_px[0] / math.tan(math.radians(self.fov_deg) / 2)

    @property
    def centre_px(self) -> tuple[float, float]:
        """Image position (x right, y down, pixel corners at integers) of the sphere centre."""
        return (self.resolution_px[0] / 2, self.resolution_px[1] / 2)

    @property
    def sphere_radius_px(self) -> float:
        """Radius of the sphere's silhouette, a circle because the sphere is on the axis (px)."""
        return self.focal_px * math.tan(math.asin(self.radius_cm / self.distance_cm))


def photo_camera(setup: PhotoSetup) -> Camera:
    """The camera of the photos (their field of view and resolution)."""
    return Camera(setup.fov_deg, tuple(setup.resolution_px), setup.camera_distance_cm,
                  setup.sphere_radius_cm)


def fit_camera(setup: PhotoSetup, size_px: int, *, fill: float = 0.7) -> Camera:
    """A square camera framing the sphere, for the fit's small renders.

    Its pixels are photo pixels binned ``fit_binning(setup, size_px, fill)`` times per side, so
    a registered photo needs only a shift (and a small scale) to land on the render grid, and its
    binned pixels integrate light as the render's box-filtered pixels do.

    Parameters
    ----------
    setup : PhotoSetup
    size_px : int
        Width and height of the fit renders (pixels).
    fill : float
        Wanted share of the image width the sphere's diameter spans (0-1); the rest is background
        for the registration and the background residuals.
    """
    n = fit_binning(setup, size_px, fill=fill)
    focal = setup.focal_px / n
    fov = 2 * math.degrees(math.atan(size_px / 2 / focal))
    return Camera(fov, (size_px, size_px), setup.camera_distance_cm, setup.sphere_radius_cm)


def fit_binning(setup: PhotoSetup, size_px: int, *, fill: float = 0.7) -> int:
    """Photo pixels per fit pixel (per side) that make the sphere span about ``fill``."""
    n = max(1, round(setup.sphere_diameter_px / (fill * size_px)))
    if setup.sphere_diameter_px / n > 0.95 * size_px:
        n += 1
    return n


def sphere_distance_px(camera: Camera) -> np.ndarray:
    """Distance of each pixel centre from the sphere's projected centre, in sphere radii.

    Returns
    -------
    ndarray, shape (height, width)
        < 1 on the sphere, > 1 on the background.
    """
    w, h = camera.resolution_px
    cx, cy = camera.centre_px
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    return np.hypot(x - cx, y - cy) / camera.sphere_radius_px


#: Probability of sampling the glossy lobe in the fit renders: fixed, so that the sampling does
#: not depend on the albedos and renders are linear in them (stimuli.ward, ``lobe_probability``).
FIT_LOBE_PROBABILITY = 0.5


def ward_bsdf(rho_d: float, rho_s: float, alpha: float) -> dict:
    """Mitsuba dict of the isotropic Ward BSDF (plugin ``ward``, stimuli.ward), fixed lobe choice."""
    return {"type": "ward", "rho_d": float(rho_d), "rho_s": float(rho_s), "alpha": float(alpha),
            "lobe_probability": FIT_LOBE_PROBABILITY}


class SphereScene:
    """A Mitsuba scene of the sphere in a panorama; renders on demand and counts its renders.

    Use as a context manager (``with SphereScene(...) as scene``); the scene is freed on exit.

    Parameters
    ----------
    envmap : ndarray, shape (h, 2h, 3)
        Lat-long panorama (linear radiance).
    camera : Camera
    spp : int
        Samples per pixel (rounded up to a square for the stratified ``multijitter`` sampler,
        which is 3-4 times less noisy here than ``independent`` at the same count).
    seed : int
        Sampler seed, the same for every render.
    envmap_rotation_deg : float
        Rotation of the panorama about +y (degrees).
    bsdf : callable (rho_d, rho_s, alpha) -> dict
        The sphere's material as a Mitsuba dict; the isotropic Ward BSDF by default.
    """

    _variant_before: str | None = None

    def __init__(self, envmap: np.ndarray, camera: Camera, *, spp: int = 36, seed: int = 0,
                 envmap_rotation_deg: float = 0.0,
                 bsdf: Callable[[float, float, float], dict] = ward_bsdf) -> None:
        from stimuli.glossfit.mitsuba_setup import mitsuba, use_fit_variant

        self._mi = mitsuba()
        self._variant_before = use_fit_variant()
        self.camera = camera
        # The multijitter sampler draws a square number of samples per pixel.
        self.spp = math.ceil(math.sqrt(int(spp))) ** 2
        self.seed = int(seed)
        self._bsdf = bsdf
        self._envmap = np.ascontiguousarray(envmap, dtype=np.float32)
        self._rotation = float(envmap_rotation_deg)
        self._scene = None
        self._params = None
        self._keys: dict[str, str] = {}
        self._current: tuple[float, float, float] | None = None
        self.n_renders = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Free the scene and switch back to the Mitsuba variant active before it."""
        self._scene = None
        self._params = None
        before, self._variant_before = self._variant_before, None
        if before is not None and self._mi.variant() != before:
            self._mi.set_variant(before)

    def _scene_dict(self, rho_d: float, rho_s: float, alpha: float) -> dict:
        mi = self._mi
        cam = self.camera
        w, h = cam.resolution_px
        to_world = mi.ScalarTransform4f().look_at(
            origin=[0.0, 0.0, -cam.distance_cm], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0])
        return {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2, "rr_depth": 100,
                           "hide_emitters": False},
            "sensor": {
                "type": "perspective", "fov": cam.fov_deg, "fov_axis": "x",
                "to_world": to_world,
                # An offset of 1 / width moves the content 1 px left (1 / height: 1 px up).
                "principal_point_offset_x": -float(cam.shift_px[0]) / w,
                "principal_point_offset_y": -float(cam.shift_px[1]) / h,
                "film": {"type": "hdrfilm", "width": w, "height": h,
                         "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                "sampler": {"type": "multijitter", "sample_count": self.spp},
            },
            "env": {"type": "envmap", "bitmap": mi.Bitmap(self._envmap),
                    "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], self._rotation)},
            "sphere": {"type": "sphere", "radius": cam.radius_cm,
                       "bsdf": self._bsdf(rho_d, rho_s, alpha)},
        }

    def _load(self, rho_d: float, rho_s: float, alpha: float) -> None:
        mi = self._mi
        self._scene = mi.load_dict(self._scene_dict(rho_d, rho_s, alpha))
        params = mi.traverse(self._scene)
        keys = {name: f"sphere.bsdf.{name}" for name in ("rho_d", "rho_s", "alpha")}
        if not all(k in params for k in keys.values()):
            keys = {}
        self._params = params if len(keys) == 3 else None
        self._keys = keys
        self._current = (rho_d, rho_s, alpha)

    def render(self, rho_d: float, rho_s: float, alpha: float) -> np.ndarray:
        """Render the sphere with the given Ward parameters.

        Returns
        -------
        ndarray, float32, shape (height, width, 3)
            Linear radiance in the panorama's units, y down.
        """
        material = (float(rho_d), float(rho_s), float(alpha))
        if self._mi.variant() != FIT_VARIANT:
            raise RuntimeError(f"Mitsuba variant changed to {self._mi.variant()} while a gloss-fit "
                               f"scene ({FIT_VARIANT}) was open; close the scene first")
        if self._scene is None or (self._params is None and material != self._current):
            self._load(*material)
        elif material != self._current:
            for name, value in zip(("rho_d", "rho_s", "alpha"), material, strict=True):
                self._params[self._keys[name]] = value
            self._params.update()
            self._current = material
        image = self._mi.render(self._scene, seed=self.seed, spp=self.spp)
        self.n_renders += 1
        return np.array(image, dtype=np.float32)[..., :3]
