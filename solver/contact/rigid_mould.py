"""The rigid-mould reference for the pressure model: the paper's section 4.3 set-up, in our own
code.

The body is a rigid body resting in a rigid mould made of its own faces that point down or
sideways. A load (735 N, a 75 kg person) pushes it through its centre of mass. Contact is a linear
penalty: a contact vertex k moved by d_k into the mould (overclosure g_k = d_k . n_k, n_k its
outward normal) feels the pressure k_n max(0, g_k) over its area A_k. Friction is Coulomb with
mu = 0.5 and elastic slip: the tangential traction grows with the tangential slip s_k at
stiffness mu p / slip_limit until it reaches mu p, then stays there. The body's small rigid
displacement d_k = u + theta x (x_k - c) is found so that the contact forces balance the load and
its moment; the reaction at each vertex is then split into its normal and tangential parts.

Defaults follow the paper's ABAQUS set-up: contact stiffness 8e12 Pa/m, mu = 0.5, elastic slip
1e-10 m, load 735 N.

This reference agrees with the model nearly by construction: a rigid body that sinks straight
into a mould of linear springs loads each face by k A (n . g) d, the model's A max(0, n . g);
only the small rotation that balances the moment and the friction differ. It is kept as the
paper's set-up; `solver.contact.soft_layer` (finite elements) and `solver.contact.programme`
(a conic programme) are the independent references.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import root

from solver.contact.pressure import GRAVITY, mould_vertices
from solver.mesh import triangle_mesh, volume_centroid


@dataclass(frozen=True, eq=False)
class ContactForces:
    """A reference's equilibrium: `vertices` (K,) indices of the contact (mould) vertices, their
    `normal_force` and `tangential_force` vectors (K, 3) in newtons (the force the body puts on
    the support), the body's rigid `translation` (3,) m and `rotation` (3,) rad, and the
    equilibrium `residual` (N and N m)."""

    vertices: np.ndarray
    normal_force: np.ndarray
    tangential_force: np.ndarray
    translation: np.ndarray
    rotation: np.ndarray
    residual: float

    @property
    def normal(self) -> np.ndarray:
        """(K,) magnitude of the normal force at each contact vertex, N."""
        return np.linalg.norm(self.normal_force, axis=1)

    @property
    def reaction(self) -> np.ndarray:
        """(K,) magnitude of the total reaction (normal + tangential) at each contact vertex."""
        return np.linalg.norm(self.normal_force + self.tangential_force, axis=1)


def rigid_mould_contact(vertices: np.ndarray, triangles: np.ndarray, *, load: float = 735.0,
                         gravity=GRAVITY, centre: np.ndarray | None = None,
                         stiffness: float = 8e12, mu: float = 0.5, slip_limit: float = 1e-10
                         ) -> ContactForces:
    """Static equilibrium of the rigid body in its mould (see the module docstring).

    vertices : (V, 3) metres; triangles : (F, 3); centre : where the load acts (default: the
    centroid of the enclosed volume).
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    areas, normals = triangle_mesh(t, len(v)).measures(v)
    if centre is None:
        centre = volume_centroid(v, t)
    contact = mould_vertices(v, t, g)
    x = v[contact] - centre
    n = normals[contact]
    a = areas[contact]
    weight = load * g
    # unknowns in units of the slip limit (displacements) so the solver sees numbers near 1
    length = slip_limit
    arm = np.linalg.norm(x, axis=1).max()

    def forces(z):
        u = z[:3] * length
        theta = z[3:] * length / arm
        d = u + np.cross(theta, x)
        gap = np.einsum("ij,ij->i", d, n)
        p = stiffness * np.maximum(gap, 0.0)
        fn = -(p * a)[:, None] * n
        slip = d - gap[:, None] * n
        s = np.linalg.norm(slip, axis=1)
        traction = mu * p / np.maximum(s, slip_limit)
        ft = -(traction * a)[:, None] * slip
        return fn, ft

    def residual(z):
        fn, ft = forces(z)
        f = fn + ft
        total = f.sum(axis=0) + weight
        moment = np.cross(x, f).sum(axis=0)
        return np.concatenate([total / load, moment / (load * arm)])

    # start from the pure translation that carries the load on normal forces alone
    down = -(n @ -g).clip(min=0)
    guess = np.zeros(6)
    guess[:3] = g * load / (stiffness * np.sum(a * down**2)) / length
    best = None
    for method in ("hybr", "lm"):
        sol = root(residual, guess, method=method, options={"xtol": 1e-12})
        err = float(np.abs(residual(sol.x)).max())
        if best is None or err < best[1]:
            best = (sol.x, err)
        if err < 1e-9:
            break
    z, err = best
    fn, ft = forces(z)  # (on the body: the support's reaction)
    return ContactForces(contact, -fn, -ft, z[:3] * length, z[3:] * length / arm,
                           err * load)
