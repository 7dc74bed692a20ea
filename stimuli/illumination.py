"""HDR light probes: lat-long OpenEXR or Radiance maps -> checked float32 arrays -> Mitsuba
``envmap`` emitters.

EXRs are decoded with the OpenEXR package, never with Mitsuba's bundled decoder (which read some
DWAB-compressed maps differently when tried). A probe is a linear-RGB equirectangular map, rows
from the zenith (top) to the nadir, columns covering 360 deg of azimuth; Mitsuba's ``envmap``
takes the same layout with +y up, which is the stimulus's up (the array hangs fronto-parallel like a
picture on a wall, the sky above it).

Radiance ``.hdr`` files are decoded by :mod:`stimuli.rgbe`.

The shipped probes (``stimuli/probes``, CC0 Poly Haven, see ``probes/LICENSE.txt`` and
``probes/lightfields.tsv``) are the design's light fields: 22 real, unclipped captures, two of
which light the experiment; any lab probe (e.g. SYNS) is accepted by path. Their scale is the
design's (:func:`diffuse_white_scale`): the files are not absolutely calibrated.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from labfiles import atomic_path
from stimuli.errors import IlluminationError
from stimuli.manifest import sha256_file
from studydesign import REC709_Y, rec709_luminance

__all__ = [
    "NORMALISE_MODES",
    "REC709_Y",
    "SHIPPED_PROBES",
    "LightProbe",
    "diffuse_white_luminance",
    "diffuse_white_scale",
    "downsample_latlong",
    "load_light_probe",
    "luminance",
    "probe_path",
    "read_exr",
    "read_probe_image",
    "rotate_latlong",
    "solid_angle_weights",
    "write_exr",
]

#: Folder of the light probes shipped with the package.
SHIPPED_PROBES = Path(__file__).resolve().parent / "probes"
#: Intensity normalisations: none; scale so the solid-angle-weighted mean luminance = target; or
#: so that a matte white facing the viewer has luminance = target (:func:`diffuse_white_scale`).
NORMALISE_MODES = ("none", "mean_luminance", "diffuse_white")
#: Negative values down to this fraction of the mean |value| are compression ringing, set to 0.
NEGATIVE_TOLERANCE = 1e-3


def probe_path(name_or_path: str | os.PathLike) -> Path:
    """Resolve a probe given by path, or by file name among :data:`SHIPPED_PROBES`.

    Raises
    ------
    IlluminationError
        If neither exists; the message lists the shipped probes.
    """
    p = Path(name_or_path)
    if p.is_file():
        return p
    shipped = SHIPPED_PROBES / p.name
    if not p.parent.parts and shipped.is_file():
        return shipped
    have = sorted(f.name for f in SHIPPED_PROBES.iterdir() if f.suffix in (".exr", ".hdr"))
    raise IlluminationError(
        f"light probe {str(name_or_path)!r} not found (neither a file nor one of the shipped probes "
        f"{have} in {SHIPPED_PROBES}); give the path of a lat-long OpenEXR or Radiance .hdr file"
    )


def read_probe_image(path: str | os.PathLike) -> np.ndarray:
    """Read a light probe file: OpenEXR (:func:`read_exr`) or Radiance RGBE
    (:func:`stimuli.rgbe.read_rgbe`), told apart by their first bytes.

    Returns
    -------
    ndarray, shape (h, w, 3) or (h, w), float32
        Linear values as stored.
    """
    from stimuli.rgbe import is_rgbe, read_rgbe

    path = Path(path)
    if path.is_file() and is_rgbe(path):
        return read_rgbe(path)
    return read_exr(path)


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read an OpenEXR image with the OpenEXR package.

    Parameters
    ----------
    path : path-like
        An RGB (or single-channel Y) OpenEXR file.

    Returns
    -------
    ndarray, shape (height, width, 3) or (height, width), float32
        Linear values as stored (RGB when the file has R, G, B; else its single channel).

    Raises
    ------
    IlluminationError
        If the file is missing, not an OpenEXR file, truncated/corrupt, or lacks RGB/Y channels.
    """
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise IlluminationError(f"EXR file {path} does not exist; check the path")
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"\x76\x2f\x31\x01":
        raise IlluminationError(
            f"{path} is not an OpenEXR file (bad magic number); convert it to OpenEXR "
            "(e.g. `oiiotool in.hdr -o out.exr`)")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            channels = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except Exception as exc:  # the OpenEXR binding raises RuntimeError/ValueError with C++ text
        raise IlluminationError(
            f"cannot decode EXR {path} ({exc}); the file is truncated or corrupt: re-copy or "
            "re-export it") from exc
    names = set(channels)
    if {"R", "G", "B"} <= names:
        out = np.stack([channels[c] for c in ("R", "G", "B")], axis=-1)
    elif "Y" in names:
        out = channels["Y"]
    elif len(names) == 1:
        out = next(iter(channels.values()))
    else:
        raise IlluminationError(
            f"EXR {path} has channels {sorted(names)}; expected R, G, B (or a single Y channel)")
    return np.ascontiguousarray(out, dtype=np.float32)


