"""The render layer's simulation: what the renders predict of the photos, and how likely
the photos are under that prediction.

- the photo's noise (:func:`noise_model`, :func:`noise_sd`): Poisson-Gaussian, measured from
  the second differences of photo - render when the files are read (``data.load_render``);
- the effects' image-forming forms the candidates' terms use: wider lobes (``_wings``,
  ``_wider_lobe``), the glare's blur (``_glare_blur``), the scene shifted with the
  silhouette's pixel coverage recomputed (``_shift_scene``, ``_coverage``, ``_fill``);
- the extended render (``_basis``: each registered candidate's term in the catalogue's order;
  ``_predict``: with the diffuse and specular scales re-fitted) and its Gaussian NLL per pixel
  (:func:`render_loss`);
- the pixel units and the held-out split (:func:`render_unit_ids`, :func:`split_render`);
- the fit helpers the candidates share: the scales' least-squares fit (``_scaled_fit``,
  ``_scaled_sse``, ``_scaled_residuals``); one bounded amplitude with a form from a grid is
  ``candidates._fit_amp``.

The bottom of the layer: it imports nothing else of it at run time (the reader, ``data``,
measures the noise with it).
"""

from __future__ import annotations

import functools
import hashlib
import weakref
from collections import OrderedDict
from typing import TYPE_CHECKING

import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage, signal

from analysis.gap.engine import GapError, catalogue
from analysis.gap.render.optics.sphere import _fill

if TYPE_CHECKING:
    from analysis.gap.render.data import RenderData


def _wings(S: np.ndarray, width: float, inside: np.ndarray) -> np.ndarray:
    """A wider lobe from the fitted one. ``width`` >= 1: Gaussian blur of that many px within
    the sphere (``inside``: the share of each pixel the sphere covers; a wider lobe moves light
    across the sphere, not onto the background); ``width`` in (0, 1): the lobe raised to that
    power (Ward's lobe exp(-tan^2 / alpha^2) raised to alpha^2 / alpha_t^2 is the lobe of the
    wider alpha_t), rescaled to the same energy; ``width`` < 0: the lobe spread within the
    sphere (as the Gaussian) by a kernel 1 / (1 + (r / w)^2), w = -width px: the GTR1 haze
    of Burley (2012, eq. 4), whose tails fall as the square of the angle (tan^-2) where a Ward
    lobe's fall as a Gaussian -- with angle ~ distance on the sphere near the highlight."""
    if width < 0:
        def blur(im):
            h, w = im.shape
            yy, xx = np.mgrid[-h:h + 1, -w:w + 1]
            kern = 1 / (1 + (yy**2 + xx**2) / width**2)
            return signal.fftconvolve(im, kern / kern.sum(), mode="same")
    elif width >= 1:
        def blur(im):
            return ndimage.gaussian_filter(im, width)
    if width < 0 or width >= 1:  # each image blurred once (_remembered)
        blurred = _remembered("wings", width, S * inside, blur)
        weight = _remembered("wings", width, inside, blur)
        return np.where(inside > 0, blurred / np.maximum(weight, 1e-6), 0.0) * inside
    top = float(S.max())
    if top <= 0:
        return S
    wide = top * np.clip(S / top, 0, None) ** width
    return wide * (S.sum() / max(wide.sum(), 1e-12))


def _wider_lobe(lv: dict, S: np.ndarray, other: str) -> np.ndarray:
    """Wings from a less glossy level: ``other``'s specular render (the same room, camera and
    sphere through its wider Ward lobe) with the factor the material terms fitted before it
    put on this level's lobe (Fresnel's rise), at this lobe's energy on the sphere. A haze
    reflects the whole room into the body, where this level's own lobe shows little of it;
    the image-space forms (:func:`_wings`) can only spread what this lobe shows."""
    So = lv["wider"][other]
    base = lv["S"]
    ok = base > 1e-6 * max(float(base.max()), 1e-30)
    factor = np.where(ok, S / np.where(ok, base, 1.0), 1.0)
    wide = So * factor * lv["cover"]
    return wide * (float((S * lv["cover"]).sum()) / max(float(wide.sum()), 1e-30))


