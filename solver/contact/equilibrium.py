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


def _lever_gram(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(6, 6) sum_k a_k L_k' L_k with L_k = [I, -[x_k]_x] (the rigid motion's displacement at
    x_k), from the sums of a, a x and a x x' alone."""
    sa, sx, sxx = a.sum(), a @ x, (a[:, None] * x).T @ x
    cx = _cross_matrices(sx[None])[0]
    out = np.empty((6, 6))
    out[:3, :3] = sa * np.eye(3)
    out[:3, 3:] = -cx
    out[3:, :3] = cx
    out[3:, 3:] = np.trace(sxx) * np.eye(3) - sxx  # -sum a [x]_x [x]_x
    return out


def _balance(z, n, a, x, w, mu, shear):
    """Net wrench (6,) of the spring forces on the support under the motion z = (u, theta),
    its Jacobian (6, 6), and the normal compressions (K,). w (K, 6) are the wrenches [n, x X n]
    of the unit normals, also the derivatives of the compressions."""
    d = z[:3] + np.cross(z[3:], x)
    delta = w @ z
    active = delta > 0
    slip = d - delta[:, None] * n
    size = np.sqrt(np.einsum("ij,ij->i", slip, slip))
    cap = mu * np.maximum(delta, 0.0)
    slipping = active & (shear * size > cap)
    stick = active & ~slipping
    f = np.where(stick[:, None], delta[:, None] * n + shear * slip, 0.0)
    aw = a[:, None] * w
    jac = aw[active].T @ w[active]
    jac += shear * (_lever_gram(a[stick], x[stick]) - aw[stick].T @ w[stick])
    if slipping.any():  # tau = cap u, u the unit slip: d tau = mu u dw' + cap/|s| (I - uu') P L
        s = slipping
        unit = slip[s] / size[s, None]
        f[s] = delta[s, None] * n[s] + cap[s, None] * unit
        wu = np.concatenate([unit, np.cross(x[s], unit)], axis=1)  # L' u
        c = a[s] * cap[s] / size[s]
        jac += (mu * a[s, None] * wu).T @ w[s]
        jac += _lever_gram(c, x[s]) - (c[:, None] * w[s]).T @ w[s] - (c[:, None] * wu).T @ wu
    fa = a[:, None] * f
    net = np.concatenate([fa.sum(axis=0), np.cross(x, fa).sum(axis=0)])
    return net, jac, delta


UNBALANCED = 1e-6  # of the unit load: a balance left over past this is no balance (the Newton
# steps stop at `tol`, 1e-8, when they converge)


def equilibrium_compression(vertices: np.ndarray, normals: np.ndarray, areas: np.ndarray,
                            gravity: np.ndarray, centre: np.ndarray, *, mu: float = 0.5,
                            shear_ratio: float = SHEAR_RATIO, max_iterations: int = 40,
                            tol: float = 1e-8) -> np.ndarray:
    """(V,) the normal compression max(0, delta) of each vertex when the body balances a unit
    load along `gravity` (unit (3,)) through `centre` (3,) on its envelope of springs (module
    docstring); zero on vertices facing up. vertices, normals (V, 3), areas (V,) m^2."""
    contact = np.flatnonzero(normals @ gravity >= 0)
    n, a, x = normals[contact], areas[contact], vertices[contact] - centre
    reach = np.linalg.norm(x, axis=1).max()
    x = x / reach  # theta in units of 1 / reach
    w = np.concatenate([n, np.cross(x, n)], axis=1)
    z = np.zeros(6)
    z[:3] = gravity / np.sum(a * np.maximum(n @ gravity, 0.0) ** 2)  # the paper's sinking
    target = np.concatenate([gravity, np.zeros(3)])

    def residual(z):
        net, jac, delta = _balance(z, n, a, x, w, mu, shear_ratio)
        return net - target, jac, delta

    r, jac, delta = residual(z)
    for _ in range(max_iterations):
        if np.abs(r).max() < tol:
            break
        step = np.linalg.solve(jac, -r)
        scale = 1.0
        while scale > 1e-4:  # backtrack on the residual's size
            trial = residual(z + scale * step)
            if np.linalg.norm(trial[0]) < np.linalg.norm(r):
                break
            scale /= 2
        z = z + scale * step
        r, jac, delta = trial
    if not np.abs(r).max() < UNBALANCED:
        raise ValueError(f"The body finds no balance on its envelope of springs within "
                         f"{max_iterations} Newton steps (the net force and moment left are "
                         f"{np.abs(r).max():.3g} of the load): its compression would not "
                         f"carry it")
    out = np.zeros(len(vertices))
    out[contact] = np.maximum(delta, 0.0)
    return out
