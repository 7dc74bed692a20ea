"""The ellipsoid array: drawn from the design and a seed; meshes for rendering and printing."""

from __future__ import annotations

import numpy as np
import pytest

from stimuli.geometry import (
    Mesh,
    draw_array,
    mesh_edges_ok,
    print_mesh,
    render_mesh,
    stimulus_seed,
    write_mesh,
)


def test_array_follows_the_design_and_the_seed(design):
    d = design.depth.cm(5)
    a = draw_array(design, d, stimulus_seed(5))
    spec = design.array
    assert a.centres_cm.shape == (spec.n_ellipsoids, 2)
    assert np.all(np.abs(a.centres_cm - spec.grid_centres_cm()) <= spec.jitter_cm)
    assert np.all((a.z_radii_cm >= spec.z_radius_min_fraction * d) & (a.z_radii_cm <= d))
    b = draw_array(design, d, stimulus_seed(5))
    assert np.array_equal(a.centres_cm, b.centres_cm) and np.array_equal(a.z_radii_cm, b.z_radii_cm)
    assert stimulus_seed(5) != stimulus_seed(6) != stimulus_seed(6, 1)


def test_render_mesh_normals_are_the_ellipsoids_analytic_normals(design):
    a = draw_array(design, design.depth.cm(10), stimulus_seed(10))
    m = render_mesh(a, backing_half_cm=10.0, n_theta=8, n_phi=16)
    assert np.allclose(np.linalg.norm(m.normals, axis=1), 1.0)
    # vertices of ellipsoid 0: the normal is parallel to (x/r^2, y/r^2, z/c^2)
    n_per = 1 + 8 * 16
    (cx, cy), c, r = a.centres_cm[0], max(a.z_radii_cm[0], 1e-3), a.radius_xy_cm
    p = m.vertices[:n_per] - [cx, cy, 0.0]
    assert np.allclose((p[:, 0] / r) ** 2 + (p[:, 1] / r) ** 2 + (p[:, 2] / c) ** 2, 1.0)
    g = p / [r**2, r**2, c**2]
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    assert np.allclose(g, m.normals[:n_per], atol=1e-9)
    assert m.vertices[:, 2].min() == 0.0 and m.vertices[:, 2].max() <= design.depth.cm(10)


def test_print_mesh_is_watertight_and_has_the_depth(design, tmp_path):
    d = design.depth.cm(5)
    a = draw_array(design, d, stimulus_seed(5))
    m = print_mesh(a, spacing_cm=0.1)
    ok, why = mesh_edges_ok(m)
    assert ok, why
    assert m.vertices[:, 2].max() == pytest.approx(a.z_radii_cm.max(), rel=0.05)
    # signed volume (divergence theorem) is positive: faces point outwards
    v = m.vertices[m.faces]
    volume = np.sum(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2]))) / 6
    assert volume > 0
    # a mesh with a hole is caught
    holed = Mesh(vertices=m.vertices, faces=m.faces[1:])
    assert not mesh_edges_ok(holed)[0]
    write_mesh(m, tmp_path / "a.stl", units="mm")
    data = (tmp_path / "a.stl").read_bytes()
    assert len(data) == 84 + 50 * len(m.faces)
    write_mesh(m, tmp_path / "a.ply", units="mm")
    assert (tmp_path / "a.ply").read_text().startswith("ply")