#: The blurs' results by (form, width, the image's content), least recently used dropped
#: beyond _BLUR_CACHE_BYTES: a fit evaluates an amplitude many times on the same images (the
#: glare's R + c G(R) needs G(R) once per image and width, not once per c), and the held-out
#: losses blur the same test images again. Keyed by a 128-bit digest of the pixels, so an
#: image changed by an earlier term is a new key. Values are read-only.
_BLUR_CACHE: OrderedDict = OrderedDict()
_BLUR_CACHE_BYTES = 256 * 2**20
_BLUR_HELD = [0]  # bytes held in _BLUR_CACHE
_DIGESTS: dict = {}  # id -> (weak reference, digest) of read-only images


def _digest(img: np.ndarray) -> bytes:
    """A 128-bit digest of the pixels of ``img``, remembered for a read-only array (the
    levels' own images, which every evaluation passes again)."""
    if img.flags.writeable:
        return hashlib.blake2b(np.ascontiguousarray(img).data, digest_size=16).digest()
    held = _DIGESTS.get(id(img))
    if held is not None and held[0]() is img:
        return held[1]
    digest = hashlib.blake2b(np.ascontiguousarray(img).data, digest_size=16).digest()
    key = id(img)
    _DIGESTS[key] = (weakref.ref(img, lambda _, k=key: _DIGESTS.pop(k, None)), digest)
    return digest


def _remembered(form: str, width: float, img: np.ndarray, blur) -> np.ndarray:
    """``blur(img)``, computed once per (``form``, ``width``, pixels) (:data:`_BLUR_CACHE`)."""
    img = np.asarray(img, dtype=float)
    key = (form, float(width), img.shape, _digest(img))
    hit = _BLUR_CACHE.get(key)
    if hit is not None:
        _BLUR_CACHE.move_to_end(key)
        return hit
    out = np.array(blur(img), dtype=float)  # a copy: a view would keep its base alive
    out.flags.writeable = False
    _BLUR_CACHE[key] = out
    _BLUR_HELD[0] += out.nbytes
    while _BLUR_HELD[0] > _BLUR_CACHE_BYTES and len(_BLUR_CACHE) > 1:
        _BLUR_HELD[0] -= _BLUR_CACHE.popitem(last=False)[1].nbytes
    return out


def _glare_blur(img: np.ndarray, width_px: float) -> np.ndarray:
    """``img`` spread by a unit-sum glare kernel, zero outside the frame: a Gaussian of SD
    ``width_px`` (> 0), or (< 0) a power law (1 + (r / w)^2)^(-3/2) of core w = -width_px: a
    lens's stray light falls off as a power of the angle with a narrow core (inverse-cube
    spread functions, e.g. the CIE 1999 glare spread function's dominant term), which no one
    Gaussian follows both near and far. Each image and width blurred once
    (:func:`_remembered`); a black image (the background of a directional-light set) stays
    black."""
    if not np.any(img):
        return np.zeros(np.shape(img))
    return _remembered("glare", width_px, img, lambda im: _glare_kernel(im, width_px))


def _glare_kernel(img: np.ndarray, width_px: float) -> np.ndarray:
    """``img`` convolved with the glare kernel (:func:`_glare_spectrum`), zero outside the
    frame, by FFT with the kernel's spectrum computed once per image size and width."""
    h, w = img.shape
    fshape, spectrum = _glare_spectrum((h, w), float(width_px))
    full = sp_fft.irfftn(sp_fft.rfftn(img, fshape) * spectrum, fshape)
    return full[h:2 * h, w:2 * w]


@functools.lru_cache(maxsize=32)
def _glare_spectrum(shape: tuple, width_px: float):
    """The glare kernel on a (2h + 1) x (2w + 1) window (every offset within the frame) and its
    spectrum at a fast FFT size: a Gaussian of SD ``width_px`` (> 0) as ``ndimage.
    gaussian_filter`` builds it (truncated at 4 SD and normalised there; its taps beyond the
    frame meet only the zeros outside it), or (< 0) the power law (1 + (r / w)^2)^(-3/2)
    normalised over the window."""
    h, w = shape
    if width_px > 0:
        def taps(n):
            r = int(4.0 * width_px + 0.5)
            x = np.arange(-r, r + 1, dtype=float)
            g = np.exp(-0.5 / width_px**2 * x**2)
            g /= g.sum()
            return np.pad(g, max(n - r, 0))[max(r - n, 0):max(r - n, 0) + 2 * n + 1]
        kern = np.outer(taps(h), taps(w))
    else:
        yy, xx = np.mgrid[-h:h + 1, -w:w + 1]
        kern = (1 + (yy**2 + xx**2) / width_px**2) ** -1.5
        kern /= kern.sum()
    fshape = tuple(sp_fft.next_fast_len(3 * n, real=True) for n in shape)
    return fshape, sp_fft.rfftn(kern, fshape)


