"""Fitting Ward parameters to one registered photo: the source study's grid search and the basis fit.

Both minimise the source study's objective: over the sphere's circular mask, the mean squared difference
of photo and render luminance, each divided by its own mean,

    E = mean((P / mean(P) - R / mean(R))^2),    R = R(rho_d = 1 - r, rho_s = r, alpha),

then undo the normalisation: with k = mean(P) / mean(R), rho_d = k (1 - r) and rho_s = k r.

* ``grid_fit`` (the seed): a 2-D grid over r (= rho_s before the rescaling) and alpha, one
  render per grid point; recentre on the best point and shrink each range by 35 %; stop when the
  best point moves by less than ``tol`` (in r and in alpha) for ``patience`` iterations in a row.
* ``basis_fit``: for a convex sphere the render is linear in the albedos,
  R = B + rho_d D + rho_s S(alpha), with B the background (the panorama around a black sphere),
  D the diffuse light (render with rho_d = 1, rho_s = 0, minus B) and S(alpha) the specular light
  (rho_d = 0, rho_s = 1, minus B). Inside the sphere mask B = 0. With d = D / mean(D) and s = S / mean(S), the
  normalised renders R / mean(R) are exactly the line u(t) = d + t (s - d), t in [0, 1], so the
  best r for a given alpha is a least-squares projection (closed form); alpha is searched in 1-D
  (a log-spaced scan shared by all levels, then Brent's method in the best bracket) and each
  S(alpha) is rendered once and cached.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from stimuli.glossfit.photoset import GlossFitError
from stimuli.glossfit.scene import luminance

__all__ = ["BasisCache", "FitSettings", "LevelFit", "basis_fit", "grid_fit", "normalised_error"]

METHODS = ("basis", "grid")
_GRID_SCALE = 0.999


@dataclass(frozen=True)
class FitSettings:
    """Settings of the fit (all recorded in the output).

    Attributes
    ----------
    method : {"basis", "grid"}
    alpha_bounds : (float, float)
        Range of the Ward roughness alpha searched.
    grid_points : int
        Points per axis of the source study's grid (odd, so the centre is on the grid).
    shrink : float
        Share by which each range shrinks per grid iteration (seed: 0.35).
    tol : float
        Grid stops when the best point moves less than this in r and alpha ...
    patience : int
        ... for this many iterations in a row (seed: 0.001, five).
    max_iter : int
        Grid iterations at most.
    alpha_scan : int
        Basis fit: log-spaced alphas scanned before Brent's method.
    alpha_xtol : float
        Basis fit: Brent's tolerance on alpha.
    """

    method: str = "basis"
    alpha_bounds: tuple[float, float] = (0.01, 0.5)
    grid_points: int = 5
    shrink: float = 0.35
    tol: float = 0.001
    patience: int = 5
    max_iter: int = 60
    gate_on_spacing: bool = True
    alpha_scan: int = 9
    alpha_xtol: float = 5e-4

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise GlossFitError(f"method {self.method!r}; choose one of {list(METHODS)}")
        lo, hi = self.alpha_bounds
        if not 0 < lo < hi <= 1:
            raise GlossFitError(f"alpha_bounds {self.alpha_bounds}; need 0 < low < high <= 1")
        if self.grid_points < 3 or self.grid_points % 2 == 0:
            raise GlossFitError(f"grid_points = {self.grid_points}; need an odd number >= 3")
        if not 0 < self.shrink < 1:
            raise GlossFitError(f"shrink = {self.shrink}; need 0 < shrink < 1")


@dataclass
class LevelFit:
    """The fit of one photo.

    Attributes
    ----------
    rho_d, rho_s, alpha : float
        Ward parameters, albedos in the photo's units relative to the panorama's.
    r : float
        rho_s / (rho_d + rho_s), the grid's coordinate.
    error : float
        The normalised objective E at the optimum.
    n_renders : int
        Renders this fit caused (the basis fit's shared cache counts each render once).
    render, diffuse, specular : ndarray, shape (h, w, 3)
        Best render (B + rho_d D + rho_s S, background included) and its sphere components
        (rho_d D, rho_s S); the grid fit renders the components once more at its optimum.
    iterations : int
    """

    rho_d: float
    rho_s: float
    alpha: float
    r: float
    error: float
    n_renders: int
    render: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    iterations: int = 0
    trace: list = field(default_factory=list)


def normalised_error(photo_lum: np.ndarray, render_lum: np.ndarray) -> float:
    """The source study's objective E over already-masked luminance vectors (dimensionless)."""
    q = photo_lum / photo_lum.mean()
    return float(np.mean((q - render_lum / render_lum.mean()) ** 2))


def _check_target(photo_lum: np.ndarray, mask: np.ndarray) -> np.ndarray:
    p = np.asarray(photo_lum, dtype=np.float64)[mask]
    if p.size < 20:
        raise GlossFitError(f"only {p.size} usable sphere pixels; enlarge the fit renders")
    if not p.mean() > 0:
        raise GlossFitError("the photo is black on the sphere")
    return p


def _finish(p: np.ndarray, r: float, alpha: float, background_rgb: np.ndarray,
            diffuse_rgb: np.ndarray, specular_rgb: np.ndarray, mask: np.ndarray, error: float,
            n_renders: int, iterations: int, trace: list) -> LevelFit:
    unit = (1 - r) * luminance(diffuse_rgb)[mask] + r * luminance(specular_rgb)[mask]
    k = float(p.mean() / unit.mean())
    rho_d, rho_s = k * (1 - r), k * r
    render = background_rgb + rho_d * diffuse_rgb + rho_s * specular_rgb
    return LevelFit(rho_d=rho_d, rho_s=rho_s, alpha=float(alpha), r=float(r), error=error,
                    n_renders=n_renders, render=render,
                    diffuse=rho_d * diffuse_rgb, specular=rho_s * specular_rgb,
                    iterations=iterations, trace=trace)


def _window(centre: float, width: float, lo: float, hi: float, n: int) -> np.ndarray:
    width = min(width, hi - lo)
    start = min(max(centre - width / 2, lo), hi - width)
    return np.linspace(start, start + width, n)


def grid_fit(renderer, photo_lum: np.ndarray, mask: np.ndarray,
             settings: FitSettings | None = None) -> LevelFit:
    """The source study's fit: iterated, shrinking 2-D grid over r = rho_s and alpha (rho_d = 1 - r).

    Parameters
    ----------
    renderer : object with ``render(rho_d, rho_s, alpha) -> ndarray (h, w, 3)`` and ``n_renders``
        Renders the sphere on the fit grid (a SphereScene).
    photo_lum : ndarray, shape (h, w)
        Registered photo luminance on the same grid.
    mask : ndarray of bool, shape (h, w)
        The circular sphere mask (minus clipped pixels).
    settings : FitSettings

    Returns
    -------
    LevelFit
    """
    settings = FitSettings(method="grid") if settings is None else settings
    p = _check_target(photo_lum, mask)
    start_renders = renderer.n_renders
    a_lo, a_hi = settings.alpha_bounds
    cache: dict[tuple[float, float], float] = {}

    def error(r: float, a: float) -> float:
        key = (round(r, 12), round(a, 12))
        if key not in cache:
            # The scale is free (E is normalised); just below 1 keeps rho_d + rho_s <= 1 in
            # float32.
            img = renderer.render(_GRID_SCALE * (1.0 - r), _GRID_SCALE * r, a)
            cache[key] = normalised_error(p, luminance(img)[mask])
        return cache[key]

    centre = (0.5, 0.5 * (a_lo + a_hi))
    width = [1.0, a_hi - a_lo]
    best, best_e, stable, trace = None, np.inf, 0, []
    iterations = 0
    for iterations in range(1, settings.max_iter + 1):
        rs = _window(centre[0], width[0], 0.0, 1.0, settings.grid_points)
        alphas = _window(centre[1], width[1], a_lo, a_hi, settings.grid_points)
        new = min((error(r, a), (float(r), float(a))) for r in rs for a in alphas)
        if best is not None and new[0] > best_e:
            new = (best_e, best)  # the grid moved past the best point seen; keep it
        # Stop only once the grid resolves tol (the source study's rule alone could stop at a coarse grid
        # whose centre stays best by chance).
        # At r = 0 alpha has no effect on the render (rho_s = 0), so the best alpha there is
        # chance (Monte-Carlo noise): keep alpha's range whole and do not count the iteration
        # as stable until r leaves 0. Without this the grid locked onto r = 0 and a random alpha
        # on weakly glossy photos whose best fit has rho_s > 0 (protocol.md, choices).
        at_zero = new[1][0] <= 0.0
        if at_zero:
            new = (new[0], (0.0, centre[1]))
        move = np.inf if best is None else max(abs(new[1][0] - best[0]),
                                               abs(new[1][1] - best[1]))
        spacing = max(width[0], width[1]) / (settings.grid_points - 1)
        converged = not settings.gate_on_spacing or spacing < settings.tol
        stable = stable + 1 if move < settings.tol and not at_zero and converged else 0
        best_e, best = new
        trace.append((iterations, best[0], best[1], best_e))
        centre = best
        width = [width[0] * (1 - settings.shrink),
                 width[1] if at_zero else width[1] * (1 - settings.shrink)]
        if stable >= settings.patience or (at_zero and width[0] < settings.tol):
            break
    r, alpha = best
    background = renderer.render(0.0, 0.0, alpha)
    diffuse = renderer.render(1.0, 0.0, alpha) - background
    specular = renderer.render(0.0, 1.0, alpha) - background
    return _finish(p, r, alpha, background, diffuse, specular, mask, best_e,
                   renderer.n_renders - start_renders, iterations, trace)


class BasisCache:
    """Background, diffuse and specular basis renders of the sphere, each rendered once.

    Parameters
    ----------
    renderer : object with ``render(rho_d, rho_s, alpha)`` and ``n_renders``
    """

    def __init__(self, renderer) -> None:
        self.renderer = renderer
        self._background: np.ndarray | None = None
        self._diffuse: np.ndarray | None = None
        self._specular: dict[float, np.ndarray] = {}

    def background(self) -> np.ndarray:
        """B: the render of a black sphere (rho_d = rho_s = 0): the panorama around it."""
        if self._background is None:
            self._background = self.renderer.render(0.0, 0.0, 0.1)
        return self._background

    def diffuse(self) -> np.ndarray:
        """D: the render with rho_d = 1, rho_s = 0 (alpha plays no part), minus B."""
        if self._diffuse is None:
            self._diffuse = self.renderer.render(1.0, 0.0, 0.1) - self.background()
        return self._diffuse

    def specular(self, alpha: float) -> np.ndarray:
        """S(alpha): the render with rho_d = 0, rho_s = 1, minus B."""
        key = round(float(alpha), 7)
        if key not in self._specular:
            self._specular[key] = self.renderer.render(0.0, 1.0, key) - self.background()
        return self._specular[key]


def _project(q: np.ndarray, d: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    """Closed-form best t on the line d + t (s - d), t in [0, 1]; returns (t, error)."""
    diff = s - d
    denom = float(diff @ diff)
    t = 0.0 if denom == 0 else float(np.clip((q - d) @ diff / denom, 0.0, 1.0))
    return t, float(np.mean((q - d - t * diff) ** 2))


def basis_fit(cache: BasisCache, photo_lum: np.ndarray, mask: np.ndarray,
              settings: FitSettings | None = None, *, refine_alpha: bool = True) -> LevelFit:
    """The fast fit: closed-form albedos for each alpha, 1-D search over alpha.

    Parameters
    ----------
    cache : BasisCache
        Shared by all photos of a set (same camera, panorama and sampler seed).
    photo_lum, mask, settings
        As for ``grid_fit``.
    refine_alpha : bool
        False: stop at the best alpha of the shared scan (no new renders after the first photo;
        used for the registration's template).

    Returns
    -------
    LevelFit
        The same optimum as ``grid_fit`` (same objective and constraint).
    """
    settings = FitSettings() if settings is None else settings
    p = _check_target(photo_lum, mask)
    start_renders = cache.renderer.n_renders
    q = p / p.mean()
    dlum = luminance(cache.diffuse())[mask].astype(np.float64)
    mean_d = dlum.mean()
    d = dlum / mean_d
    results: dict[float, tuple[float, float]] = {}

    def evaluate(alpha: float) -> float:
        alpha = round(float(alpha), 7)
        if alpha not in results:
            slum = luminance(cache.specular(alpha))[mask].astype(np.float64)
            mean_s = slum.mean()
            t, err = _project(q, d, slum / mean_s)
            # t weights the normalised images; in albedos, rho_d ~ (1 - t)/mean(D), rho_s ~ t/mean(S).
            a, b = (1 - t) / mean_d, t / mean_s
            results[alpha] = (b / (a + b), err)
        return results[alpha][1]

    lo, hi = settings.alpha_bounds
    scan = np.geomspace(lo, hi, settings.alpha_scan)
    errors = [evaluate(a) for a in scan]
    i = int(np.argmin(errors))
    bracket = (scan[max(i - 1, 0)], scan[min(i + 1, len(scan) - 1)])
    nfev = len(scan)
    if refine_alpha:
        res = optimize.minimize_scalar(evaluate, bounds=bracket, method="bounded",
                                       options={"xatol": settings.alpha_xtol})
        nfev += int(res.nfev)
    alpha = min(results, key=lambda a: results[a][1])
    r, err = results[alpha]
    trace = sorted((a, v[0], v[1]) for a, v in results.items())
    return _finish(p, r, alpha, cache.background(), cache.diffuse(), cache.specular(alpha),
                   mask, err,
                   cache.renderer.n_renders - start_renders, nfev, trace)
