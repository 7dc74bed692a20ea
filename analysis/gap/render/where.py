"""Where the render layer's misfit lies.

:func:`render_where`: the gloss level and region of the sphere carrying most of the held-out
loss above the ceiling, in words; :func:`localise_render`: the plain render's mean residual per
region and gloss level with block-bootstrap CIs; :func:`residual_maps`: residuals in noise SDs
per level, before and after the chosen steps.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.render.data import _BLOCK, REGIONS, RenderData
from analysis.gap.render.model import _predict, render_loss


def render_where(fits: list) -> str:
    """Words for where the chosen model falls short of the ceiling: the gloss level and the
    region of the sphere (highlight, body, rim, background) that carry most of the held-out
    excess loss, whether the photo is brighter or darker than the extended render there, and
    that cell's share of the excess. The misfit's size is :func:`render_misfit_pct`'s.

    ``fits``: ``[(train, test, fitted, ceiling_loss), ...]`` per fold (see
    engine.diagnose_losses; ``ceiling_loss`` from `render_ceiling`, in `render_loss`'s order).
    """
    cells: dict = {}
    for _train, test, fitted, ceiling_loss in fits:
        excess = render_loss(test, list(fitted)) - ceiling_loss
        start = 0
        for lv in test.levels:
            m = lv["use"]
            n = int(m.sum())
            ex = excess[start:start + n]
            res = (lv["P"] - _predict(lv, list(fitted)))[m]
            start += n
            for reg in REGIONS:
                r = lv["regions"][reg][m]
                if r.any():
                    c = cells.setdefault((lv["name"], reg), [0.0, 0.0])
                    c[0] += float(ex[r].sum())
                    c[1] += float(res[r].sum())
    total = sum(max(v[0], 0.0) for v in cells.values())
    if not cells or total <= 0:
        return ""
    (name, reg), (ex, res) = max(cells.items(), key=lambda kv: kv[1][0])
    side = "brighter" if res > 0 else "darker"
    return (f"mostly in the {reg} of level {name} (the photo {side} than the extended render "
            f"there; {100 * max(ex, 0.0) / total:.0f} % of the excess)")


def localise_render(data: RenderData, rng: np.random.Generator,
                    n_boot: int = 500) -> pd.DataFrame:
    """Mean residual (photo - render, % of the level's mean sphere luminance) per region and
    gloss level, 95 % CIs by a bootstrap over 4 x 4 px blocks (pixels within a block are not
    independent)."""
    rows = []
    for lv in data.levels:
        R = lv["B"] + lv["D"] + lv["S"]
        sph = lv["regions"]["highlight"] | lv["regions"]["body"] | lv["regions"]["rim"]
        scale = float(np.mean(lv["P"][sph])) if sph.any() else 1.0
        res = 100 * (lv["P"] - R) / max(scale, 1e-12)
        h, w = res.shape
        yy, xx = np.mgrid[0:h, 0:w]
        block = (yy // _BLOCK) * (w // _BLOCK + 1) + xx // _BLOCK
        for reg in REGIONS:
            m = lv["regions"][reg]
            if not m.any():
                continue
            frame = pd.DataFrame({"b": block[m], "r": res[m]})
            sums = frame.groupby("b")["r"].agg(["sum", "size"]).to_numpy()
            idx = rng.integers(0, len(sums), (n_boot, len(sums)))
            boot = sums[idx, 0].sum(axis=1) / sums[idx, 1].sum(axis=1)
            lo, hi = np.percentile(boot, [2.5, 97.5])
            # The mean as the resamples compute it (block sums over block sizes), so a cell
            # of one block has its CI at its mean exactly.
            rows.append({"axis": "region", "cell": f"{lv['name']}: {reg}", "n": int(m.sum()),
                         "mean_residual": float(sums[:, 0].sum() / sums[:, 1].sum()),
                         "ci_low": float(lo),
                         "ci_high": float(hi), "unit": "% of mean sphere luminance"})
    return pd.DataFrame(rows)


def residual_maps(data: RenderData, fitted: list) -> dict:
    """Residual maps in noise SDs, (photo - render) / sd, per gloss level: of the plain render
    and of the render extended by ``fitted`` (the diagnosis's chosen steps, parameters as in
    ``Diagnosis.steps``). NaN outside the pixels the loss uses (the sphere's valid pixels).

    Returns
    -------
    dict
        ``{level name: {"photo": P, "prediction": the extended render, "before": z,
        "after": z}}``, each (h, w) float.
    """
    out = {}
    for lv in data.levels:
        valid = lv["fit"]
        maps = {"photo": lv["P"], "prediction": _predict(lv, fitted)}
        for key, steps in (("before", []), ("after", fitted)):
            z = (lv["P"] - _predict(lv, steps)) / lv["sd"]
            maps[key] = np.where(valid, z, np.nan)
        out[lv["name"]] = maps
    return out
