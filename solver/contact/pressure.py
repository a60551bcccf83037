"""Where a body needs support: the pressure model of the paper's section 4.

The body is taken as fully enveloped by a perfectly fitting support, friction and the body's
weight are ignored, and each vertex facing down or sideways carries a normal reaction: with n its
unit normal, g the unit direction of gravity and A its Voronoi area,

    p = max(0, n . g)      |r_n| = A p      rho = |r_n| / max |r_n|

Vertices facing up carry nothing. The importance rho weights the surface fit; vertices outside
the body regions the designer chose get zero importance.

`model="equilibrium"` replaces max(0, n . g) by the normal compression of an envelope of springs
when the body, turning and leaning on friction, balances its weight and the weight's moment
(`solver.contact.equilibrium`); the default is the paper's model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from solver.mesh import face_cross, triangle_mesh

GRAVITY = (0.0, -1.0, 0.0)
MODELS = ("paper", "equilibrium")


@dataclass(frozen=True, eq=False)
class PressureField:
    """Per-vertex fields (V,): `pressure` p in [0, 1], `area` A (m^2), `reaction` |r_n| = A p,
    `importance` rho in [0, 1] (zero outside the chosen parts)."""

    pressure: np.ndarray
    area: np.ndarray
    reaction: np.ndarray
    importance: np.ndarray


def pressure_field(vertices: np.ndarray, triangles: np.ndarray, *,
                   gravity: Sequence[float] = GRAVITY, mask: np.ndarray | None = None,
                   normals: np.ndarray | None = None, areas: np.ndarray | None = None,
                   model: str = "paper", mu: float = 0.5, centre: np.ndarray | None = None
                   ) -> PressureField:
    """The pressure model on a posed body mesh.

    Parameters
    ----------
    vertices : (V, 3) float
        Posed body vertices, metres.
    triangles : (F, 3) int
        The body's triangles.
    gravity : (3,) float, default (0, -1, 0)
        Direction of gravity (normalised here; any non-zero length).
    mask : (V,) bool, optional
        The vertices of the supported body regions; the others get zero importance.
    normals : (V, 3) float, optional
        Precomputed unit vertex normals (otherwise from the mesh).
    areas : (V,) float, optional
        Precomputed Voronoi areas, m^2 (otherwise from the mesh).
    model : {"paper", "equilibrium"}, default "paper"
        The paper's p = max(0, n . g), or the normal compression of a balanced body in an
        envelope of springs, scaled to a largest value of 1 (`solver.contact.equilibrium`).
    mu : float, default 0.5
        Friction coefficient of the equilibrium model.
    centre : (3,) float, optional
        Where the weight acts in the equilibrium model (default: the centroid of the enclosed
        volume).

    Returns
    -------
    PressureField
        Per-vertex (V,) fields: pressure p in [0, 1], area A (m^2), reaction
        |r_n| = A p (m^2), and importance rho = |r_n| / max |r_n| in [0, 1], taken over the
        masked vertices (all zero when none carries any reaction).

    Raises
    ------
    ValueError
        If `gravity` is not a finite, non-zero (3,) direction, `model` or `mu` unknown, the
        vertices not finite (V, 3), a triangle index out of range or the mask of another length.
    """
    g = np.asarray(gravity, dtype=np.float64)
    norm = np.linalg.norm(g)
    if g.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise ValueError(f"Expected a non-zero gravity direction (3,), got {gravity!r}")
    g = g / norm
    if model not in MODELS or not mu >= 0:
        raise ValueError(f"Expected model in {MODELS} and mu >= 0, got {model!r} and {mu!r}")
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or triangles.ndim != 2 or \
            triangles.shape[1] != 3:
        raise ValueError(f"Expected (V, 3) vertices and (F, 3) triangles, got "
                         f"{vertices.shape} and {triangles.shape}")
    if triangles.size and (triangles.min() < 0 or triangles.max() >= len(vertices)):
        raise ValueError(f"Expected triangle indices in 0..{len(vertices) - 1}, got "
                         f"{triangles.min()}..{triangles.max()}")
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():  # (a NaN vertex would leave every importance 0, silently)
        raise ValueError(f"Expected finite vertices, got {int(bad.sum())} that are not "
                         f"(the first is vertex {int(np.flatnonzero(bad)[0])})")
    if mask is not None and np.shape(mask) != (len(vertices),):
        raise ValueError(f"Expected a mask of {len(vertices)} entries (one per vertex), got "
                         f"shape {np.shape(mask)}")
    if normals is None or areas is None:
        a, n = triangle_mesh(triangles, len(vertices)).measures(vertices)
        n = n if normals is None else np.asarray(normals)
        a = a if areas is None else np.asarray(areas)
    else:
        n, a = np.asarray(normals), np.asarray(areas)
    if model == "paper":
        pressure = np.maximum(0.0, n @ g)
    else:
        from solver.contact.equilibrium import equilibrium_compression
        from solver.mesh import volume_centroid

        v = np.asarray(vertices, dtype=np.float64)
        c = volume_centroid(v, triangles) if centre is None else np.asarray(centre, float)
        pressure = equilibrium_compression(v, n, a, g, c, mu=mu)
        pressure = pressure / max(pressure.max(), 1e-300)
    reaction = a * pressure
    supported = reaction if mask is None else np.where(mask, reaction, 0.0)
    peak = supported.max(initial=0.0)
    importance = supported / peak if peak > 0 else np.zeros_like(supported)
    return PressureField(pressure, a, reaction, importance)


def mould_vertices(vertices: np.ndarray, triangles: np.ndarray,
                   gravity=GRAVITY) -> np.ndarray:
    """(K,) the vertices of the faces that point down or sideways: the mould's contact set."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    fn = face_cross(v, t)
    facing = fn @ g >= 0  # not pointing up
    return np.unique(t[facing])


REACH_STEPS = (0.01, 0.02, 0.04, 0.08, 0.16)  # metres along the normal


def reachable(vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray,
              candidates: np.ndarray) -> np.ndarray:
    """(V,) bool: vertices a support could touch, those whose outward normal does not run
    straight back into the body within 16 cm (the underside of a belly over the thighs, the
    inner side of a thigh against the other). Only `candidates` (V,) bool are tested."""
    from solver.contact.skins import body_winding

    out = np.zeros(len(vertices), dtype=bool)
    idx = np.flatnonzero(candidates)
    if not idx.size:
        return out
    steps = np.asarray(REACH_STEPS)
    probes = (vertices[idx, None, :] + steps[None, :, None] * normals[idx, None, :]).reshape(-1, 3)
    # the skin's tree is kept: the evaluation's inside tests ask the same body again
    wn = body_winding(vertices, triangles).winding_number(probes)
    blocked = (wn.reshape(len(idx), len(steps)) > 0.5).any(axis=1)
    out[idx] = ~blocked
    return out