@functools.lru_cache(maxsize=64)
def _coverage(shape, cy: float, cx: float, radius: float, n: int = 8) -> np.ndarray:
    """Share of each pixel (centres at integers) inside the sphere's silhouette (n x n
    sub-pixels); computed once per silhouette (read-only)."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    offs = (np.arange(n) + 0.5) / n - 0.5
    cover = np.zeros(shape)
    for oy in offs:
        for ox in offs:
            cover += ((yy + oy - cy) ** 2 + (xx + ox - cx) ** 2) < radius**2
    cover /= n**2
    cover.flags.writeable = False
    return cover


def _shift_scene(lv: dict, images: list, dy: float, dx: float) -> list:
    """Diffuse, specular and background images of the scene shifted by (dy, dx) px.

    A pixel on the silhouette mixes the sphere and the background by the share it covers; a
    shift changes that share as geometry, not as an interpolation of a step. So each image is
    split into radiance (sphere parts: image / coverage; background: image / (1 - coverage),
    edge pixels filled from their nearest well-covered neighbour), the radiance shifted by
    cubic-spline interpolation, and the shares recomputed at the shifted silhouette."""
    cy, cx, radius = lv["geometry"]
    cov = lv["cover"]
    cov_s = _coverage(cov.shape, float(cy + dy), float(cx + dx), float(radius))
    out = []
    for k, img in enumerate(images):
        share, share_s = (cov, cov_s) if k < 2 else (1 - cov, 1 - cov_s)

        def shifted(im, share=share):  # each image shifted once (_remembered)
            known = share > 0.5
            rad = _fill(np.where(known, im / np.maximum(share, 1e-6), 0.0), known)
            return ndimage.shift(rad, (dy, dx), order=3, mode="nearest")
        form = f"shift {lv['geometry']!r} {dy!r} {dx!r} {'sphere' if k < 2 else 'surround'}"
        out.append(share_s * _remembered(form, 0.0, img, shifted))
    return out


def _basis(lv: dict, fitted: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Diffuse, specular and background images after every fitted extension (before the
    diffuse and specular scales): each registered candidate's ``apply``, in the catalogue's
    order (material terms, then the camera's, then the shift)."""
    p = dict(fitted)
    terms = _terms(lv)
    unknown = set(p) - {c.name for c in terms}
    if unknown:
        raise GapError(f"no render candidate(s) {sorted(unknown)}; known: "
                       f"{[c.name for c in terms]}")
    images = {"D": lv["D"], "S": lv["S"], "B": lv["B"]}
    for cand in terms:
        if cand.name in p:
            images = cand.apply(lv, images, p[cand.name])
    return images["D"], images["S"], images["B"]


def _terms(lv: dict) -> list:
    """The candidates whose terms may apply to a level, in order: the render catalogue, and
    for a level under a directional light (it has ``light``) the ``render_lights`` one after
    it (:mod:`analysis.gap.render.lights`)."""
    return catalogue("render") + (catalogue("render_lights") if "light" in lv else [])


def _predict(lv: dict, fitted: list, scaled_by: list | None = None) -> np.ndarray:
    """The extended render: the Ward fit's diffuse and specular scales re-fitted with the
    extension (``scale`` of the last fitted step, per level; 1 for the plain render); with
    ``scaled_by``, that list's scales instead of ``fitted``'s (a part of a fitted model)."""
    D, S, B = _basis(lv, fitted)
    steps = fitted if scaled_by is None else scaled_by
    scale = next((q["scale"] for _, q in reversed(steps) if "scale" in q), {})
    a, b = scale.get(lv["name"], scale.get("*", (1.0, 1.0)))
    return B + a * D + b * S


def render_loss(data: RenderData, fitted: list) -> np.ndarray:
    """Per-pixel Gaussian NLL (nats) on the view's pixels, levels concatenated."""
    out = []
    for lv in data.levels:
        m = lv["use"]
        r = (lv["P"] - _predict(lv, fitted))[m]
        sd = lv["sd"][m]
        out.append(0.5 * np.log(2 * np.pi * sd**2) + 0.5 * (r / sd) ** 2)
    return np.concatenate(out)