def write_exr(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write a float32 OpenEXR (ZIP, lossless) atomically: a temporary file, then ``os.replace``.

    Parameters
    ----------
    path : path-like
        Destination ``.exr``.
    image : ndarray, shape (h, w) or (h, w, 3)
        Linear values; (h, w) is written as channel Y, (h, w, 3) as R, G, B.

    Returns
    -------
    Path
        ``path``. An interrupted write leaves at most a ``*.tmp-*.exr`` file, never ``path``.
    """
    import OpenEXR

    path = Path(path)
    image = np.ascontiguousarray(image, dtype=np.float32)
    if image.ndim == 2:
        channels = {"Y": image}
    elif image.ndim == 3 and image.shape[2] == 3:
        channels = {c: np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")}
    else:
        raise ValueError(f"write_exr needs shape (h, w) or (h, w, 3), got {image.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp, OpenEXR.File(header, channels) as f:
        f.write(str(tmp))
    return path


def luminance(rgb: np.ndarray) -> np.ndarray:
    """CIE Y of linear Rec. 709 RGB, shape (..., 3) -> (...); same units as the input
    (``studydesign.rec709_luminance``)."""
    return rec709_luminance(rgb)


def solid_angle_weights(height: int, width: int) -> np.ndarray:
    """Solid angle (sr) of each pixel of a lat-long map, shape (height, width); sums to 4 pi."""
    theta_edges = np.linspace(0.0, np.pi, height + 1)
    band = np.cos(theta_edges[:-1]) - np.cos(theta_edges[1:])
    return np.repeat((band * 2 * np.pi / width)[:, None], width, axis=1)


def _front_cosine(height: int, width: int) -> np.ndarray:
    """cos of the angle to +z (towards the viewer) of each pixel's direction, clipped at 0.

    Mitsuba's ``envmap`` maps a direction d to u = atan2(d_x, -d_z) / 2 pi, v = acos(d_y) / pi,
    so the centre column (u = 1/2) is +z, the light that falls on the array's front.
    """
    theta = (np.arange(height) + 0.5) / height * np.pi
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    return np.clip(-np.cos(phi)[None, :] * np.sin(theta)[:, None], 0.0, None)


def diffuse_white_luminance(rgb: np.ndarray) -> float:
    """Luminance of a matte white (Lambertian, albedo 1) facing the viewer, lit by a lat-long map.

    L_white = (1 / pi) * integral over the front hemisphere of Y(w) cos(w, +z) dw, the irradiance
    of the array's plane over pi (occlusion by the array itself left out). Same units as ``rgb``.
    """
    y = luminance(np.asarray(rgb, dtype=np.float64))
    h, w = y.shape
    return float(np.sum(y * solid_angle_weights(h, w) * _front_cosine(h, w)) / np.pi)


def diffuse_white_scale(rgb: np.ndarray, *, target: float = 1.0) -> float:
    """Factor that makes :func:`diffuse_white_luminance` of ``rgb`` equal ``target``.

    The design's scale of each light field (``python -m stimuli probe-scale FILE`` prints it):
    captures are not absolutely calibrated, so each is scaled so that a matte white facing the
    viewer has the same luminance under every light field (protocol.md, section 4).

    Raises
    ------
    IlluminationError
        If no light falls on the front hemisphere.
    """
    white = diffuse_white_luminance(rgb)
    if not white > 0:
        raise IlluminationError("the probe sends no light onto the array's front (+z "
                                "hemisphere); check the file and its orientation")
    return float(target) / white


def downsample_latlong(image: np.ndarray, factor: int) -> np.ndarray:
    """Shrink a lat-long map by an integer ``factor`` in each direction, keeping its energy.

    Each output pixel is the solid-angle-weighted mean of the ``factor`` x ``factor`` pixels it
    covers, so the radiant power from every region of the sphere (a sun spread over fewer,
    larger pixels included) is the same as in the input.

    Parameters
    ----------
    image : ndarray, shape (h, w, 3) or (h, w)
        h and w multiples of ``factor``.
    factor : int
        >= 1.

    Returns
    -------
    ndarray, shape (h / factor, w / factor[, 3]), float32
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape[:2]
    if factor < 1 or h % factor or w % factor:
        raise ValueError(f"cannot shrink a {w} x {h} map by {factor}: use a factor >= 1 that "
                         "divides both sides")
    om = solid_angle_weights(h, w)
    om = om.reshape(om.shape + (1,) * (img.ndim - 2))
    shape = (h // factor, factor, w // factor, factor) + img.shape[2:]
    num = (img * om).reshape(shape).sum(axis=(1, 3))
    den = np.broadcast_to(om, img.shape).reshape(shape).sum(axis=(1, 3))
    return (num / den).astype(np.float32)


def rotate_latlong(image: np.ndarray, degrees: float) -> np.ndarray:
    """Rotate a lat-long map about the vertical axis by ``degrees`` of azimuth (new array).

    Whole-pixel shifts are exact (a column roll); fractional shifts interpolate linearly between
    neighbouring columns with wrap-around.
    """
    w = image.shape[1]
    shift = (float(degrees) / 360.0) * w
    k = int(np.floor(shift))
    frac = shift - k
    a = np.roll(image, k, axis=1)
    if frac < 1e-9:
        return a.copy()
    b = np.roll(image, k + 1, axis=1)
    return ((1.0 - frac) * a + frac * b).astype(image.dtype)


@dataclass(frozen=True)
class LightProbe:
    """A checked light probe ready to light a scene.

    Attributes
    ----------
    name : str
        File name of the probe (e.g. ``noon_grass_256.hdr``).
    path : str
        Where it was read from.
    sha256 : str
        Checksum of the file, recorded with the renders.
    rgb : ndarray, shape (h, w, 3), float32
        Linear RGB radiance after rotation and scaling (relative units).
    rotation_deg : float
        Azimuthal rotation applied, degrees.
    scale : float
        Factor applied to the file's values.
    n_clamped : int
        Values within rounding of 0 but negative (compression ringing) that were set to 0.
    """

    name: str
    path: str
    sha256: str
    rgb: np.ndarray
    rotation_deg: float
    scale: float
    n_clamped: int = 0

    @property
    def luminance(self) -> np.ndarray:
        """CIE Y of the map, shape (h, w)."""
        return luminance(self.rgb)

    def emitter(self) -> dict:
        """A Mitsuba ``envmap`` emitter dict built from the in-memory bitmap (needs a variant set).

        Under a monochrome variant (``*_mono``) the map is given as its CIE Y (:attr:`luminance`,
        converted once here), which is what a grey scene reflects: the render is then the
        luminance of the colour render, exactly (protocol.md, section 4). RGB and spectral
        variants get the RGB map (spectral ones upsample each texel to a spectrum).

        References
        ----------
        Karlik, O., Sik, M., Vevoda, P., Skrivan, T. & Krivanek, J. (2019). MIS compensation:
        optimizing sampling techniques in multiple importance sampling. ACM TOG 38(6), 151.
        """
        import mitsuba as mi

        from stimuli.mitsuba_env import is_monochrome

        # MIS compensation (Karlik et al. 2019): the path tracer combines emitter sampling with
        # the BSDF's own sampling by multiple importance sampling, so the emitter's sampling
        # density is sharpened towards the bright texels (mean subtracted) while BSDF sampling
        # covers the rest. Unbiased; on the indoor probe it lowered the displayed error by
        # 13-17 % at equal spp (protocol.md, section 4).
        image = self.luminance[..., None] if is_monochrome(mi.variant()) else self.rgb
        return {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(image)),
                "mis_compensation": True}


def load_light_probe(
    name_or_path: str | os.PathLike,
    *,
    rotation_deg: float = 0.0,
    normalise: str = "mean_luminance",
    target: float = 1.0,
    scale: float | None = None,
) -> LightProbe:
    """Read, check, rotate and scale a lat-long HDR light probe (OpenEXR or Radiance ``.hdr``).

    Parameters
    ----------
    name_or_path : str or path-like
        A file, or the name of a shipped probe (``noon_grass_256.hdr``).
    rotation_deg : float
        Azimuthal rotation about the vertical axis, degrees.
    normalise : {"none", "mean_luminance", "diffuse_white"}
        "mean_luminance" scales the map so its solid-angle-weighted mean CIE Y equals ``target``;
        "diffuse_white" so that a matte white facing the viewer has luminance ``target``
        (:func:`diffuse_white_scale`). Ignored when ``scale`` is given.
    target : float
        Mean luminance or diffuse white's luminance after normalisation (relative units), > 0.
    scale : float, optional
        The factor applied to the file's values (the design's scale of a light field), > 0;
        replaces ``normalise``.

    Raises
    ------
    IlluminationError
        Missing/corrupt file, not 2:1 lat-long, NaN/Inf/negative radiance, all-black map.
    """
    if normalise not in NORMALISE_MODES:
        raise ValueError(f"normalise={normalise!r}; choose one of {list(NORMALISE_MODES)}")
    if not target > 0:
        raise ValueError(f"target mean luminance must be > 0, got {target}")
    if scale is not None and not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"light probe scale must be a finite number > 0, got {scale}")
    path = probe_path(name_or_path)
    img = read_probe_image(path)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    h, w = img.shape[:2]
    if w != 2 * h:
        raise IlluminationError(
            f"light probe {path} is {w} x {h} px; a lat-long map is twice as wide as high "
            "(convert cube maps or mirror-ball images to equirectangular first)")
    bad = ~np.isfinite(img)
    if bad.any():
        raise IlluminationError(
            f"light probe {path} holds {int(bad.any(axis=-1).sum())} pixels of NaN/Inf radiance; "
            "fill or clamp them (e.g. `oiiotool in.exr --fixnan box3 -o out.exr`)")
    # Lossy-compressed probes ring slightly below 0 near dark edges: values within
    # NEGATIVE_TOLERANCE of the mean are set to 0 (counted in LightProbe.n_clamped); larger
    # negatives mean a broken file.
    tol = NEGATIVE_TOLERANCE * float(np.mean(np.abs(img)))
    if (img < -tol).any():
        raise IlluminationError(
            f"light probe {path} holds negative radiance (min {img.min():.3g}); clamp at 0 "
            "(`oiiotool in.exr --clamp:min=0 -o out.exr`)")
    n_clamped = int((img < 0).sum())
    img = np.maximum(img, 0.0)
    y = luminance(img)
    mean_y = float(np.sum(y * solid_angle_weights(h, w)) / (4 * np.pi))
    if not mean_y > 0:
        raise IlluminationError(f"light probe {path} is black (mean luminance 0); check the file")
    if scale is None:
        scale = {"none": 1.0, "mean_luminance": target / mean_y}.get(normalise)
        if normalise == "diffuse_white":
            scale = diffuse_white_scale(img, target=target)
    rgb = (rotate_latlong(img, rotation_deg) if rotation_deg else img) * np.float32(scale)
    return LightProbe(name=path.name, path=str(path), sha256=sha256_file(path),
                      rgb=rgb.astype(np.float32), rotation_deg=float(rotation_deg),
                      scale=float(scale), n_clamped=n_clamped)
