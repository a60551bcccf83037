"""Where a body needs support: the pressure model of the paper's section 4.

The body is taken as fully enveloped by a perfectly fitting support, friction and the body's
weight are ignored, and each vertex facing down or sideways carries a normal reaction: with n its
unit normal, g the unit direction of gravity and A its Voronoi area,

    p = max(0, n . g)      |r_n| = A p      rho = |r_n| / max |r_n|

Vertices facing up carry nothing. The importance rho weights the surface fit; vertices outside
the body parts the designer chose get zero importance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

GRAVITY = (0.0, -1.0, 0.0)


@dataclass(frozen=True, eq=False)
class PressureField:
    """Per-vertex fields (V,): `pressure` p in [0, 1], `area` A (m^2), `reaction` |r_n| = A p,
    `importance` rho in [0, 1] (zero outside the chosen parts)."""

    pressure: np.ndarray
    area: np.ndarray
    reaction: np.ndarray
    importance: np.ndarray


class TriangleMesh:
    """Per-topology operators for fast Voronoi areas and vertex normals of a triangle mesh.

    Computed column by column (structure of arrays), with the scatter to vertices as sparse
    products, which on a 26k-triangle body is several times faster than libigl's mass matrix
    construction; the tests check both against libigl.
    """

    def __init__(self, triangles: np.ndarray, n_vertices: int):
        t = np.asarray(triangles, dtype=np.int64)
        if t.ndim != 2 or t.shape[1] != 3:
            raise ValueError(f"Expected triangles (F, 3), got {t.shape}")
        self.n = int(n_vertices)
        self.t0, self.t1, self.t2 = (np.ascontiguousarray(t[:, k]) for k in range(3))
        f = len(t)
        rows = np.concatenate([self.t0, self.t1, self.t2])
        self.corner_sum = sp.csr_matrix((np.ones(3 * f), (rows, np.arange(3 * f))),
                                        shape=(self.n, 3 * f))
        self.face_sum = sp.csr_matrix((np.ones(3 * f), (rows, np.tile(np.arange(f), 3))),
                                      shape=(self.n, f))

    def measures(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(V,) Voronoi (mixed) areas and (V, 3) area-weighted unit normals."""
        v = np.asarray(vertices, dtype=np.float64)
        x, y, z = v[:, 0].copy(), v[:, 1].copy(), v[:, 2].copy()
        x0, y0, z0 = x.take(self.t0), y.take(self.t0), z.take(self.t0)
        x1, y1, z1 = x.take(self.t1), y.take(self.t1), z.take(self.t1)
        x2, y2, z2 = x.take(self.t2), y.take(self.t2), z.take(self.t2)
        # the edge opposite each corner
        ax, ay, az = x2 - x1, y2 - y1, z2 - z1
        bx, by, bz = x0 - x2, y0 - y2, z0 - z2
        cx, cy, cz = x1 - x0, y1 - y0, z1 - z0
        nx, ny, nz = by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx  # 2 x area vector
        dbl = np.sqrt(nx * nx + ny * ny + nz * nz)
        la, lb, lc = ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz, \
            cx * cx + cy * cy + cz * cz
        # dot products of the two edges leaving each corner (cot = dot / (2 area))
        d0 = -(cx * bx + cy * by + cz * bz)
        d1 = -(ax * cx + ay * cy + az * cz)
        d2 = -(bx * ax + by * ay + bz * az)
        inv = 0.125 / np.maximum(dbl, 1e-300)
        w0, w1, w2 = (lb * d1 + lc * d2) * inv, (lc * d2 + la * d0) * inv, (la * d0 + lb * d1) * inv
        obtuse = (d0 < 0) | (d1 < 0) | (d2 < 0)
        if obtuse.any():  # Meyer et al.: half the area to the obtuse corner, a quarter to others
            q = dbl[obtuse] * 0.125
            for w, d in ((w0, d0), (w1, d1), (w2, d2)):
                w[obtuse] = np.where(d[obtuse] < 0, 2 * q, q)
        areas = self.corner_sum @ np.concatenate([w0, w1, w2])
        vx, vy, vz = self.face_sum @ nx, self.face_sum @ ny, self.face_sum @ nz
        norm = np.sqrt(vx * vx + vy * vy + vz * vz)
        normals = np.empty((self.n, 3))
        normals[:, 0], normals[:, 1], normals[:, 2] = vx / norm, vy / norm, vz / norm
        return areas, normals


_MESHES: dict[tuple, TriangleMesh] = {}


def triangle_mesh(triangles: np.ndarray, n_vertices: int) -> TriangleMesh:
    """The cached `TriangleMesh` of a topology."""
    t = np.asarray(triangles)
    key = (n_vertices, t.shape, hash(t.tobytes()))
    mesh = _MESHES.get(key)
    if mesh is None:
        if len(_MESHES) > 16:
            _MESHES.clear()
        mesh = _MESHES[key] = TriangleMesh(t, n_vertices)
    return mesh


def voronoi_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V,) Voronoi (mixed) area of each vertex, m^2."""
    return triangle_mesh(triangles, len(vertices)).measures(vertices)[0]


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 3) unit normals, area-weighted."""
    return triangle_mesh(triangles, len(vertices)).measures(vertices)[1]


def pressure_field(vertices: np.ndarray, triangles: np.ndarray, *,
                   gravity: Sequence[float] = GRAVITY, mask: np.ndarray | None = None,
                   normals: np.ndarray | None = None, areas: np.ndarray | None = None
                   ) -> PressureField:
    """The pressure model on a posed body mesh.

    vertices : (V, 3) metres; triangles : (F, 3).
    gravity : direction of gravity (normalised here).
    mask : optional (V,) bool, the vertices of the supported body parts.
    normals, areas : optional precomputed (V, 3) unit normals and (V,) areas.
    """
    g = np.asarray(gravity, dtype=np.float64)
    norm = np.linalg.norm(g)
    if g.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise ValueError(f"Expected a non-zero gravity direction (3,), got {gravity!r}")
    g = g / norm
    if normals is None or areas is None:
        a, n = triangle_mesh(triangles, len(vertices)).measures(vertices)
        n = n if normals is None else np.asarray(normals)
        a = a if areas is None else np.asarray(areas)
    else:
        n, a = np.asarray(normals), np.asarray(areas)
    pressure = np.maximum(0.0, n @ g)
    reaction = a * pressure
    supported = reaction if mask is None else np.where(mask, reaction, 0.0)
    peak = supported.max(initial=0.0)
    importance = supported / peak if peak > 0 else np.zeros_like(supported)
    return PressureField(pressure, a, reaction, importance)


REACH_STEPS = (0.01, 0.02, 0.04, 0.08, 0.16)  # metres along the normal


def reachable(vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray,
              candidates: np.ndarray) -> np.ndarray:
    """(V,) bool: vertices a support could touch, those whose outward normal does not run
    straight back into the body within 16 cm (the underside of a belly over the thighs, the
    inner side of a thigh against the other). Only `candidates` (V,) bool are tested."""
    import igl

    out = np.zeros(len(vertices), dtype=bool)
    idx = np.flatnonzero(candidates)
    if not idx.size:
        return out
    steps = np.asarray(REACH_STEPS)
    probes = (vertices[idx, None, :] + steps[None, :, None] * normals[idx, None, :]).reshape(-1, 3)
    wn = igl.fast_winding_number(np.asarray(vertices, dtype=np.float64),
                                 np.asarray(triangles, dtype=np.int64), probes)
    blocked = (wn.reshape(len(idx), len(steps)) > 0.5).any(axis=1)
    out[idx] = ~blocked
    return out