def render_unit_ids(data: RenderData) -> list[str]:
    """Pixel names ``level|y|x``."""
    ids = []
    for lv in data.levels:
        ys, xs = np.nonzero(lv["use"])
        ids += [f"{lv['name']}|{y}|{x}" for y, x in zip(ys, xs)]
    return ids


def split_render(data: RenderData, rng: np.random.Generator):
    """Held-out pixels: a checkerboard of 4 x 4 px blocks (``rng`` unused: fixed split)."""
    return data.view("train"), data.view("test")


# --- fit helpers the candidates share -------------------------------------------------------

def _scaled_fit(train: RenderData, fitted: list) -> tuple[list, dict]:
    """Weighted residuals per level with the diffuse and specular scales re-fitted per level
    (least squares), and the scales; levels of one material under several lights (each
    ``shared``) share one pair of scales, ``scale["*"]``."""
    if train.levels and all(lv.get("shared") for lv in train.levels):
        return _shared_scaled_fit(train, fitted)
    residuals, scale = [], {}
    for lv in train.levels:
        a, y = _weighted_columns(lv, fitted)
        coef = _two_scales(a.T @ a, a.T @ y, a, y)
        scale[lv["name"]] = (float(coef[0]), float(coef[1]))
        residuals.append(y - a @ coef)
    return residuals, scale


def _weighted_columns(lv: dict, fitted: list) -> tuple[np.ndarray, np.ndarray]:
    """One level's least-squares problem for the scales: the columns (D, S) and the target
    P - B on its pixels in use, each weighted by 1 / sd; shapes (n, 2) and (n,)."""
    m, w, pw = _weights(lv)
    D, S, B = _basis(lv, fitted)
    a = np.empty((w.size, 2))
    a[:, 0], a[:, 1] = D.ravel()[m] * w, S.ravel()[m] * w
    return a, pw - B.ravel()[m] * w


def _weights(lv: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The level's pixels in use (flat indices), their weights 1 / sd and the weighted photo
    P / sd, computed once per view (the fits evaluate them hundreds of times)."""
    use = lv["use"]
    held = lv.get("_weights")
    if held is None or held[0] is not use:
        m = np.flatnonzero(use)
        w = 1 / lv["sd"].ravel()[m]
        held = lv["_weights"] = (use, m, w, lv["P"].ravel()[m] * w)
    return held[1:]


def _two_scales(ata: np.ndarray, aty: np.ndarray, a, y) -> np.ndarray:
    """The two scales from the normal equations (A^T A) x = A^T y (2 x 2); by an SVD of the
    stacked ``a``, ``y`` (a list of blocks or one array) where A^T A is near singular (a
    component black on the pixels in use), as lstsq would."""
    if np.linalg.cond(ata) < 1e8:
        return np.linalg.solve(ata, aty)
    a = np.concatenate(a) if isinstance(a, list) else a
    y = np.concatenate(y) if isinstance(y, list) else y
    return np.linalg.lstsq(a, y, rcond=None)[0]


def _shared_scaled_fit(train: RenderData, fitted: list) -> tuple[list, dict]:
    """:func:`_scaled_fit` with one diffuse and one specular scale for all levels."""
    blocks = [_weighted_columns(lv, fitted) for lv in train.levels]
    ata = sum(a.T @ a for a, _ in blocks)
    aty = sum(a.T @ y for a, y in blocks)
    coef = _two_scales(ata, aty, [a for a, _ in blocks], [y for _, y in blocks])
    return [y - a @ coef for a, y in blocks], {"*": (float(coef[0]), float(coef[1]))}


def _scaled_sse(train: RenderData, fitted: list):
    """Weighted SSE with the diffuse and specular scales re-fitted per level (least squares)."""
    residuals, scale = _scaled_fit(train, fitted)
    return sum(float(np.sum(r**2)) for r in residuals), scale


def _scaled_residuals(train: RenderData, fitted: list) -> np.ndarray:
    """The weighted residuals behind :func:`_scaled_sse` (scales re-fitted per level)."""
    return np.concatenate(_scaled_fit(train, fitted)[0])
