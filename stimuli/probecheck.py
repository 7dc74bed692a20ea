"""Is a panorama a light field? Checks of a lat-long map's content and of a design's scale.

A light field lights the stimuli as the captured room or landscape did: a linear, unclipped,
high-dynamic-range panorama (the shipped ones are Poly Haven captures, 512 x 256, their brightest
pixel 29 to 220,000 times their median). A lab's 8-bit photo converted to EXR looks like one to
the file readers but is not: its top is flat (the sun and the lamps clipped at one value, the
brightest direction lost), its values come in 256 steps, and its scale by the design's rule is
off by a factor of several. These checks run where a panorama is read for the stimuli:
``python -m stimuli probe-scale``, the design check (``python -m studydesign check``) and
``python -m stimuli render`` (before any worker starts).

Refused (:func:`light_field_problems`'s first list): fewer than :data:`MIN_SIZE_PX` pixels, a flat
top (more than :data:`FLAT_TOP_FRACTION` of the pixels within 0.1 % of the largest value), 8-bit
steps (at most 256 distinct values in every channel of a map of :data:`STEPS_MIN_PIXELS` pixels
or more), and absurd pixels (the brightest luminance more than :data:`MAX_CONTRAST` times the
median: no scene is, the sun against its sky is about 1e5 to 1e6). Warned: a dynamic range
(brightest over median luminance) below :data:`MIN_CONTRAST`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from stimuli.errors import IlluminationError
from stimuli.illumination import diffuse_white_scale, load_light_probe, luminance

__all__ = [
    "FLAT_TOP_FRACTION",
    "MAX_CONTRAST",
    "MIN_CONTRAST",
    "MIN_SIZE_PX",
    "SCALE_RTOL",
    "STEPS_MIN_PIXELS",
    "check_light_field_file",
    "design_light_field_report",
    "light_field_problems",
    "refuse_bad_light_fields",
]

#: Smallest lat-long map accepted, (width, height) px: a pixel of 2.8 deg.
MIN_SIZE_PX = (128, 64)
#: Largest share of the pixels allowed at the top value (within 0.1 %): a clipped capture piles
#: its sun and lamps there (an 8-bit photo: 1.4 %; the shipped captures: 1 or 2 pixels, < 2e-5).
FLAT_TOP_FRACTION = 1e-3
#: Maps of this many pixels or more must hold more than 256 distinct values in some channel
#: (the shipped captures: 1,284 to 6,735 in green).
STEPS_MIN_PIXELS = 4096
#: Brightest over median luminance below this is warned: too little dynamic range for the light
#: sources of a scene (the shipped captures: 29, a white room in daylight, to 220,000).
MIN_CONTRAST = 20.0
#: Brightest over median luminance above this is refused: absurd pixels.
MAX_CONTRAST = 1e9
#: A design's scale may differ from the file's own (``probe-scale``) by this fraction: the
#: 6 significant digits the scales are written with, and RGBE rounding.
SCALE_RTOL = 1e-4
#: What every message ends with.
NEEDS = ("a light field needs a linear, unclipped HDR capture (bracketed exposures merged, or a "
         "shipped probe): at least 128 x 64 px, its light sources well above the rest")


def light_field_problems(rgb: np.ndarray) -> tuple[list[str], list[str]]:
    """What makes a lat-long map unfit to be a light field.

    Parameters
    ----------
    rgb : ndarray, shape (h, w, 3)
        Linear radiance as stored (finite, >= 0: :func:`stimuli.load_light_probe` checks that).

    Returns
    -------
    (list of str, list of str)
        Reasons to refuse it, and warnings; each says what is wrong, with the figure.
    """
    h, w = rgb.shape[:2]
    problems: list[str] = []
    warnings: list[str] = []
    if w < MIN_SIZE_PX[0] or h < MIN_SIZE_PX[1]:
        problems.append(f"only {w} x {h} px (a pixel spans {180 / h:.3g} deg; the shipped light "
                        "fields are 512 x 256)")
    if h * w >= STEPS_MIN_PIXELS:
        distinct = max(len(np.unique(rgb[..., c])) for c in range(3))
        if distinct <= 256:
            problems.append(f"8-bit steps: at most {distinct} distinct values per channel (an "
                            "8-bit image converted to floats)")
    y = luminance(rgb.astype(np.float64))
    positive = y[y > 0]
    median = float(np.median(positive)) if positive.size else 0.0
    contrast = float(y.max()) / median if median > 0 else float("inf")
    absurd = contrast > MAX_CONTRAST
    if absurd:
        n = int(np.sum(y > MAX_CONTRAST * median))
        problems.append(f"{n} absurd pixel(s): up to {float(y.max()):.3g}, {contrast:.3g} times "
                        "the median luminance (the sun against its sky is about 1e5 to 1e6)")
    elif contrast < MIN_CONTRAST:
        warnings.append(f"little dynamic range: the brightest luminance is {contrast:.3g} times "
                        f"the median (the shipped captures: 29 to 220,000); an 8-bit or "
                        "tone-mapped photo has no light sources above its white")
    top = float(rgb.max())
    at_top = float(np.mean((rgb >= top * (1 - 1e-3)).any(axis=-1))) if top > 0 else 1.0
    if at_top > FLAT_TOP_FRACTION and h * w * at_top >= 4 and not absurd:
        problems.append(f"a flat top: {100 * at_top:.2g} % of the pixels at the largest value "
                        f"{top:.6g} (clipped: the sun and the lamps flattened, the brightest "
                        "direction lost)")
    return problems, warnings


def check_light_field_file(envmap: str | os.PathLike, *, scale: float | None = None,
                           where: str = "") -> tuple[list[str], list[str], float]:
    """Read a panorama and check it (:func:`light_field_problems`), and a design's scale of it.

    Parameters
    ----------
    envmap : str or path-like
        A file, or a shipped probe's name.
    scale : float, optional
        The design's scale of it: refused where it differs from the file's own
        (:func:`stimuli.illumination.diffuse_white_scale`) by more than :data:`SCALE_RTOL`.
    where : str
        What names it in the messages (``light field 'lab'``); default the file.

    Returns
    -------
    (list of str, list of str, float)
        Problems and warnings, each a whole sentence naming the file, and the file's own scale
        (NaN where it cannot be read).
    """
    name = where or f"light probe {envmap}"
    try:
        probe = load_light_probe(envmap, normalise="none")
    except IlluminationError as exc:  # missing, unreadable, not 2:1, NaN, negative, black
        return [f"{where}: {exc}" if where else str(exc)], [], float("nan")
    problems, warnings = light_field_problems(probe.rgb)
    problems = [f"{name} ({probe.path}): {p}; {NEEDS}" for p in problems]
    warnings = [f"{name} ({probe.path}): {w}; {NEEDS}" for w in warnings]
    own = diffuse_white_scale(probe.rgb) if probe.luminance.max() > 0 else float("nan")
    problems += _scale_problem(name, scale, own, probe.path)
    return problems, warnings, own


def _scale_problem(name: str, scale: float | None, own: float, path: str) -> list[str]:
    """A design's scale that is not the file's own, as a sentence with the fix (or none)."""
    if scale is None or np.isnan(scale) or np.isnan(own) or abs(scale - own) <= SCALE_RTOL * own:
        return []
    return [(f"{name}: scale {scale:.6g} is not the file's own {own:.6g} ({scale / own:.4g} times "
            f"it; a matte white facing the viewer at luminance 1: `python -m stimuli probe-scale "
            f"{path}` prints it, the shipped probes' are in stimuli/probes/lightfields.tsv); "
            f"write scale = {own:.6g}")]


def design_light_field_report(design) -> tuple[list[str], list[str]]:
    """Check every panorama a design names: its illuminations and its light fields.

    Relative ``envmap`` paths are read from the design file's folder
    (:func:`stimuli.sets.design_envmap`). Returns (problems, warnings).
    """
    from stimuli.sets import design_envmap

    entries = [(f"illumination {il.name!r}", il.envmap, il.scale) for il in design.illuminations]
    entries += [(f"light field {lf.name!r}", lf.envmap, lf.scale)
                for lf in design.imagestats.light_fields]
    problems, warnings, seen = [], [], {}
    for where, envmap, scale in entries:
        path = design_envmap(design, envmap)
        missing = _not_beside_design(design, where, envmap, path)
        if missing and path not in seen:
            seen[path] = (missing, [], float("nan"))
            problems += missing
        if path not in seen:
            seen[path] = check_light_field_file(path, where=f"{where} ({envmap})")
            problems += seen[path][0]
            warnings += seen[path][1]
        problems += _scale_problem(f"{design.source}: {where} ({envmap})", scale, seen[path][2],
                                   path)
    return problems, warnings


def _not_beside_design(design, where: str, envmap: str, path: str) -> list[str]:
    """A relative envmap with no file in the design's folder (nor a shipped probe's name)."""
    if Path(envmap).is_absolute() or not Path(path).is_absolute() or Path(path).is_file():
        return []
    return [(f"{design.source}: {where}: envmap {envmap!r} is not in the design file's folder "
             f"({path} does not exist; a relative envmap is read from there, not from the "
             "current directory); put the panorama there, or give its absolute path")]


def refuse_bad_light_fields(plan, say=print) -> None:
    """Before a render: refuse a set whose panoramas are not light fields or whose scales are
    not their files' own; say the warnings (``say``, a line each).

    Parameters
    ----------
    plan : DataFrame
        Rows of a stimulus set (``envmap``, ``envmap_scale``; NaN: mean luminance 1).

    Raises
    ------
    IlluminationError
        Naming every problem, before any worker starts.
    """
    problems: list[str] = []
    pairs = plan[["envmap", "envmap_scale"]].drop_duplicates()
    for envmap, scale in pairs.itertuples(index=False):
        found, warnings, _ = check_light_field_file(envmap, scale=float(scale))
        problems += found
        for w in warnings:
            say(f"warning: {w}")
    if problems:
        raise IlluminationError("the set's light fields are refused (nothing was rendered):\n  "
                                + "\n  ".join(problems))

