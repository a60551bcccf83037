"""The least peak pressure any support could give a body at rest: a bound a fitted surface's peak
is measured against, beside the flat seat.

A rigid posed body rests on some of its skin (the `supported` vertices whose outward normal
does not point up by more than `FACING_UP`, which a support from below or beside can reach),
and optionally on the floor under its feet. A support pushes each skin vertex k along its inward
normal with a pressure p_k >= 0 over the vertex's area A_k, and, with friction mu > 0, along the
skin with a tangential traction t_k within the Coulomb cone |t_k| <= mu p_k. The floor pushes
straight up, anywhere under the feet, with no bound on its pressure. The forces balance the
weight, and their moments about the centre of mass balance. The least peak max_k p_k over every
such set of forces is a linear programme, solved by HiGHS (`scipy.optimize.linprog`): the cone
is replaced by the polygon of `CONE_SIDES` sides drawn round it (d_j . t_k <= mu p_k for unit
tangent directions d_j, one of them along the skin's slope), which holds every traction the cone
holds, so the programme's least peak is never above the cone's (a bound from below, within
1 / cos(pi / CONE_SIDES) - 1 = 2 % of it; an inner pyramid, as before, gave a peak up to 1.3 %
above the cone's on `single_seated`, no bound).

No surface shape can give that body a lower peak at rest with those contact laws, so a fitted
surface's peak over this bound says how far the shape is from the best any shape could do; over
the flat seat's, whether the bar is within reach at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solver.contact.mat import G
from solver.contact.pressure import GRAVITY
from solver.mesh import volume_centroid

FACING_UP = 0.17  # the largest upward component (sine, ~10 degrees) of a reachable skin normal
FLOOR_BAND = 0.02  # metres above the lowest foot vertex that count as the soles
CONE_SIDES = 16  # sides of the polygon round the friction cone


class BoundError(ValueError):
    """No set of forces balances the body (or the programme failed), and why."""


@dataclass(frozen=True)
class LeastPeak:
    """The least peak pressure `peak_kpa`, the skin vertices that carry pressure (`vertices`)
    and their pressure (`pressure_kpa`), the vertical load the support carries (`support_n`)
    and the floor's (`floor_n`), in newtons."""

    peak_kpa: float
    vertices: np.ndarray
    pressure_kpa: np.ndarray
    support_n: float
    floor_n: float


def least_peak(vertices: np.ndarray, normals: np.ndarray, areas: np.ndarray,
               triangles: np.ndarray, supported: np.ndarray, mass_kg: float, *,
               feet: np.ndarray | None = None, support_load_n: float | None = None,
               mu: float = 0.0, gravity=GRAVITY) -> LeastPeak:
    """The least peak pressure any support of the `supported` skin could give the body at rest
    (see the module docstring).

    Parameters
    ----------
    vertices, normals : (V, 3) the posed skin, metres, and its unit outward normals.
    areas : (V,) Voronoi areas, m^2.
    triangles : (F, 3) the closed skin (for the centre of mass).
    supported : (V,) bool, the skin a support may press.
    mass_kg : the body's mass.
    feet : (V,) bool, optional: the feet's vertices; those within FLOOR_BAND of the lowest
        stand on the floor, which may carry any share of the weight.
    support_load_n : optional: the vertical load the support must carry (the floor the rest),
        as a fitted surface carries it, so that a peak is compared at the same load.
    mu : friction coefficient between skin and support (0: pressure along the normal only).
    gravity : the direction of gravity.

    Returns
    -------
    LeastPeak. Raises BoundError when no forces of that kind balance the body.
    """
    from scipy.optimize import linprog

    x = np.asarray(vertices, dtype=np.float64)
    n, a = np.asarray(normals, dtype=np.float64), np.asarray(areas, dtype=np.float64)
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    up = -g
    skin = np.flatnonzero(np.asarray(supported, dtype=bool) & (n @ up <= FACING_UP) & (a > 0))
    if not len(skin):
        raise BoundError("No supported skin faces down or sideways: nothing can carry the body")
    centre = volume_centroid(x, np.asarray(triangles, dtype=np.int64))
    weight = mass_kg * G
    # columns: pressure per skin vertex (Pa), floor forces (N), tangential tractions (Pa), peak
    push = -(a[skin, None] * n[skin])  # force per unit pressure (into the body)
    columns = [push]
    soles = np.zeros(0, dtype=np.int64)
    if feet is not None and np.any(feet):
        foot = np.flatnonzero(feet)
        lowest = float((x[foot] @ up).min())
        soles = foot[x[foot] @ up <= lowest + FLOOR_BAND]
        columns.append(np.tile(up, (len(soles), 1)))
    tangents = np.zeros((0, 3))
    if mu > 0:  # two tangential traction components per skin vertex, free in sign
        first = np.cross(n[skin], up)
        flat = np.linalg.norm(first, axis=1) < 1e-6  # (a normal along gravity)
        first[flat] = np.cross(n[skin][flat], [1.0, 0.0, 0.0] if abs(up[0]) < 0.9
                               else [0.0, 1.0, 0.0])
        first /= np.linalg.norm(first, axis=1, keepdims=True)
        second = np.cross(n[skin], first)
        tangents = np.concatenate([first, second]) * np.tile(a[skin], 2)[:, None]
        columns.append(tangents)
    where = np.concatenate([x[skin], x[soles], np.tile(x[skin], (2 if mu > 0 else 0, 1))])
    forces = np.concatenate(columns)
    k, s, t = len(skin), len(soles), len(tangents)
    count = k + s + t + 1
    balance = np.zeros((6, count))
    balance[:3, :-1] = forces.T
    balance[3:, :-1] = np.cross(where - centre, forces).T
    target = np.concatenate([weight * up, np.zeros(3)])
    if support_load_n is not None:  # the support's vertical share, as given
        share = np.zeros((1, count))
        share[0, :k] = push @ up
        share[0, k + s:-1] = tangents @ up
        balance = np.vstack([balance, share])
        target = np.append(target, support_load_n)
    eye = sp.identity(k, format="csr")
    rows = [sp.hstack([eye, sp.csr_matrix((k, s + t)), sp.csr_matrix(-np.ones((k, 1)))])]
    if t:  # tangential tractions within the polygon round the cone of mu times the pressure
        for angle in 2 * np.pi * np.arange(CONE_SIDES) / CONE_SIDES:
            rows.append(sp.hstack([-mu * eye, sp.csr_matrix((k, s)), np.cos(angle) * eye,
                                   np.sin(angle) * eye, sp.csr_matrix((k, 1))]))
    bounded = sp.vstack(rows).tocsr()
    cost = np.zeros(count)
    cost[-1] = 1.0
    scale = max(weight / a[skin].sum(), 1.0)  # Pa: the programme in units of a mean pressure
    result = linprog(cost, A_ub=bounded, b_ub=np.zeros(bounded.shape[0]),
                     A_eq=balance * np.r_[np.full(k, scale), np.ones(s), np.full(t, scale),
                                          scale][None, :],
                     b_eq=target, method="highs",
                     bounds=[(0, None)] * (k + s) + [(None, None)] * t + [(0, None)])
    if result.status != 0:
        raise BoundError(f"No forces of that kind balance the body: HiGHS says "
                         f"{result.message}")
    values = result.x
    pressure = values[:k] * scale
    carried = pressure @ (push @ up) + (values[k + s:-1] * scale) @ (tangents @ up)
    return LeastPeak(float(values[-1] * scale / 1e3), skin[pressure > 0],
                     pressure[pressure > 0] / 1e3, float(carried), float(values[k:k + s].sum()))
