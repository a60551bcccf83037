"""The equilibrium-aware importance model: the paper's envelope, with force and moment balance.

The paper's model loads each vertex facing down or sideways by A max(0, n . g): what a rigid
body that sinks straight into an envelope of springs feels. A real body also turns, until the
support's forces balance the moment of its weight about its centre of mass, and leans on
friction. Here the envelope is a layer of springs per unit area on the vertices whose normal
does not point up, normal stiffness 1 and tangential stiffness `shear_ratio` (a foam layer's
G / E_oed), with Coulomb friction mu capping the tangential force; the body's small rigid motion
(u, theta) is found so that the forces balance a unit load along gravity through the centre and
its moment, by a semi-smooth Newton method on the six unknowns (each iteration one pass over the
vertices and a 6 x 6 solve). The normal compression delta_k = n_k . (u + theta x x_k), clipped
at zero, replaces the paper's max(0, n . g).
"""

from __future__ import annotations

import numpy as np

SHEAR_RATIO = (1 - 2 * 0.4) / (2 * (1 - 0.4))  # G / E_oed of a foam with Poisson's ratio 0.4


def _cross_matrices(x: np.ndarray) -> np.ndarray:
    """(K, 3, 3) [x]_x with [x]_x y = x X y."""
    m = np.zeros((len(x), 3, 3))
    m[:, 0, 1], m[:, 0, 2], m[:, 1, 2] = -x[:, 2], x[:, 1], -x[:, 0]
    m[:, 1, 0], m[:, 2, 0], m[:, 2, 1] = x[:, 2], -x[:, 1], x[:, 0]
    return m


def _forces(z, n, a, x, cross, mu, shear):
    """Spring forces (K, 3) on the support under the motion z = (u, theta) and their
    derivatives (K, 3, 6)."""
    lever = np.concatenate([np.broadcast_to(np.eye(3), cross.shape), -cross], axis=2)  # d = L z
    d = z[:3] + np.cross(z[3:], x)
    delta = np.einsum("ij,ij->i", d, n)
    active = delta > 0
    rows = np.einsum("ij,ijk->ik", n, lever)  # d delta / dz (K, 6)
    f = (a * np.maximum(delta, 0.0))[:, None] * n
    jac = np.where(active[:, None, None], (a[:, None] * n)[:, :, None] * rows[:, None, :], 0.0)
    slip = d - delta[:, None] * n
    size = np.linalg.norm(slip, axis=1)
    stick_f = (shear * a)[:, None] * slip
    cap = mu * a * np.maximum(delta, 0.0)
    slipping = shear * a * size > cap
    proj = np.eye(3) - n[:, :, None] * n[:, None, :]
    dslip = proj @ lever  # (K, 3, 6)
    jt = (shear * a)[:, None, None] * dslip
    if slipping.any():
        s = slipping
        unit = slip[s] / np.maximum(size[s], 1e-300)[:, None]
        stick_f[s] = cap[s, None] * unit
        perp = (np.eye(3) - unit[:, :, None] * unit[:, None, :]) / np.maximum(size[s], 1e-300)[
            :, None, None]
        jt[s] = (mu * a[s] * active[s])[:, None, None] * unit[:, :, None] * rows[s][:, None, :] \
            + cap[s, None, None] * (perp @ dslip[s])
    return f + stick_f, jac + jt, delta


def equilibrium_compression(vertices: np.ndarray, normals: np.ndarray, areas: np.ndarray,
                            gravity: np.ndarray, centre: np.ndarray, *, mu: float = 0.5,
                            shear_ratio: float = SHEAR_RATIO, max_iterations: int = 40,
                            tol: float = 1e-9) -> np.ndarray:
    """(V,) the normal compression max(0, delta) of each vertex when the body balances a unit
    load along `gravity` (unit (3,)) through `centre` (3,) on its envelope of springs (module
    docstring); zero on vertices facing up. vertices, normals (V, 3), areas (V,) m^2."""
    contact = np.flatnonzero(normals @ gravity >= 0)
    n, a, x = normals[contact], areas[contact], vertices[contact] - centre
    reach = np.linalg.norm(x, axis=1).max()
    x = x / reach  # theta in units of 1 / reach
    cross = _cross_matrices(x)
    wrench = np.concatenate([np.broadcast_to(np.eye(3), cross.shape), cross], axis=1)  # (K,6,3)
    z = np.zeros(6)
    z[:3] = gravity / np.sum(a * np.maximum(n @ gravity, 0.0) ** 2)  # the paper's sinking
    target = np.concatenate([gravity, np.zeros(3)])

    def residual(z):
        f, jac, delta = _forces(z, n, a, x, cross, mu, shear_ratio)
        return np.einsum("kij,kj->i", wrench, f) - target, jac, delta

    r, jac, delta = residual(z)
    for _ in range(max_iterations):
        if np.abs(r).max() < tol:
            break
        step = np.linalg.solve(np.einsum("kij,kjl->il", wrench, jac), -r)
        scale = 1.0
        while scale > 1e-4:  # backtrack on the residual's size
            trial = residual(z + scale * step)
            if np.linalg.norm(trial[0]) < np.linalg.norm(r):
                break
            scale /= 2
        z = z + scale * step
        r, jac, delta = trial
    out = np.zeros(len(vertices))
    out[contact] = np.maximum(delta, 0.0)
    return out
