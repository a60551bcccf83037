"""Synthetic surfaces with known curvature for the workshop tests."""

import numpy as np
import pytest
import trimesh

from solver.io.solid import boundary_edges


def bent_grid(radius: float = 0.012, bend: float = 1.0, columns: int = 161, rows: int = 9,
              width: float = 0.08, length: float = 0.04, height: float = 0.1):
    """A grid bent into a trough (bend = 1: hollow seen from above, towards +Y) or a ridge
    (bend = -1) of `radius` (m) in its middle, with straight flanks tangent to the arc at 60
    degrees; quads counter-clockwise seen from above (normals up, towards the bodies).
    Returns vertices (N, 3), quads (F, 4) and the arc's half width (m)."""
    theta0 = np.pi / 3
    half = radius * np.sin(theta0)
    x = np.linspace(-width / 2, width / 2, columns)
    inside = np.abs(x) <= half
    y = np.where(inside, radius - np.sqrt(np.maximum(radius ** 2 - x ** 2, 0.0)),
                 radius * (1 - np.cos(theta0)) + (np.abs(x) - half) * np.tan(theta0))
    z = np.linspace(0.0, length, rows)
    xx, zz = np.meshgrid(x, z)
    yy = np.broadcast_to(height + bend * y, xx.shape)
    vertices = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)
    idx = np.arange(rows * columns).reshape(rows, columns)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]],
                     axis=-1).reshape(-1, 4)
    return vertices, quads, half


@pytest.fixture
def trough():
    return bent_grid(bend=1.0)


@pytest.fixture
def ridge():
    return bent_grid(bend=-1.0, columns=81, rows=5)


@pytest.fixture
def fine_ridge():
    return bent_grid(bend=-1.0)


def underside_distances(solid):
    """trimesh's distances (not the solid module's) from the points of the solid's underside
    to the surface: of its vertices, then of the middles of its triangles (those not
    touching the surface, more than half the thickness below its inside)."""
    surface = trimesh.Trimesh(solid.vertices[:solid.n_surface], solid.surface_triangles,
                              process=False)
    below = solid.triangles[(solid.triangles >= solid.n_surface).all(axis=1)]
    corners = np.unique(below)
    probes = np.concatenate([solid.vertices[corners], solid.vertices[below].mean(axis=1)])
    closest, dist, _ = trimesh.proximity.closest_point(surface, probes)
    edges = surface.vertices[boundary_edges(solid.surface_triangles)]  # (B, 2, 3)
    a, ab = edges[:, 0], edges[:, 1] - edges[:, 0]
    to_border = np.concatenate([_to_segments(part, a, ab)
                                for part in np.array_split(closest, len(closest) // 2000 + 1)])
    keep = (to_border > 1e-4) & (dist > 0.5 * solid.thickness)
    return dist[:len(corners)][keep[:len(corners)]], dist[len(corners):][keep[len(corners):]]


def _to_segments(points, a, ab):
    """(P,) least distance from each point to the segments a -> a + ab."""
    s = np.clip(np.einsum("pbk,bk->pb", points[:, None] - a[None], ab) /
                np.einsum("bk,bk->b", ab, ab), 0.0, 1.0)
    return np.linalg.norm(points[:, None] - (a[None] + s[..., None] * ab[None]),
                          axis=2).min(axis=1)
