"""The ellipsoid array: 25 jittered half-ellipsoids on a flat backing, as triangle meshes (cm).

One array is drawn from a seed (:func:`draw_array`): grid centres from ``design.array`` jittered by
a uniform offset in ``[-jitter_cm, jitter_cm]`` along x and along y, each z radius uniform in
``[z_radius_min_fraction * d, d]`` for the depth level's ``d`` (cm); x/y radius ``radius_xy_cm``.
The half-ellipsoids are cut at z = 0, where the backing lies; +z points at the viewer.

Two meshes come from one array:

* :func:`render_mesh` for Mitsuba: each half-ellipsoid as a (theta, phi) grid whose vertex normals
  are the ellipsoid's analytic normals (Mitsuba's ``sphere`` refuses non-uniform scaling, and
  faceted normals would show as facets in the highlights), the 25 merged with a square backing into
  one mesh. Neighbouring ellipsoids overlap (pitch 1 cm, radius 1 cm); a ray tracer needs no union.
* :func:`print_mesh` for 3-D printing the physical depth set: the union of the bumps as a height
  field z(x, y) = max_k c_k sqrt(1 - |p - p_k|^2 / r^2) on a fine grid over a base slab, closed by
  side walls and a bottom, so it is watertight by construction (each edge in exactly two faces).
"""

from __future__ import annotations

import functools
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from labfiles import atomic_open
from studydesign import StudyDesign

__all__ = [
    "ArrayGeometry",
    "Mesh",
    "draw_array",
    "mesh_edges_ok",
    "print_mesh",
    "render_mesh",
    "stimulus_seed",
    "write_mesh",
]

#: Base of every per-stimulus seed (the project's start date); changing it changes every array.
SEED_BASE = 20261122
#: Smallest z radius meshed, cm: a z radius drawn as (almost) 0 becomes a 10 um flat cap.
MIN_Z_RADIUS_CM = 1e-3


@functools.lru_cache(maxsize=4096)
def stimulus_seed(depth_level: int, array_index: int = 0) -> int:
    """Seed of the array for a depth level and array index (32-bit, from ``SeedSequence``).

    The experiment uses one array per depth level (array_index 0), shared by all gloss levels and
    illuminations, so those differ only in material and light; the image-statistics set uses
    array indices 0..n-1.
    """
    ss = np.random.SeedSequence([SEED_BASE, int(depth_level), int(array_index)])
    return int(ss.generate_state(1, dtype=np.uint32)[0])


@dataclass(frozen=True)
class ArrayGeometry:
    """One drawn ellipsoid array (all lengths in cm).

    Attributes
    ----------
    centres_cm : ndarray, shape (n, 2)
        Jittered x, y centres.
    z_radii_cm : ndarray, shape (n,)
        Heights of the half-ellipsoids.
    radius_xy_cm : float
        x and y radius of every ellipsoid.
    depth_cm : float
        The depth level's maximum z radius ``d``.
    seed : int
        Seed the array was drawn from.
    """

    centres_cm: np.ndarray
    z_radii_cm: np.ndarray
    radius_xy_cm: float
    depth_cm: float
    seed: int

    @property
    def half_extent_cm(self) -> float:
        """Half-width of the square that holds every ellipsoid's footprint."""
        return float(np.max(np.abs(self.centres_cm)) + self.radius_xy_cm)


def draw_array(design: StudyDesign, depth_cm: float, seed: int) -> ArrayGeometry:
    """Draw one ellipsoid array (see the module docstring) from ``seed``.

    Parameters
    ----------
    design : StudyDesign
        Supplies ``design.array`` (grid, radii, jitter, z-radius range).
    depth_cm : float
        The depth level's d_i, cm (> 0).
    seed : int
        Record it: the same seed gives the same array.
    """
    if not depth_cm > 0:
        raise ValueError(f"depth_cm must be > 0, got {depth_cm}")
    spec = design.array
    rng = np.random.default_rng(seed)
    grid = spec.grid_centres_cm()
    jitter = rng.uniform(-spec.jitter_cm, spec.jitter_cm, size=grid.shape)
    z = rng.uniform(spec.z_radius_min_fraction * depth_cm, depth_cm, size=len(grid))
    return ArrayGeometry(centres_cm=grid + jitter, z_radii_cm=z, radius_xy_cm=spec.radius_xy_cm,
                         depth_cm=float(depth_cm), seed=int(seed))


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh: vertices (V, 3) cm, faces (F, 3) int32 counter-clockwise seen from outside,
    optional unit vertex normals (V, 3)."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None


