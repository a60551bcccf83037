"""An independent reference for the pressure model: the contact forces of a rigid body on a
compliant support, found by a convex conic programme.

The body is rigid and rests on its mould (its faces pointing down or sideways), a load (735 N)
through its centre of mass. The body puts a force f_k = lambda_k n_k + t_k
on the support at each mould vertex k (n_k its outward unit normal, lambda_k >= 0, t_k
tangential). The support is a compliant layer of springs per
unit area, normal stiffness k_n and tangential stiffness k_t (by default in the ratio of a foam
layer's shear modulus to its oedometric modulus, G / E_oed = (1 - 2 nu) / (2 (1 - nu)) with
nu = 0.4). Among the forces that balance the load and its moment and lie in the exact Coulomb
cone |t_k| <= mu lambda_k, the programme picks the one of least complementary energy

    sum_k  lambda_k^2 / (2 k_n A_k) + |t_k|^2 / (2 k_t A_k)

(A_k the vertex's Voronoi area). By convex duality the six multipliers of the balance are the
body's rigid displacement and rotation, and inside the cone the forces are the springs' forces
under that motion: this is the elastic, compliant contact solved on the forces rather than on
the displacements. Where a point slips, the programme's friction law is the associated one (a
slipping point also lifts off by mu times its slip, the cone-complementarity relaxation of
Coulomb friction that makes the problem convex). Solved by Clarabel's interior-point method;
the rigid-mould reference (`solver.contact.reference`) is a penalty solved by root finding.
Normalised results do not depend on k_n, only on k_t / k_n and mu.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solver.contact._conic import solve_conic, tangent_frames
from solver.contact.pressure import GRAVITY, mould_vertices
from solver.contact.rigid_mould import ContactForces
from solver.mesh import triangle_mesh, volume_centroid

FOAM_POISSON = 0.4
SHEAR_RATIO = (1 - 2 * FOAM_POISSON) / (2 * (1 - FOAM_POISSON))  # G / E_oed


def contact_programme(vertices: np.ndarray, triangles: np.ndarray, *, load: float = 735.0,
                      gravity=GRAVITY, centre: np.ndarray | None = None, mu: float = 0.5,
                      stiffness: float = 2e7, shear_ratio: float = SHEAR_RATIO
                      ) -> ContactForces:
    """Contact forces of least complementary energy in the friction cone (module docstring).

    Parameters
    ----------
    vertices : (V, 3) float
        The posed body, metres; closed and outward-oriented.
    triangles : (F, 3) int
        Its triangles.
    load : float, default 735
        The load through the centre, N.
    gravity : (3,) float, default (0, -1, 0)
        Direction of the load.
    centre : (3,) float, optional
        Where the load acts (default: the centroid of the enclosed volume).
    mu : float, default 0.5
        Coulomb friction coefficient (0: frictionless).
    stiffness : float, default 2e7
        Normal stiffness k_n per unit area, Pa/m (a 1 cm layer of 100 kPa foam, nu = 0.4).
    shear_ratio : float
        k_t / k_n.

    Returns
    -------
    ContactForces

    Raises
    ------
    ValueError
        If a parameter is out of range.
    solver.contact._conic.ConicError
        If Clarabel does not solve the programme.
    """
    if not (load > 0 and mu >= 0 and stiffness > 0 and shear_ratio > 0):
        raise ValueError("Expected load > 0, mu >= 0, stiffness > 0 and shear_ratio > 0, got "
                         f"load={load}, mu={mu}, stiffness={stiffness}, "
                         f"shear_ratio={shear_ratio}")
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    centre = volume_centroid(v, t) if centre is None else np.asarray(centre, dtype=np.float64)
    contact = mould_vertices(v, t, g)
    areas, normals = triangle_mesh(t, len(v)).measures(v)
    n, a, x = normals[contact], areas[contact], v[contact] - centre
    t1, t2 = tangent_frames(n)
    k = len(contact)
    reach = float(np.linalg.norm(x, axis=1).max())
    # unknowns per vertex, in units of the load: (lambda, tau1, tau2), force on the support
    # lambda n + tau1 t1 + tau2 t2
    basis = np.stack([n, t1, t2], axis=1)  # (K, 3 unknowns, 3 axes)
    soft = 1.0 / (stiffness * a)
    # complementary energy / (load x the mean compression), scaled to numbers near 1
    length = load / (stiffness * a.sum())
    diag = np.stack([soft, soft / shear_ratio, soft / shear_ratio], axis=1).reshape(-1)
    p = sp.diags(diag * load / length)
    cols = np.arange(3 * k)
    equal = _balance_rows(x, basis, reach)
    b = np.concatenate([g, np.zeros(3), np.zeros(3 * k)])
    if mu > 0:  # (mu lambda, tau1, tau2) in the second-order cone
        rows = sp.vstack([equal, sp.diags(-np.tile([mu, 1.0, 1.0], k))])
        z, dual = solve_conic(p, np.zeros(3 * k), rows, b, 6, 0, k)
    else:  # frictionless: tau = 0, lambda >= 0
        eye = sp.eye(3 * k, format="csr")
        rows = sp.vstack([equal, eye[np.setdiff1d(cols, cols[0::3])], -eye[0::3]])
        z, dual = solve_conic(p, np.zeros(3 * k), rows, b, 6 + 2 * k, k, 0)
    f = np.einsum("ij,ijk->ik", z.reshape(k, 3), basis) * load
    normal_force = np.einsum("ij,ij->i", f, n)[:, None] * n
    residual = float(max(np.linalg.norm(f.sum(axis=0) - load * g),
                         np.linalg.norm(np.cross(x, f).sum(axis=0))))
    motion = -dual[:6] * length
    return ContactForces(contact, normal_force, f - normal_force, motion[:3],
                         motion[3:] / reach, residual)


def _balance_rows(x: np.ndarray, basis: np.ndarray, reach: float) -> sp.csr_matrix:
    """(6, 3K) the force rows and the moment rows (per `reach`) of the unknowns, each vertex's
    force `basis` (K, 3 unknowns, 3 axes) acting at `x` (K, 3) from the centre."""
    k = len(x)
    rows, cols = np.repeat(np.arange(3), 3 * k), np.tile(np.arange(3 * k), 3)
    force = sp.csr_matrix((basis.transpose(2, 0, 1).reshape(-1), (rows, cols)), shape=(3, 3 * k))
    torque = np.cross(x[:, None, :], basis) / reach  # (K, 3 unknowns, 3 axes)
    moment = sp.csr_matrix((torque.transpose(2, 0, 1).reshape(-1), (rows, cols)),
                           shape=(3, 3 * k))
    return sp.vstack([force, moment])
