"""The clear coat under directional lights: a coat over a glossy base shows two lobes and the
base's transmission loss; a second lobe alone is the broad lobe, not a coat.

The photos are drawn in NumPy from the physics (exact Fresnel of IOR 1.5, Ward lobes of
``model.ward_lobe``) on a 32 px sphere under 8 lights, 4 fitted and 4 held out; the fit's
components are what a single-lobe Ward fit keeps (the diffuse shading and one lobe). Each
candidate is fitted on the fitted lights and scored, as the diagnosis scores it alone, by the
held-out loss it removes.
"""

from __future__ import annotations

import numpy as np

from analysis.gap.engine import catalogue
from analysis.gap.render import RenderData, render_loss
from analysis.gap.render.data import _light_level
from analysis.gap.render.optics.sphere import _fresnel_coat, ward_lobe

SIZE, RADIUS = 32, 12.3
RHO_D, RHO_S, F0 = 0.4, 0.08, 0.04
#: Ward widths: the coat's sharp lobe (what the single-lobe fit took), the glossy base's lobe
#: beneath it, a hazy second lobe (the broad-lobe photos).
ALPHA_COAT, ALPHA_BASE, ALPHA_HAZE = 0.1, 0.25, 0.6


def _lights() -> list[np.ndarray]:
    out = []
    for k in range(8):
        polar, az = np.radians(20 + 30 * (k % 3) / 2), 2 * np.pi * k / 8 + 0.3
        out.append(np.array([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az),
                             np.cos(polar)]))
    return out


def _levels(photo_of, seed: int = 0) -> tuple[RenderData, RenderData]:
    """(train, test) light levels: lights 0, 2, 4, 6 fitted, 1, 3, 5, 7 held out; ``photo_of
    (normals, light, ndl)`` the noiseless photo (photo units, ~1000 at the highlight)."""
    rng = np.random.default_rng(seed)
    yy, xx = (np.mgrid[0:SIZE, 0:SIZE] - (SIZE - 1) / 2 - 0.2) / RADIUS
    inside = yy**2 + xx**2 < 1
    normals = np.stack([xx, -yy, np.sqrt(np.clip(1 - xx**2 - yy**2, 0, 1))]) * inside
    mask = yy**2 + xx**2 < ((RADIUS - 1) / RADIUS) ** 2  # 1 px inside, as the fit's mask
    train, test = [], []
    for k, light in enumerate(_lights()):
        ndl = np.clip(np.tensordot(light, normals, axes=1), 0, None) * inside
        diffuse = 1000 * RHO_D / np.pi * ndl
        specular = 1000 * F0 * ward_lobe(normals, light, ALPHA_COAT) * inside
        clean = photo_of(normals, light, ndl) * inside
        photo = clean + rng.normal(0, 1, clean.shape) * np.sqrt(4 + clean)
        rgb = [np.repeat(x[..., None], 3, axis=2).astype(np.float32)
               for x in (photo, diffuse + specular, diffuse, specular)]
        # The fit's pixels: inside the mask, lit above n.l = 0.1 (stimuli.glossfit.lightfit).
        arrays = dict(zip(("photo", "render", "diffuse", "specular"), rgb),
                      highlight=np.zeros_like(mask), body=mask, rim=np.zeros_like(mask),
                      background=~inside, sphere=mask, valid=mask & (ndl > 0.1), light=light,
                      normals=np.moveaxis(normals, 0, -1))
        (test if k % 2 else train).append(_light_level(f"light_{k + 1:03d}", arrays,
                                                       held_out=bool(k % 2)))
    return RenderData(train), RenderData(test)


def _coated(normals, light, ndl):
    """A clear coat (IOR 1.5) over a glossy Ward base: the coat's sharp lobe weighted by its
    Fresnel reflectance at the half angle, the base's light (diffuse and its own lobe)
    through the coat on the way in and out."""
    cos_o = np.clip(normals[2], 0, 1)
    half = (light + [0, 0, 1]) / np.linalg.norm(light + [0, 0, 1])
    through = (1 - _fresnel_coat(ndl)) * (1 - _fresnel_coat(cos_o))
    base = RHO_D / np.pi * ndl + RHO_S * ward_lobe(normals, light, ALPHA_BASE)
    coat = _fresnel_coat(float(half[2])) * ward_lobe(normals, light, ALPHA_COAT)
    return 1000 * (coat + through * base)


def _hazy(normals, light, ndl):
    """The fitted material with a second, hazy lobe beside its own (no coat)."""
    return 1000 * (RHO_D / np.pi * ndl + F0 * ward_lobe(normals, light, ALPHA_COAT)
                   + RHO_S * ward_lobe(normals, light, ALPHA_HAZE))


def _gains(train: RenderData, test: RenderData) -> dict:
    """Each candidate's held-out gain alone (nats per pixel)."""
    plain = render_loss(test, [])
    out = {}
    for cand in catalogue("render") + catalogue("render_lights"):
        if cand.name in ("clearcoat", "broad_lobe"):
            params = cand.fit(train, [])
            out[cand.name] = float(np.mean(plain - render_loss(test, [(cand.name, params)])))
    return out


def test_coated_sphere_under_lights_is_a_coat_before_a_second_lobe():
    """The coat's photos: its own lobe and the base's, and the base dimmed through the coat.
    A second lobe alone explains the lobes, the coat both: clearcoat gains more than
    broad_lobe on the held-out lights (before, the coat was only the diffuse light's
    transmission, and the broad lobe came first)."""
    gains = _gains(*_levels(_coated))
    assert gains["clearcoat"] > gains["broad_lobe"] > 0, gains


def test_hazy_sphere_under_lights_is_a_second_lobe_not_a_coat():
    """A second lobe without a coat's transmission loss: broad_lobe gains more than
    clearcoat, whose loss is fixed by its index, not fitted away."""
    gains = _gains(*_levels(_hazy))
    assert gains["broad_lobe"] > gains["clearcoat"], gains