def _half_ellipsoid(cx, cy, r, c, n_theta, n_phi):
    """Vertices, analytic normals and faces of one half-ellipsoid (theta from the pole to z=0)."""
    c = max(float(c), MIN_Z_RADIUS_CM)
    theta = np.linspace(0.0, np.pi / 2, n_theta + 1)[1:]  # rings below the pole
    phi = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False)
    tt, pp = np.meshgrid(theta, phi, indexing="ij")
    st, ct = np.sin(tt), np.cos(tt)
    ring = np.stack([cx + r * st * np.cos(pp), cy + r * st * np.sin(pp), c * ct], axis=-1)
    verts = np.vstack([[cx, cy, c], ring.reshape(-1, 3)])
    # normal = gradient of x^2/r^2 + y^2/r^2 + z^2/c^2: (x/r^2, y/r^2, z/c^2), normalised
    g = np.stack([st * np.cos(pp) / r, st * np.sin(pp) / r, ct / c], axis=-1).reshape(-1, 3)
    normals = np.vstack([[0.0, 0.0, 1.0], g / np.linalg.norm(g, axis=1, keepdims=True)])
    faces = []
    j = np.arange(n_phi)
    jn = (j + 1) % n_phi
    faces.append(np.column_stack([np.zeros(n_phi, int), 1 + j, 1 + jn]))
    for i in range(n_theta - 1):
        a, b = 1 + i * n_phi + j, 1 + i * n_phi + jn
        a2, b2 = a + n_phi, b + n_phi
        faces.append(np.column_stack([a, a2, b2]))
        faces.append(np.column_stack([a, b2, b]))
    return verts, normals, np.vstack(faces)


def render_mesh(geometry: ArrayGeometry, *, backing_half_cm: float, n_theta: int = 24,
                n_phi: int = 64) -> Mesh:
    """The array's 25 half-ellipsoids and a square backing (z = 0), merged into one mesh.

    Parameters
    ----------
    geometry : ArrayGeometry
        The drawn array.
    backing_half_cm : float
        Half-width of the backing square, cm; make it larger than the camera's view.
    n_theta, n_phi : int
        Rings from pole to rim and segments around, per ellipsoid (normals are analytic, so a
        moderate tessellation shows no facets in the shading; silhouettes are polygons of n_phi).
    """
    verts, normals, faces = [], [], []
    offset = 0
    for (cx, cy), c in zip(geometry.centres_cm, geometry.z_radii_cm):
        v, n, f = _half_ellipsoid(cx, cy, geometry.radius_xy_cm, c, n_theta, n_phi)
        verts.append(v)
        normals.append(n)
        faces.append(f + offset)
        offset += len(v)
    h = float(backing_half_cm)
    verts.append(np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]]))
    normals.append(np.tile([0.0, 0.0, 1.0], (4, 1)))
    faces.append(np.array([[0, 1, 2], [0, 2, 3]]) + offset)
    return Mesh(vertices=np.vstack(verts), faces=np.vstack(faces).astype(np.int32),
                normals=np.vstack(normals))


def print_mesh(geometry: ArrayGeometry, *, spacing_cm: float = 0.02, margin_cm: float = 0.5,
               base_cm: float = 0.3) -> Mesh:
    """A watertight solid of the array for 3-D printing (height field over a base slab).

    Parameters
    ----------
    geometry : ArrayGeometry
        The drawn array.
    spacing_cm : float
        Grid spacing of the height field (0.02 cm = 0.2 mm, about a printer's XY resolution).
    margin_cm : float
        Flat border around the bumps' footprint.
    base_cm : float
        Thickness of the slab under z = 0 (the top of the slab is the backing).

    Returns
    -------
    Mesh
        Closed, consistently oriented (outward) triangle surface; z from -base_cm to the top.
    """
    half = geometry.half_extent_cm + margin_cm
    n = int(np.ceil(2 * half / spacing_cm)) + 1
    xs = np.linspace(-half, half, n)
    gx, gy = np.meshgrid(xs, xs, indexing="xy")
    z = np.zeros_like(gx)
    r2 = geometry.radius_xy_cm**2
    for (cx, cy), c in zip(geometry.centres_cm, geometry.z_radii_cm):
        q = 1.0 - ((gx - cx) ** 2 + (gy - cy) ** 2) / r2
        z = np.maximum(z, c * np.sqrt(np.clip(q, 0.0, None)))
    idx = np.arange(n * n).reshape(n, n)  # idx[row=y, col=x]
    top = np.column_stack([gx.ravel(), gy.ravel(), z.ravel()])
    # top surface, counter-clockwise seen from +z
    a, b, c_, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    faces = [np.column_stack([a.ravel(), b.ravel(), c_.ravel()]),
             np.column_stack([a.ravel(), c_.ravel(), d.ravel()])]
    # boundary loop of the top grid, counter-clockwise seen from +z
    loop = np.concatenate([idx[0, :-1], idx[:-1, -1], idx[-1, :0:-1], idx[:0:-1, 0]])
    m = len(loop)
    bottom = top[loop].copy()
    bottom[:, 2] = -base_cm
    bot_idx = n * n + np.arange(m)
    nxt = np.roll(np.arange(m), -1)
    # side walls: quad (top i, top i+1, bottom i+1, bottom i), outward
    faces.append(np.column_stack([loop, bot_idx[nxt], loop[nxt]]))
    faces.append(np.column_stack([loop, bot_idx, bot_idx[nxt]]))
    # bottom: a fan around a centre vertex, clockwise seen from +z (outward = -z)
    centre = n * n + m
    faces.append(np.column_stack([np.full(m, centre), bot_idx[nxt], bot_idx]))
    verts = np.vstack([top, bottom, [[0.0, 0.0, -base_cm]]])
    return Mesh(vertices=verts, faces=np.vstack(faces).astype(np.int64))


