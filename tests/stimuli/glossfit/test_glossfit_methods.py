"""The two fitting methods on an analytic renderer (no Mitsuba): same objective, same optimum.

The toy renderer is linear in the albedos by construction, R = B + rho_d D + rho_s S(alpha), with
a smooth shading D and a Gaussian highlight S(alpha) of width ~alpha; a photo made by it with
known parameters (times an exposure factor) must be recovered by both methods.
"""

from __future__ import annotations

import numpy as np
import pytest

from stimuli.glossfit import BasisCache, FitSettings, basis_fit, grid_fit


class ToyRenderer:
    def __init__(self, n: int = 40) -> None:
        y, x = (np.mgrid[0:n, 0:n] + 0.5) / n - 0.5
        self.mask = np.hypot(x, y) < 0.45
        self._d = (0.6 + 0.4 * (0.5 - y))[..., None] * self.mask[..., None]
        self._r2 = (x + 0.15) ** 2 + (y + 0.2) ** 2
        self._b = 0.3 * (~self.mask)[..., None]
        self.n_renders = 0

    def render(self, rho_d, rho_s, alpha):
        self.n_renders += 1
        spec = np.exp(-self._r2 / (2 * alpha**2)) / (alpha**2) * 0.01
        img = self._b + rho_d * self._d + rho_s * spec[..., None] * self.mask[..., None]
        return np.repeat(img.mean(axis=-1, keepdims=True), 3, axis=-1).astype(np.float64)


@pytest.mark.parametrize("truth", [(0.4, 0.05, 0.12), (0.3, 0.1, 0.06), (0.5, 0.03, 0.2)])
def test_grid_and_basis_recover_the_toy_truth(truth):
    toy = ToyRenderer()
    photo = 7.5 * toy.render(*truth)[..., 0]  # another exposure: albedos come out x 7.5
    lum_mask = toy.mask
    g = grid_fit(toy, photo, lum_mask, FitSettings(method="grid"))
    grid_renders = toy.n_renders
    toy.n_renders = 0
    b = basis_fit(BasisCache(toy), photo, lum_mask, FitSettings())
    # The basis fit lands on the truth; the grid within the 0.005 of it (its shrinking
    # window can stop while still crawling along a curved valley: alpha 0.2036 for 0.2 here).
    assert b.alpha == pytest.approx(truth[2], abs=0.001)
    assert b.rho_s / 7.5 == pytest.approx(truth[1], rel=0.01)
    assert b.rho_d / 7.5 == pytest.approx(truth[0], rel=0.01)
    assert abs(g.alpha - b.alpha) < 0.005 and abs(g.rho_s - b.rho_s) / 7.5 < 0.005
    assert grid_renders >= 10 * b.n_renders
    assert b.error <= g.error + 1e-8  # as good as the grid, up to Brent's tolerance in alpha
