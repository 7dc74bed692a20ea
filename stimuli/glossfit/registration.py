"""Registration of a photo onto the fit renders' pixel grid (the source study's affine Nelder-Mead).

The seed registers each photo to a reference render by Nelder-Mead (MATLAB's ``fminsearch``)
over x-scale, y-scale, x-shift and y-shift of an affine warp, minimising the pixel-wise SSE. Here
the warp maps a fit-render pixel (u, v) to photo coordinates::

    x = cx + dx + sx * k * (u - u0),    y = cy + dy + sy * k * (v - v0)

where (u0, v0) is the sphere centre in the render, (cx, cy) the sphere-centre guess in the photo
and k the photo's pixels per render pixel; (sx, sy, dx, dy) = (1, 1, 0, 0) is the geometry of
setup.toml. Both images are compared as log luminance, each divided by its mean first, so the
photo's exposure does not matter and a highlight that differs between the photo and the reference
render weighs no more than the silhouette. A coarse search over shifts (up to one sphere radius) precedes
Nelder-Mead so that a poor centre guess still converges.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import ndimage, optimize

from stimuli.glossfit.photoset import GlossFitError, PhotoSetup
from stimuli.glossfit.scene import Camera, luminance, photo_camera

__all__ = ["Registration", "register", "warp_photo"]


@dataclass(frozen=True)
class Registration:
    """An affine registration of one photo.

    Attributes
    ----------
    sx, sy : float
        Scale relative to the setup's geometry (1 = as setup.toml says).
    dx_px, dy_px : float
        Shift of the sphere centre from the guess, in photo pixels (x right, y down).
    sse : float
        Mean squared difference of the normalised luminances at the optimum.
    background_ratio : float
        Mean photo / mean render luminance over the background: 1 when photo and panorama are in
        the same radiometric units.
    background_mismatch : float
        RMS difference of photo and render over the background, each divided by its mean (0 when
        they agree; large when the photo was not taken in the panorama's room).
    """

    sx: float
    sy: float
    dx_px: float
    dy_px: float
    sse: float
    background_ratio: float
    background_mismatch: float

    def to_dict(self) -> dict:
        return asdict(self)


def _coords(params, fit_cam: Camera, photo_cam: Camera, centre_px, n: int) -> np.ndarray:
    """Indices into the n-binned photo of each fit pixel's centre, shape (2, h, w)."""
    sx, sy, dx, dy = params
    w, h = fit_cam.resolution_px
    k = photo_cam.focal_px / fit_cam.focal_px
    u0, v0 = fit_cam.centre_px
    v, u = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    x = centre_px[0] + dx + sx * k * (u - u0)
    y = centre_px[1] + dy + sy * k * (v - v0)
    # map_coordinates indexes pixel centres at integers: subtract half a (binned) pixel.
    return np.stack([y / n - 0.5, x / n - 0.5])


def _bin(image: np.ndarray, n: int) -> np.ndarray:
    """Mean over n x n blocks of photo pixels (a camera with n times larger pixels)."""
    if n == 1:
        return image.astype(np.float64)
    h, w = (image.shape[0] // n) * n, (image.shape[1] // n) * n
    cut = image[:h, :w].astype(np.float64)
    return cut.reshape(h // n, n, w // n, n, *image.shape[2:]).mean(axis=(1, 3))


def _binning(fit_cam: Camera, photo_cam: Camera) -> int:
    return max(1, round(photo_cam.focal_px / fit_cam.focal_px))


def _log_normalised(image: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
    """log(image / mean), floored at 1 % of the mean: highlights weigh no more than edges."""
    mean = image.mean() if where is None else image[where].mean()
    return np.log(np.maximum(image / mean, 0.01))


def warp_photo(image: np.ndarray, registration: Registration, fit_cam: Camera,
               setup: PhotoSetup, *, order: int = 3) -> np.ndarray:
    """Resample a photo (or a per-pixel map of it) onto the fit renders' pixel grid.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, c)
        In photo pixels.
    registration : Registration
    fit_cam : Camera
        The fit renders' camera.
    setup : PhotoSetup
    order : int
        Spline order: 3 (cubic, default: keeps highlights sharp), 1 (bilinear, for masks).

    The photo is first binned to the fit pixels' size (``scene.fit_binning``), then resampled
    at the registered sub-pixel positions.

    Returns
    -------
    ndarray, shape (h, w) or (h, w, c), float32
        Pixels outside the photo are 0.
    """
    photo_cam = photo_camera(setup)
    n = _binning(fit_cam, photo_cam)
    coords = _coords((registration.sx, registration.sy, registration.dx_px, registration.dy_px),
                     fit_cam, photo_cam, setup.centre_px, n)
    binned = _bin(image, n)
    if binned.ndim == 2:
        binned = binned[..., None]
    out = np.stack([ndimage.map_coordinates(binned[..., c], coords, order=order, mode="constant",
                                            cval=0.0) for c in range(binned.shape[2])], axis=-1)
    out = np.clip(out, 0.0, None).astype(np.float32)
    return out[..., 0] if image.ndim == 2 else out


def register(photo: np.ndarray, reference: np.ndarray, fit_cam: Camera, setup: PhotoSetup,
             *, valid: np.ndarray | None = None, max_scale_error: float = 0.25,
             name: str = "photo") -> Registration:
    """Register a photo to a reference render (the source study's affine Nelder-Mead).

    Parameters
    ----------
    photo : ndarray, shape (H, W, 3)
        Linear HDR photo (any exposure).
    reference : ndarray, shape (h, w, 3)
        Reference render on the fit grid, background included.
    fit_cam : Camera
        The reference render's camera.
    setup : PhotoSetup
    valid : ndarray of bool, shape (H, W), optional
        Photo pixels to use (e.g. not clipped); all when None.
    max_scale_error : float
        A fitted scale further than this from 1 (relative) means the sphere was not found.
    name : str
        The photo's name, for error messages.

    Returns
    -------
    Registration

    Raises
    ------
    GlossFitError
        If the sphere is not found: the optimum lies on a scale more than ``max_scale_error``
        from the setup's, or moves the sphere by more than its radius from the guess, or the
        photo does not resemble the render (correlation < 0.5 over the frame).
    """
    photo_cam = photo_camera(setup)
    sample = _sampler(photo, fit_cam, photo_cam, setup, valid)
    ref = _log_normalised(luminance(reference).astype(np.float64))

    def cost(params):
        img, wgt = sample(params)
        good = wgt > 0.99
        if good.sum() < 0.5 * good.size:
            return 1e6
        return float(np.mean((_log_normalised(img, good)[good] - ref[good]) ** 2))

    radius_photo_px = fit_cam.sphere_radius_px * photo_cam.focal_px / fit_cam.focal_px
    res = _minimise(cost, radius_photo_px)
    sx, sy, dx, dy = (float(v) for v in res.x)
    if max(abs(sx - 1), abs(sy - 1)) > max_scale_error:
        raise GlossFitError(
            f"{name}: sphere not found (registration scale {sx:.2f} x {sy:.2f}, expected about "
            f"1); check fov_deg, camera_distance_cm and sphere_radius_cm in setup.toml")
    if np.hypot(dx, dy) > 1.5 * radius_photo_px:
        raise GlossFitError(
            f"{name}: sphere not found near the centre guess (moved {np.hypot(dx, dy):.1f} px); "
            f"set sphere_centre_px in setup.toml")
    img, wgt = sample(res.x)
    good = wgt > 0.99
    corr = float(np.corrcoef(_log_normalised(img, good)[good], ref[good])[0, 1])
    if not corr > 0.5:
        raise GlossFitError(
            f"{name}: sphere not found (correlation with the reference render {corr:.2f}); is "
            f"the photo taken in the room of envmap.exr, with the sphere in view?")
    bg_ratio, bg_mismatch = _background(img, good, reference, fit_cam)
    return Registration(sx=sx, sy=sy, dx_px=dx, dy_px=dy, sse=float(res.fun),
                        background_ratio=bg_ratio, background_mismatch=bg_mismatch)


def _sampler(photo: np.ndarray, fit_cam: Camera, photo_cam: Camera, setup: PhotoSetup,
             valid: np.ndarray | None):
    """``sample(params) -> (luminance, weight)``: the photo's luminance (0 where not
    ``valid``), binned to the fit pixels' size and resampled bilinearly on the fit grid under
    the warp ``params`` = (sx, sy, dx, dy), with the share of valid photo pixels under each."""
    lum = luminance(photo)
    if valid is not None:
        lum = np.where(valid, lum, 0.0)
    n = _binning(fit_cam, photo_cam)
    blurred = _bin(lum, n)
    weight = _bin(np.ones_like(lum) if valid is None else valid.astype(np.float32), n)
    centre = setup.centre_px

    def sample(params):
        coords = _coords(params, fit_cam, photo_cam, centre, n)
        img = ndimage.map_coordinates(blurred, coords, order=1, mode="constant", cval=0.0)
        wgt = ndimage.map_coordinates(weight, coords, order=1, mode="constant", cval=0.0)
        return img, wgt

    return sample


def _minimise(cost, radius_photo_px: float) -> optimize.OptimizeResult:
    """The source study's Nelder-Mead over (sx, sy, dx, dy), started from the best of a 9 x 9
    grid of shifts up to one sphere radius (photo px), so that a poor centre guess converges."""
    shifts = np.linspace(-radius_photo_px, radius_photo_px, 9)
    start = min(((1.0, 1.0, dx, dy) for dx in shifts for dy in shifts), key=cost)
    step = 0.25 * radius_photo_px
    simplex = np.array([start, *(np.array(start) + np.diag([0.05, 0.05, step, step]))])
    return optimize.minimize(cost, start, method="Nelder-Mead",
                             options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-7,
                                      "maxiter": 800})


def _background(img: np.ndarray, good: np.ndarray, reference: np.ndarray, fit_cam: Camera
                ) -> tuple[float, float]:
    """``Registration.background_ratio`` and ``background_mismatch`` of the registered photo
    luminance ``img`` against the reference render, over the valid pixels outside 1.1 sphere
    radii; NaN when too few (10) or dark."""
    w, h = fit_cam.resolution_px
    v, u = np.mgrid[0:h, 0:w] + 0.5
    bg = (np.hypot(u - fit_cam.centre_px[0], v - fit_cam.centre_px[1])
          > 1.1 * fit_cam.sphere_radius_px) & good
    raw_ref = luminance(reference)
    if bg.sum() > 10 and raw_ref[bg].mean() > 0 and img[bg].mean() > 0:
        bg_ratio = float(img[bg].mean() / raw_ref[bg].mean())
        bg_mismatch = float(np.sqrt(np.mean((img[bg] / img[bg].mean()
                                             - raw_ref[bg] / raw_ref[bg].mean()) ** 2)))
        return bg_ratio, bg_mismatch
    return float("nan"), float("nan")