def mesh_edges_ok(mesh: Mesh) -> tuple[bool, str]:
    """Check that a mesh is closed and consistently oriented.

    Every directed edge must appear exactly once and its reverse exactly once (each undirected edge
    in exactly two faces, traversed in opposite directions), and V - E + F = 2 (one closed surface
    of genus 0). Returns (ok, reason).
    """
    f = np.asarray(mesh.faces, dtype=np.int64)
    nv = len(mesh.vertices)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = directed[:, 0] * nv + directed[:, 1]
    uniq, counts = np.unique(key, return_counts=True)
    if np.any(counts != 1):
        return False, f"{int(np.sum(counts != 1))} directed edges used more than once"
    rev = directed[:, 1] * nv + directed[:, 0]
    if not np.all(np.isin(rev, uniq)):
        return False, f"{int(np.sum(~np.isin(rev, uniq)))} edges are on a boundary (no twin)"
    n_edges = len(uniq) // 2
    euler = nv - n_edges + len(f)
    if euler != 2:
        return False, f"Euler characteristic {euler} != 2"
    return True, "closed, oriented, genus 0"


#: Length units a mesh file can be written in: name -> units per cm.
MESH_UNITS_PER_CM = {"mm": 10.0, "cm": 1.0}


def write_mesh(mesh: Mesh, path: str | os.PathLike, *, units: str) -> Path:
    """Write a mesh as binary STL (``.stl``) or ASCII PLY (``.ply``), atomically.

    Parameters
    ----------
    mesh : Mesh
        Vertices in cm.
    path : str or PathLike
    units : {"mm", "cm"}
        Length unit of the numbers in the file. STL has no unit field and slicers (Cura,
        PrusaSlicer, GrabCAD Print) read it as millimetres, so "mm" prints at true size;
        the unit is also named in the STL header and a PLY comment.

    Raises
    ------
    ValueError
        Another suffix or unit.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".stl", ".ply"):
        raise ValueError(f"mesh file {path} must end in .stl or .ply")
    if units not in MESH_UNITS_PER_CM:
        raise ValueError(f"units {units!r}: use one of {list(MESH_UNITS_PER_CM)}")
    scale = MESH_UNITS_PER_CM[units]
    v = np.asarray(mesh.vertices, dtype=np.float64) * scale
    f = np.asarray(mesh.faces, dtype=np.int64)
    with atomic_open(path, "wb") as fh:
        if suffix == ".stl":
            tri = v[f].astype(np.float32)
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
            header = f"glossdepth ellipsoid array, units {units}".encode()
            fh.write(header.ljust(80, b" "))
            fh.write(struct.pack("<I", len(f)))
            rec = np.zeros(len(f), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
            rec["n"], rec["v"] = nrm, tri
            fh.write(rec.tobytes())
        else:
            lines = ["ply", "format ascii 1.0", f"comment units {units}",
                     f"element vertex {len(v)}", "property float x", "property float y",
                     "property float z", f"element face {len(f)}",
                     "property list uchar int vertex_indices", "end_header"]
            fh.write(("\n".join(lines) + "\n").encode())
            np.savetxt(fh, v, fmt="%.6f")
            np.savetxt(fh, np.column_stack([np.full(len(f), 3), f]), fmt="%d")
    return path
