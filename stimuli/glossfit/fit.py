"""The gloss fit, end to end: photo set -> registration -> Ward fit per level -> gloss table.

``fit_gloss(photo_set_dir, out_dir, gloss_pct, settings=...)`` loads and checks the photo set,
renders a reference sphere, registers each photo to it (seed), fits each level with the grid
(seed) or basis method, writes each level's row, residual arrays and figure as soon as it is
fitted, and at the end the gloss table, fit.json and report.html (stimuli.glossfit.output).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from stimuli.glossfit.methods import BasisCache, FitSettings, LevelFit, basis_fit, grid_fit
from stimuli.glossfit.output import (
    append_fit_row,
    write_json,
    write_level_figure,
    write_report,
    write_residuals,
)
from stimuli.glossfit.photoset import GlossFitError, PhotoSet, load_photo_set, photo_name
from stimuli.glossfit.registration import Registration, register, warp_photo
from stimuli.glossfit.residuals import highlight_centroid, region_masks, region_rmse
from stimuli.glossfit.scene import (
    Camera,
    SphereScene,
    fit_camera,
    luminance,
    sphere_distance_px,
)
from stimuli.glossfit.table import gloss_table_from_fits

__all__ = ["OUTPUT_NAMES", "FitRun", "fit_gloss", "fit_level"]

#: What fit_gloss writes into its output folder.
OUTPUT_NAMES = ("gloss_table.csv", "fits.csv", "residuals", "figures", "fit.json", "report.html")
#: Below this share of specular light on the sphere a photo does not determine alpha: the
#: objective is so flat in alpha that Monte-Carlo noise moves its minimum (on a 20 % clear-coat
#: photo, 4 % specular light, grid and basis fits differed by 0.07 in alpha at equal RMSE).
MIN_SPECULAR_SHARE = 0.05
_ALPHA_UNDETERMINED = "alpha is not determined by this photo"
#: Ward parameters of the registration's reference render (stimuli.ward's defaults).
REFERENCE_WARD = (0.5, 0.05, 0.1)


@dataclass
class FitRun:
    """What ``fit_gloss`` did.

    Attributes
    ----------
    out_dir : Path
    fits : DataFrame
        fits.csv as written.
    table : DataFrame or None
        The gloss table (None if it could not be made; see ``warnings``).
    n_renders : int
    wall_s : float
    warnings : list of str
    """

    out_dir: Path
    fits: pd.DataFrame
    table: pd.DataFrame | None
    n_renders: int
    wall_s: float
    warnings: list[str] = field(default_factory=list)


def fit_level(photo: np.ndarray, clipped: np.ndarray, photo_set: PhotoSet, scene: SphereScene,
              reference: np.ndarray, cache: BasisCache, settings: FitSettings, *,
              name: str, max_highlight_offset_px: float = 3.0,
              max_background_mismatch: float = 0.25, refine: bool = True) -> tuple[Registration, LevelFit, dict, dict[str, np.ndarray]]:
    """Register and fit one photo.

    Registration is the source study's (Nelder-Mead against ``reference``); with ``refine`` it is done
    once more against a quick basis fit's render, whose shading and highlight match the photo's
    (the reference's differ, which biased the scale by up to 3 % on synthetic photos). Both
    methods get the same registration.

    Returns
    -------
    registration, fit, row, arrays
        ``row``: the fits.csv row (no gloss_pct/method/n_renders yet); ``arrays``: the
        residuals file's arrays.

    Raises
    ------
    GlossFitError
        If the sphere is not found in the photo.
    """
    setup = photo_set.setup
    cam = scene.camera
    r = sphere_distance_px(cam)
    # Pixels wholly inside the silhouette: there the background render is exactly 0.
    sphere = r < 1.0 - 1.0 / cam.sphere_radius_px

    def warped(reg):
        photo_fit = warp_photo(photo, reg, cam, setup)
        valid = warp_photo((~clipped).astype(np.float32), reg, cam, setup, order=1) > 0.999
        return photo_fit, valid, luminance(photo_fit)

    reg = register(photo, reference, cam, setup, valid=~clipped, name=name)
    photo_fit, valid, lum = warped(reg)
    if refine:
        quick = basis_fit(cache, lum, sphere & valid, replace(settings, method="basis"),
                          refine_alpha=False)
        reg = register(photo, quick.render, cam, setup, valid=~clipped, name=name)
        photo_fit, valid, lum = warped(reg)
    mask = sphere & valid
    if settings.method == "grid":
        fit = grid_fit(scene, lum, mask, settings)
    else:
        fit = basis_fit(cache, lum, mask, settings)
    residual = photo_fit - fit.render
    masks = region_masks(cam, luminance(fit.specular))
    rmse = region_rmse(luminance(residual), masks, lum, sphere, valid)

    warnings = []
    flag = False
    spec_share = float(luminance(fit.specular)[mask].mean() / luminance(fit.render)[mask].mean())
    if spec_share < MIN_SPECULAR_SHARE:
        warnings.append(f"specular light is {100 * spec_share:.1f} % of the sphere's: "
                        f"{_ALPHA_UNDETERMINED}")
    if spec_share > 0.05 and masks["highlight"].any():
        region = (r < 0.85) & valid
        c_photo = highlight_centroid(lum, region)
        c_render = highlight_centroid(luminance(fit.render), region)
        if c_photo and c_render:
            offset = math.dist(c_photo, c_render)
            if offset > max_highlight_offset_px:
                flag = True
                warnings.append(f"highlight centroids {offset:.1f} px apart (limit "
                                f"{max_highlight_offset_px:g}); check the registration")
    if reg.background_mismatch > max_background_mismatch:
        warnings.append(f"background differs from the panorama's render by "
                        f"{100 * reg.background_mismatch:.0f} % RMS: photo and envmap.exr may "
                        f"not match")
    if np.isfinite(reg.background_ratio) and abs(math.log(reg.background_ratio)) > math.log(1.25):
        warnings.append(f"photo / render background = {reg.background_ratio:.3g}: photo and "
                        f"panorama are not in the same units, so rho_d, rho_s are scaled by it")
    clipped_fraction = float(clipped.mean())
    if clipped_fraction > 0:
        warnings.append(f"{100 * clipped_fraction:.3f} % of pixels clipped (left out)")
    lo, hi = settings.alpha_bounds
    if fit.alpha <= lo * 1.001 or fit.alpha >= hi * 0.999:
        warnings.append(f"alpha {fit.alpha:.4g} at the search bound {settings.alpha_bounds}")
    if fit.r <= 0.0 or fit.r >= 1.0:
        warnings.append(f"rho_s/(rho_d+rho_s) = {fit.r:g} at its bound")
    row = {"rho_d": fit.rho_d, "rho_s": fit.rho_s, "alpha": fit.alpha, "reg_sx": reg.sx,
           "reg_sy": reg.sy, "reg_dx_px": reg.dx_px, "reg_dy_px": reg.dy_px, "reg_flag": flag,
           "clipped_fraction": clipped_fraction, **rmse, "warnings": "; ".join(warnings)}
    arrays = {"photo": photo_fit, "render": fit.render.astype(np.float32),
              "residual": residual.astype(np.float32),
              "diffuse": fit.diffuse.astype(np.float32),
              "specular": fit.specular.astype(np.float32),
              **masks, "sphere": sphere, "valid": valid}
    return reg, fit, row, arrays


def fit_gloss(photo_set_dir: str | Path, out_dir: str | Path, gloss_pct: tuple[float, ...], *,
              settings: FitSettings | None = None, resolution_px: int = 64, spp: int = 36,
              seed: int = 0, max_highlight_offset_px: float = 3.0, progress=None,
              lighting: str | None = None) -> FitRun:
    """Fit Ward parameters to a photo set and write the output folder.

    Parameters
    ----------
    photo_set_dir : str or Path
        The photo set (stimuli.glossfit.photoset).
    out_dir : str or Path
        Output folder; may hold other files (e.g. the photo set) but none of ``OUTPUT_NAMES``.
    gloss_pct : tuple of float
        The design's physical gloss levels (%).
    settings : FitSettings
        Method and search settings.
    resolution_px : int
        Width = height of the fit renders (pixels).
    spp : int
        Samples per pixel of the fit renders.
    seed : int
        Sampler seed of every fit render.
    max_highlight_offset_px : float
        Registration is flagged when photo and render highlights are further apart (fit px).
    progress : callable(str), optional
        Called with a line per level.
    lighting : str, optional
        A set photographed in several lightings (:mod:`stimuli.glossfit.lightings`): the one
        fitted; fit.json records it, so the others can be held out.

    Returns
    -------
    FitRun

    Raises
    ------
    GlossFitError
        Bad photo set (stimuli.glossfit.photoset), or no level could be fitted.
    FileExistsError
        If ``out_dir`` already holds a fit's output.
    """
    t0 = time.perf_counter()
    settings = FitSettings() if settings is None else settings
    out = Path(out_dir)
    _refuse_taken(out)
    photo_set = load_photo_set(photo_set_dir, gloss_pct, lighting=lighting)
    (out / "residuals").mkdir(parents=True, exist_ok=True)
    (out / "figures").mkdir(exist_ok=True)
    warnings = list(photo_set.warnings)
    cam = fit_camera(photo_set.setup, resolution_px)
    rows, details, n_renders = _fit_levels(out, photo_set, cam, settings, warnings, spp=spp,
                                           seed=seed, progress=progress,
                                           max_highlight_offset_px=max_highlight_offset_px)
    fits = pd.read_csv(out / "fits.csv")
    table, summary = _write_gloss_table(fits, out, warnings)
    wall_s = time.perf_counter() - t0
    info = {"photo_set": str(Path(photo_set_dir)), "settings": asdict(settings),
            "setup": photo_set.setup.to_dict(), "resolution_px": resolution_px, "spp": spp,
            "seed": seed, "fit_fov_deg": cam.fov_deg, "n_renders": n_renders, "wall_s": wall_s,
            "missing_pct": photo_set.missing_pct, "summary": summary, "warnings": warnings,
            "levels": details,
            "versions": _versions()}
    if lighting is not None:
        from stimuli.glossfit.lightings import lighting_names

        info |= {"lighting": lighting, "lightings": lighting_names(photo_set_dir)}
    write_json(out / "fit.json", info)
    write_report(out / "report.html", info, rows,
                 [] if table is None else table.to_dict("records"))
    return FitRun(out_dir=out, fits=fits, table=table, n_renders=n_renders, wall_s=wall_s,
                  warnings=warnings)


def _refuse_taken(out: Path) -> None:
    """Refuse an output folder that already holds any of ``OUTPUT_NAMES`` (nothing is
    overwritten)."""
    taken = [name for name in OUTPUT_NAMES if (out / name).exists()]
    if taken:
        raise FileExistsError(f"{out} already holds a fit's output ({', '.join(taken)}); give a "
                              f"new output folder (nothing is overwritten)")


def _fit_levels(out: Path, photo_set: PhotoSet, cam: Camera, settings: FitSettings,
                warnings: list[str], *, spp: int, seed: int, progress,
                max_highlight_offset_px: float) -> tuple[list[dict], list[dict], int]:
    """Fit every level of the photo set in one sphere scene, in the set's order, writing each
    level's output as it is fitted and adding its warnings to ``warnings``.

    Returns
    -------
    rows : list of dict
        fits.csv's rows.
    details : list of dict
        fit.json's ``levels``.
    n_renders : int
        Renders made, the registration's reference included.
    """
    rows, details = [], []
    with SphereScene(photo_set.envmap, cam, spp=spp, seed=seed,
                     envmap_rotation_deg=photo_set.setup.envmap_rotation_deg) as scene:
        reference = scene.render(*REFERENCE_WARD)
        cache = BasisCache(scene)
        for pct, photo in photo_set.photos.items():
            row, detail, level_warnings = _fit_and_write_level(
                out, pct, photo, photo_set, scene, reference, cache, settings,
                max_highlight_offset_px=max_highlight_offset_px)
            warnings += level_warnings
            details.append(detail)
            rows.append(row)
            if progress:
                progress(f"{photo_name(pct)}: rho_d {row['rho_d']:.4g} rho_s {row['rho_s']:.4g} "
                         f"alpha {row['alpha']:.4g} rmse {row['rmse']:.3g} "
                         f"({row['n_renders']} renders)")
        return rows, details, scene.n_renders


def _fit_and_write_level(out: Path, pct: float, photo: np.ndarray, photo_set: PhotoSet,
                         scene: SphereScene, reference: np.ndarray, cache: BasisCache,
                         settings: FitSettings, *, max_highlight_offset_px: float
                         ) -> tuple[dict, dict, list[str]]:
    """Fit one gloss level and write what it gives the moment it exists: its row of fits.csv,
    and, when fitted, its residual arrays and figure.

    Returns
    -------
    row : dict
        The row appended to fits.csv (NaN parameters and ``reg_flag`` when not fitted).
    detail : dict
        The level's entry in fit.json's ``levels`` (registration and objective, or the error).
    warnings : list of str
        The level's warnings, named by its photo.
    """
    name = photo_name(pct)
    before = scene.n_renders
    base = {"gloss_pct": pct, "method": settings.method}
    warnings = []
    try:
        reg, fit, row, arrays = fit_level(
            photo, photo_set.clipped[pct], photo_set, scene, reference, cache, settings,
            name=name, max_highlight_offset_px=max_highlight_offset_px)
    except GlossFitError as exc:
        nan = float("nan")
        row = {c: nan for c in ("rho_d", "rho_s", "alpha", "reg_sx", "reg_sy",
                                "reg_dx_px", "reg_dy_px", "rmse", "rmse_highlight",
                                "rmse_body", "rmse_rim", "rmse_background")}
        row.update(reg_flag=True, clipped_fraction=photo_set.clipped_fraction(pct),
                   warnings=f"not fitted: {exc}")
        warnings.append(f"{name}: not fitted: {exc}")
        arrays = None
        detail = {"gloss_pct": pct, "error": str(exc)}
    else:
        detail = {"gloss_pct": pct, "registration": reg.to_dict(),
                  "objective": fit.error, "r": fit.r, "iterations": fit.iterations}
    row = {**base, **row, "n_renders": scene.n_renders - before}
    append_fit_row(out / "fits.csv", row)
    if arrays is not None:
        stem = Path(name).stem
        write_residuals(out / "residuals" / f"{stem}.npz", arrays)
        write_level_figure(out / "figures" / f"{stem}.png", arrays["photo"],
                           arrays["render"], arrays["residual"], arrays["sphere"],
                           f"gloss {pct:g} %: rho_d {row['rho_d']:.3g}, rho_s "
                           f"{row['rho_s']:.3g}, alpha {row['alpha']:.3g} "
                           f"({settings.method})")
        if row["warnings"]:
            warnings.append(f"{name}: {row['warnings']}")
    return row, detail, warnings


def _write_gloss_table(fits: pd.DataFrame, out: Path, warnings: list[str]
                       ) -> tuple[pd.DataFrame | None, dict]:
    """Write gloss_table.csv from the fits (levels whose alpha no photo determines marked);
    when it cannot be made or written, say why in ``warnings`` and return no table (with the
    summary, if the table was made)."""
    table, summary = None, {}
    try:
        from stimuli.glosstable import write_gloss_table

        undetermined = tuple(fits.loc[fits["warnings"].astype(str).str.contains(
            _ALPHA_UNDETERMINED), "gloss_pct"])
        table, summary = gloss_table_from_fits(fits, undetermined)
        write_gloss_table(table, out / "gloss_table.csv")
    except ValueError as exc:  # GlossFitError, GlossTableError
        warnings.append(f"gloss_table.csv not written: {exc}")
        table = None
    return table, summary


def _versions() -> dict:
    import mitsuba
    import scipy

    from stimuli.glossfit.mitsuba_setup import FIT_VARIANT

    return {"mitsuba": mitsuba.__version__, "numpy": np.__version__, "scipy": scipy.__version__,
            "variant": FIT_VARIANT}
