"""Rendering one stimulus: camera geometry, the Mitsuba scene (built once), luminance images.

Camera (protocol.md, "Stimuli"): the array lies in the plane z = 0, bumps towards the viewer, and a
pinhole camera sits on the z axis at the viewing distance ``D`` (the calibration's, 55 cm by
design) looking at the array centre, +y up. The image covers ``image_width_cm`` of the z = 0 plane
(the largest possible array footprint plus a margin), so its horizontal field of view is
``2 atan(image_width_cm / (2 D))``. Shown on the CRT at ``image_width_cm`` wide (native size
``image_width_cm / (width_cm / width_px)`` px, 237 px on the default 32 cm, 1024 px wide screen),
the image subtends at the eye exactly the angle the physical array would subtend in the screen
plane: the stimulus has its physical size. ``--size`` renders the same view at another pixel count
(previews); the manifest records ``image_width_cm``, so the experiment can always display it at its
physical size.

The scene is built once per (array, light probe) and re-rendered for each gloss level by updating
the Ward parameters in place with ``mi.traverse`` (no re-load, and the compiled kernel is reused
because the parameters are opaque). Each render may take its own sample count (the spp of its
gloss level, :mod:`stimuli.noise`); Dr.Jit compiles one kernel per sample count (a constant in
the kernel) and caches it.

What is left per image is Dr.Jit tracing the render again, the Python Ward BSDF included, to find
the cached kernel. Freezing the render (``dr.freeze``, which replays the recorded kernel launches
without tracing; one recording per scene and sample count) pays where the render itself is fast,
on a GPU: ``bench/stimuli_scene_reuse.py`` with cuda_ad_mono (issue 47) measured 1.18x at 256 px
and 2.8x at 128 px / 16 spp. On the CPU it buys little: interleaved image by image at 128 px and
16 spp (the cheapest render, where tracing weighs most), llvm_ad_mono, load average 7 on 2 cores,
measured re-use 1.152 s/image, frozen 1.121 s/image (identical images): 1.03x, i.e. tracing costs
about 30 ms per image, < 1 % of a 256 px render at the planned spp. So ``freeze=None`` (the
default) freezes under the ``cuda_ad_*`` variants only; the CPU tests render frozen and unfrozen
alike and compare the images. Re-loading the scene per image
instead took 1.67x as long as re-use; the first render at a new sample count took 3.2 s, the next
1.4 s (compile, then cache). Sampler: ``multijitter``. The film stores CIE Y
(``pixel_format = "luminance"``): in a monochrome variant (the default for the grey stimuli) the
scene is lit by the probe's luminance and the render *is* Y, exactly; in the spectral variant the
film integrates the spectrum against the CIE 1931 Y matching function; in the RGB variant Y is
formed from linear RGB. Any variant of :data:`stimuli.mitsuba_env.SUPPORTED_VARIANTS` works,
``cuda_ad_*`` included; the renderer records the one it loaded its scene under.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stimuli.geometry import ArrayGeometry, render_mesh
from stimuli.illumination import LightProbe
from stimuli.ward import check_ward_params

__all__ = [
    "CameraGeometry",
    "StimulusRenderer",
    "bsdf_is_achromatic",
    "camera_geometry",
    "multijitter_spp",
]

#: Border around the largest possible array footprint, cm (each side).
MARGIN_CM = 0.5


@dataclass(frozen=True)
class CameraGeometry:
    """Where the camera is and what it sees (cm, degrees).

    Attributes
    ----------
    image_width_cm : float
        Width (= height) of the z = 0 plane the square image covers.
    distance_cm : float
        Camera (eye) to array plane.
    fov_deg : float
        Horizontal field of view.
    native_px : int
        Image width in pixels at the display's pixel pitch.
    backing_half_cm : float
        Half-width of the backing square (well beyond the view, so no edge shows).
    """

    image_width_cm: float
    distance_cm: float
    fov_deg: float
    native_px: int
    backing_half_cm: float


def camera_geometry(design, calibration, *, margin_cm: float = MARGIN_CM) -> CameraGeometry:
    """Camera that shows the array at its physical size on the calibrated display.

    Parameters
    ----------
    design : StudyDesign
        Supplies the array's grid, radii and jitter.
    calibration : calibration.Calibration
        Supplies the screen's visible width (cm), resolution (px) and viewing distance (cm).
    margin_cm : float
        Border around the largest possible footprint, each side.
    """
    spec = design.array
    grid_half = float(np.max(np.abs(spec.grid_centres_cm())))
    half = grid_half + spec.jitter_cm + spec.radius_xy_cm + margin_cm
    width = 2.0 * half
    distance = float(calibration.distance_cm)
    fov = float(np.degrees(2.0 * np.arctan(width / (2.0 * distance))))
    pitch_cm = float(calibration.width_cm) / float(calibration.resolution_px[0])
    return CameraGeometry(image_width_cm=width, distance_cm=distance, fov_deg=fov,
                          native_px=round(width / pitch_cm), backing_half_cm=4.0 * half)


def multijitter_spp(spp: int) -> int:
    """The sample count Mitsuba's ``multijitter`` sampler really takes for a requested one.

    It lays samples on an a x b grid (a = floor(sqrt(spp)), b = ceil(spp / a)), so e.g. 32 becomes
    35; perfect squares (16, 64, 256) and products such as 8 = 2 x 4 are kept. Record this one.
    """
    import mitsuba as mi

    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    return int(mi.load_dict({"type": "multijitter", "sample_count": int(spp)}).sample_count())


def bsdf_is_achromatic(bsdf: dict | None) -> bool:
    """Whether a Mitsuba BSDF dict reflects every wavelength alike (grey).

    ``None`` stands for the Ward BSDF, whose reflectances are scalars: grey. Otherwise every
    nested value is inspected: a number is grey, an ``{"type": "rgb", "value": [r, g, b]}`` is grey
    when r = g = b, and anything else that can carry colour (spectra, bitmaps, other textures)
    counts as chromatic, so the caller keeps a colour variant.
    """
    if bsdf is None:
        return True

    def grey(value) -> bool:
        if isinstance(value, bool | int | float | str):
            return True
        if isinstance(value, dict):
            kind = value.get("type")
            if kind == "rgb":
                v = np.atleast_1d(np.asarray(value.get("value"), dtype=float))
                return bool(np.all(v == v[0]))
            if kind in ("spectrum", "bitmap", "irregular", "regular", "blackbody", "mesh_attribute",
                        "volume", "checkerboard"):
                return False
            return all(grey(v) for k, v in value.items() if k != "type")
        if isinstance(value, list | tuple):
            v = np.asarray(value, dtype=float)
            return v.ndim == 0 or bool(np.all(v == v.flat[0]))
        return False  # a Mitsuba object (texture instance): colour unknown

    return grey(bsdf)


def _mitsuba_mesh(mesh, bsdf):
    import mitsuba as mi

    props = mi.Properties()
    props["bsdf"] = bsdf
    m = mi.Mesh("ellipsoid_array", len(mesh.vertices), len(mesh.faces), props,
                has_vertex_normals=True)
    params = mi.traverse(m)
    params["vertex_positions"] = mi.Float(np.ravel(mesh.vertices).astype(np.float32))
    params["faces"] = mi.UInt32(np.ravel(mesh.faces).astype(np.uint32))
    params["vertex_normals"] = mi.Float(np.ravel(mesh.normals).astype(np.float32))
    params.update()
    return m


class StimulusRenderer:
    """A Mitsuba scene of one array under one light probe, re-rendered per Ward material.

    Use :meth:`load` to (re)build the scene for an array and probe (a no-op when they are the
    ones already loaded) and :meth:`render` for each material. Needs :func:`stimuli.setup_mitsuba`.

    Parameters
    ----------
    camera : CameraGeometry
    size_px : int
        Image width = height, px.
    spp : int
        Samples per pixel (multijitter; rounded as :func:`multijitter_spp`, see ``.spp``).
    max_depth : int
        Path length limit (5: light bounces between neighbouring bumps are kept).
    bsdf : dict, optional
        Another Mitsuba BSDF dict instead of ``ward`` (benchmarks compare with ``roughplastic``);
        :meth:`render` then only re-renders (pass ``None`` parameters). A chromatic one
        (:func:`bsdf_is_achromatic` False) is refused under a monochrome variant.
    integrator : dict, optional
        Another Mitsuba integrator dict (tests compare ``direct`` sampling strategies); default
        ``{"type": "path", "max_depth": max_depth}``.
    split_sun : bool
        Light the scene with the probe's brightest small region as a light of its own and the
        rest as the environment map (:mod:`stimuli.sunsplit`; the same expected image).
    freeze : bool, optional
        Replay each (scene, sample count)'s recorded kernels (``dr.freeze``) instead of tracing
        every render; default (None): on the ``cuda_ad_*`` variants, where it pays.

    Attributes
    ----------
    variant : str or None
        The Mitsuba variant the scene was loaded under (record it with the render).
    """

    def __init__(self, camera: CameraGeometry, *, size_px: int, spp: int, max_depth: int = 5,
                 bsdf: dict | None = None, integrator: dict | None = None,
                 freeze: bool | None = None, split_sun: bool = False):
        self.bsdf = bsdf
        self.split_sun = bool(split_sun)
        self.freeze = freeze
        self._frozen = {}
        self.integrator = integrator
        if size_px < 8 or spp < 1:
            raise ValueError(f"size_px must be >= 8 and spp >= 1, got {size_px}, {spp}")
        self.camera = camera
        self.size_px = int(size_px)
        self.spp = multijitter_spp(int(spp))  # the count really used (and recorded)
        self.max_depth = int(max_depth)
        self.scene = None
        self.params = None
        self.variant = None
        self._key = None
        self._keys = {}
        self._spp_cache = {int(spp): self.spp}
        self.n_loads = 0

    def spp_for(self, spp: int | None) -> int:
        """The multijitter sample count a render asked for ``spp`` takes (``None``: ``.spp``)."""
        if spp is None:
            return self.spp
        if int(spp) not in self._spp_cache:
            self._spp_cache[int(spp)] = multijitter_spp(int(spp))
        return self._spp_cache[int(spp)]

    def load(self, geometry: ArrayGeometry, probe: LightProbe) -> None:
        """Build the scene for ``geometry`` lit by ``probe`` (skipped when already loaded)."""
        import mitsuba as mi

        from stimuli.errors import MitsubaSetupError
        from stimuli.mitsuba_env import is_monochrome

        variant = mi.variant()
        if variant is None:
            raise MitsubaSetupError("no Mitsuba variant is set; call stimuli.setup_mitsuba() first")
        key = (variant, geometry.seed, geometry.depth_cm, probe.sha256, probe.rotation_deg,
               probe.scale)
        if key == self._key:
            return
        if is_monochrome(variant) and not bsdf_is_achromatic(self.bsdf):
            raise MitsubaSetupError(
                f"the BSDF {self.bsdf} is chromatic, which the monochrome variant {variant} cannot "
                "render; use a spectral variant (e.g. --variant llvm_ad_spectral)")
        cam = self.camera
        bsdf = mi.load_dict(self.bsdf or {"type": "ward", "id": "ward"})
        mesh = _mitsuba_mesh(render_mesh(geometry, backing_half_cm=cam.backing_half_cm), bsdf)
        film_format = "luminance"
        self.scene = mi.load_dict({
            "type": "scene",
            "integrator": self.integrator or {"type": "path", "max_depth": self.max_depth},
            "sensor": {
                "type": "perspective",
                "fov": cam.fov_deg,
                "fov_axis": "x",
                "near_clip": 1.0,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0.0, 0.0, cam.distance_cm], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]),
                "film": {"type": "hdrfilm", "width": self.size_px, "height": self.size_px,
                         "pixel_format": film_format, "rfilter": {"type": "gaussian"}},
                "sampler": {"type": "multijitter", "sample_count": self.spp},
            },
            **self._emitters(probe),
            "array": mesh,
        })
        self.params = mi.traverse(self.scene)
        self._keys = {name: next((k for k in self.params.properties if k.endswith("." + name)),
                                 None) for name in ("rho_d", "rho_s", "alpha")}
        self._key = key
        self.variant = variant
        self._frozen = {}  # recordings of the previous scene
        self.n_loads += 1

    def _emitters(self, probe: LightProbe) -> dict:
        if not self.split_sun:
            return {"emitter": probe.emitter()}
        from stimuli.sunsplit import split_emitters

        return split_emitters(probe)

    def render(self, rho_d: float, rho_s: float, alpha: float, *, seed: int = 0,
               spp: int | None = None) -> np.ndarray:
        """Render the loaded scene with these Ward parameters.

        Parameters
        ----------
        rho_d, rho_s, alpha : float
            Ward diffuse and specular reflectance and lobe width (:mod:`stimuli.ward`).
        seed : int
            Sampler seed (renders with different seeds are independent).
        spp : int, optional
            Samples per pixel for this render (rounded as :func:`multijitter_spp`, see
            :meth:`spp_for`); default: the renderer's ``spp``.

        Returns
        -------
        ndarray, shape (size_px, size_px), float32
            Luminance (CIE Y) in the probe's relative radiance units.

        Raises
        ------
        ValueError
            Bad Ward parameters, or a render holding NaN/Inf.
        """
        import mitsuba as mi

        if self.scene is None:
            raise RuntimeError("StimulusRenderer.render before load(geometry, probe)")
        if mi.variant() != self.variant:
            raise RuntimeError(f"the scene was loaded under {self.variant} but the active Mitsuba "
                               f"variant is {mi.variant()}; call load() again after switching")
        if self.bsdf is None:
            check_ward_params(rho_d, rho_s, alpha)
            self.params[self._keys["rho_d"]] = mi.Float(float(rho_d))
            self.params[self._keys["rho_s"]] = mi.Float(float(rho_s))
            self.params[self._keys["alpha"]] = mi.Float(float(alpha))
            self.params.update()
        n = self.spp_for(spp)
        seed = int(seed) & 0x7FFFFFFF
        freeze = self.variant.startswith("cuda") if self.freeze is None else self.freeze
        if freeze:
            img = np.asarray(self._frozen_render(n)(self.scene, mi.UInt32(seed)))
        else:
            img = np.asarray(mi.render(self.scene, spp=n, seed=seed))
        img = img[..., 0] if img.ndim == 3 else img
        if not np.all(np.isfinite(img)):
            raise ValueError("the render holds NaN/Inf luminance; check the light probe and mesh")
        return np.ascontiguousarray(img, dtype=np.float32)

    def _frozen_render(self, spp: int):
        """The render at ``spp`` samples, frozen (``dr.freeze``) once per loaded scene."""
        if spp not in self._frozen:
            import drjit as dr
            import mitsuba as mi

            def render(scene, seed):
                return mi.render(scene, spp=spp, seed=seed)

            self._frozen[spp] = dr.freeze(render)
        return self._frozen[spp]
