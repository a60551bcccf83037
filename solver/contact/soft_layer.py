"""An independent physical reference for the pressure model: a rigid body in a soft layer,
solved by finite elements.

The body is rigid. It rests in an elastic layer (default 1 cm thick, Young's modulus 100 kPa,
Poisson's ratio 0.4: a firm foam) that fits the faces of the body pointing down or sideways, the
body's mould. The layer's outer face is fixed, its edges are free. A load (735 N) pushes the body
through its centre of mass along gravity. At the body/layer interface contact is unilateral (the
layer may let go of the body, never enter it) and friction is Coulomb with coefficient mu. The
unknowns are the layer's nodal displacements and the body's small rigid motion (translation and
rotation, 6 dof); the solution is the one of least total potential energy, which is force and
moment balance.

How it is solved, and what is assumed:

* Mesh. The body is decimated with libigl's edge collapse (default 4,000 triangles) so that a
  pose solves in seconds; the mould's triangles are extruded along the vertex normals into
  prisms through the layer's thickness (default two prisms thick), each split into three
  linear tetrahedra with a rule that makes neighbouring prisms conforming. A thin shell that
  follows a body is a boundary layer, not a volume a Delaunay mesher fills: its offset face
  runs into itself between the thighs and under the arms, where tetgen and gmsh need a closed,
  non-intersecting boundary. Where two parts of the layer overlap there (thigh against thigh)
  they do not interact.
* Elasticity. Small-strain isotropic linear elasticity, assembled with scikit-fem
  (`ElementVector(ElementTetP1())`, `linear_elasticity`). Linear elasticity with Coulomb
  friction is homogeneous, so normalised fields do not depend on the modulus or the load, only
  on Poisson's ratio, the thickness and mu.
* Friction. Coulomb friction in one load step from the stress-free fitted state, found as a
  fixed point of Tresca problems (friction bound g = mu times the normal force of the previous
  iterate, starting frictionless). Each Tresca problem is a convex second-order cone programme
  (energy + sum of g times the slip's length, non-penetration along each contact normal),
  solved by Clarabel's interior-point method. The iteration stops when the normal forces move
  by less than `tol` of their largest value, or after `max_iterations` (`converged` says
  which).
* Results. The nodal reaction K w at each interface node is the force the body puts on the
  layer; split along the node's normal it gives the normal and tangential parts. To report them
  on the full body, tractions (force over the node's share of mould area) are interpolated at
  each full-body mould vertex from the closest point on the decimated body (barycentric) and
  multiplied by the vertex's Voronoi area, so the total force is kept to the accuracy of the
  decimation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solver.contact._conic import rigid_rows, solve_conic, tangent_frames
from solver.contact.pressure import GRAVITY, mould_vertices
from solver.contact.rigid_mould import ContactForces
from solver.mesh import face_cross, triangle_mesh, volume_centroid


@dataclass(frozen=True, eq=False)
class SoftLayerSolution(ContactForces):
    """The equilibrium in the layer, on the full body (`ContactForces`: the mould vertices, the
    forces the body puts on the layer, its rigid motion, the `residual` on the decimated body
    before interpolation), with the fixed point's `iterations` and whether it `converged`, and
    the FE mesh's `nodes` and `tetrahedra`."""

    iterations: int = 0
    converged: bool = False
    nodes: int = 0
    tetrahedra: int = 0


@dataclass(frozen=True, eq=False)
class LayerMesh:
    """A layer extruded from a mould: `points` (N, 3) m, `tetrahedra` (M, 4), the `inner` (K,)
    nodes on the body (numbered first, 0..K-1, in the order of `base`, the surface vertices
    they came from), and the `outer` nodes, fixed."""

    points: np.ndarray
    tetrahedra: np.ndarray
    base: np.ndarray
    outer: np.ndarray


def layer_mesh(vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray,
               thickness: float, layers: int = 2) -> LayerMesh:
    """Tetrahedra of a layer of `thickness` (m) on the triangles (F, 3) of a surface, extruded
    along the unit vertex `normals` (V, 3) in `layers` prisms, each split into three tetrahedra
    (diagonals run from the lower-numbered corner of a side's base edge to the other corner's
    top, so that neighbouring prisms share their side faces' triangles)."""
    t = np.asarray(triangles, dtype=np.int64)
    base = np.unique(t)
    local = np.full(len(vertices), -1, dtype=np.int64)
    local[base] = np.arange(len(base))
    tri = np.sort(local[t], axis=1)  # a < b < c in the base numbering
    k = len(base)
    heights = np.linspace(0.0, thickness, layers + 1)
    points = (vertices[base][None] + heights[:, None, None] * normals[base][None]).reshape(-1, 3)
    tets = []
    for layer in range(layers):
        a, b, c = (tri[:, i] + layer * k for i in range(3))
        a1, b1, c1 = a + k, b + k, c + k
        tets += [np.stack([a, b, c, c1], 1), np.stack([a, b, b1, c1], 1),
                 np.stack([a, a1, b1, c1], 1)]
    tets = np.concatenate(tets)
    p = points[tets]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]  # positively oriented
    return LayerMesh(points, tets, base, np.arange(layers * k, (layers + 1) * k))


def _stiffness(mesh: LayerMesh, youngs: float, poisson: float) -> tuple[sp.csr_matrix, np.ndarray]:
    """The layer's stiffness (3N, 3N) in N/m with node-major dofs (3 i + axis), and (N,)
    the free nodes (not on the outer face)."""
    from skfem import Basis, ElementTetP1, ElementVector, MeshTet, asm
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    m = MeshTet(mesh.points.T.copy(), mesh.tetrahedra.T.copy())
    basis = Basis(m, ElementVector(ElementTetP1()))
    stiff = asm(linear_elasticity(*lame_parameters(youngs, poisson)), basis)
    order = basis.nodal_dofs.T.reshape(-1)  # dof of node i, axis j at 3 i + j
    stiff = stiff.tocsr()[order][:, order]
    free = np.setdiff1d(np.arange(len(mesh.points)), mesh.outer)
    return stiff, free


def soft_layer_contact(vertices: np.ndarray, triangles: np.ndarray, *, load: float = 735.0,
                       gravity=GRAVITY, centre: np.ndarray | None = None, mu: float = 0.5,
                       thickness: float = 0.01, youngs: float = 1e5, poisson: float = 0.4,
                       faces: int = 4000, layers: int = 2, tol: float = 1e-3,
                       max_iterations: int = 30) -> SoftLayerSolution:
    """Static equilibrium of the rigid body in its soft layer (see the module docstring).

    Parameters
    ----------
    vertices : (V, 3) float
        The posed body, metres; a closed, outward-oriented mesh.
    triangles : (F, 3) int
        Its triangles.
    load : float, default 735
        The load through the centre, N.
    gravity : (3,) float, default (0, -1, 0)
        Direction of the load.
    centre : (3,) float, optional
        Where the load acts (default: the centroid of the enclosed volume).
    mu : float, default 0.5
        Coulomb friction coefficient at the body/layer interface (0: frictionless).
    thickness, youngs, poisson : float
        The layer: thickness (m), Young's modulus (Pa), Poisson's ratio.
    faces : int, default 4000
        Triangles of the decimated body the layer is built on (0: the body as given).
    layers : int, default 2
        Prisms through the thickness.
    tol : float, default 1e-3
        The friction fixed point stops when no normal force moves by more than `tol` times the
        largest.
    max_iterations : int, default 30
        The most Tresca problems solved.

    Returns
    -------
    SoftLayerSolution
        Normal and tangential forces at the full body's mould vertices, the rigid motion, the
        equilibrium residual and the fixed point's iterations.

    Raises
    ------
    ValueError
        If a parameter is out of range.
    solver.contact._conic.ConicError
        If Clarabel does not solve a Tresca problem.
    """
    if not (load > 0 and mu >= 0 and thickness > 0 and youngs > 0 and -1 < poisson < 0.5
            and layers >= 1):
        raise ValueError("Expected load > 0, mu >= 0, thickness > 0, youngs > 0, "
                         f"-1 < poisson < 0.5 and layers >= 1, got load={load}, mu={mu}, "
                         f"thickness={thickness}, youngs={youngs}, poisson={poisson}, "
                         f"layers={layers}")
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    centre = volume_centroid(v, t) if centre is None else np.asarray(centre, dtype=np.float64)
    coarse_v, coarse_t = _decimated(v, t, faces)
    _, coarse_n = triangle_mesh(coarse_t, len(coarse_v)).measures(coarse_v)
    mould_t = coarse_t[face_cross(coarse_v, coarse_t) @ g >= 0]
    mesh = layer_mesh(coarse_v, mould_t, coarse_n, thickness, layers)
    stiff, free = _stiffness(mesh, youngs, poisson)
    normals = coarse_n[mesh.base]
    arms = coarse_v[mesh.base] - centre
    problem = _TrescaProblem(stiff, free, normals, arms, load * g)
    force, motion, iterations, converged = _coulomb(problem, normals, mu, tol, max_iterations)
    net = force.sum(axis=0) - load * g
    moment = np.cross(arms, force).sum(axis=0)
    residual = float(max(np.linalg.norm(net), np.linalg.norm(moment)))
    share = np.zeros(len(coarse_v))
    third = np.linalg.norm(face_cross(coarse_v, mould_t), axis=1) / 6.0  # a third of the area
    np.add.at(share, mould_t, third[:, None])
    traction = np.zeros((len(coarse_v), 3))
    traction[mesh.base] = force / share[mesh.base, None]
    normal_force, tangential_force, contact = _on_full_body(v, t, g, coarse_v, coarse_t,
                                                            coarse_n, traction)
    return SoftLayerSolution(contact, normal_force, tangential_force, motion[:3], motion[3:],
                             residual, iterations, converged, len(mesh.points),
                             len(mesh.tetrahedra))


def _coulomb(problem: "_TrescaProblem", normals: np.ndarray, mu: float, tol: float,
             max_iterations: int):
    """Coulomb friction as the fixed point of Tresca problems whose friction bounds are mu
    times the last normal forces: the forces (K, 3), the rigid motion (6,), the iterations and
    whether the normal forces changed by less than `tol` (relative) at the end."""
    normal = np.zeros(len(normals))
    for iterations in range(1, max_iterations + 1):
        force, motion = problem.solve(mu * np.maximum(normal, 0.0))
        new = np.einsum("ij,ij->i", force, normals)
        change = np.abs(new - normal).max() / max(np.abs(new).max(), 1e-300)
        normal = new
        if mu == 0 or change < tol:
            return force, motion, iterations, True
    return force, motion, max_iterations, False


class _TrescaProblem:
    """The layer's Tresca problems, set up once: min 1/2 w' K w - F . u + sum g_k |s_k| over the
    free nodal displacements w and the body's rigid motion (u, theta), with the body never
    entering the layer along the contact normals, s_k the tangential slip of body against layer.
    Displacements are scaled by the layer's mean compression and theta by the body's reach, so
    that Clarabel sees numbers near 1."""

    def __init__(self, stiff, free, normals, arms, weight):
        self.k = k = len(normals)
        self.load = float(np.linalg.norm(weight))
        self.reach = float(np.linalg.norm(arms, axis=1).max())
        dofs = (3 * free[:, None] + np.arange(3)).reshape(-1)
        self.stiff = stiff[dofs][:, dofs].tocsr()
        self.nw = len(dofs)
        diag = self.stiff.diagonal()[: 3 * k].reshape(k, 3).sum(axis=1)
        self.length = self.load / diag.sum()  # displacement scale, m
        scale = np.concatenate([np.full(3, self.length), np.full(3, self.length / self.reach)])
        self.scale = scale
        self.p = sp.block_diag([self.stiff * (self.length / self.load),
                                sp.csr_matrix((6, 6))], format="csc")
        self.c = np.concatenate([np.zeros(self.nw), -weight * scale[:3] / (self.load * self.length),
                                 np.zeros(3)])
        self.normals, self.arms = normals, arms
        self.t1, self.t2 = tangent_frames(normals)

    def _relative(self, directions, nodes):
        """Rows (len(nodes), nw + 6): e . (body displacement - layer displacement) / length."""
        m = len(nodes)
        rows = np.repeat(np.arange(m), 3)
        cols = (3 * nodes[:, None] + np.arange(3)).reshape(-1)
        layer = sp.csr_matrix((-directions.reshape(-1), (rows, cols)), shape=(m, self.nw))
        body = rigid_rows(directions, self.arms[nodes] / self.reach)
        return sp.hstack([layer, sp.csr_matrix(body)], format="csr")

    def solve(self, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3) forces of the body on the layer (N) and the rigid motion (6,) (m, rad) for
        friction bounds `bound` (K,) in N."""
        k = self.k
        everyone = np.arange(k)
        rubbing = np.flatnonzero(bound > 0)
        m = len(rubbing)
        gap = self._relative(self.normals, everyone)
        blocks = [sp.hstack([gap, sp.csr_matrix((k, m))])]
        if m:
            slip = sp.vstack([self._relative(self.t1[rubbing], rubbing),
                              self._relative(self.t2[rubbing], rubbing)]).tocsr()
            order = np.arange(2 * m).reshape(2, m).T.reshape(-1)  # (t1, t2) of each node
            slip = slip[order]
            axis = sp.csr_matrix((-np.ones(m), (3 * np.arange(m), np.arange(m))),
                                 shape=(3 * m, m))
            blocks.append(sp.hstack([_interleave(m, -slip), axis]))
        a = sp.vstack(blocks, format="csc")
        p = sp.block_diag([self.p, sp.csr_matrix((m, m))], format="csc")
        c = np.concatenate([self.c, bound[rubbing] / self.load])
        x, _ = solve_conic(p, c, a, np.zeros(a.shape[0]), 0, k, m)
        w = x[: self.nw] * self.length
        force = (self.stiff[: 3 * k] @ w).reshape(k, 3)
        return force, x[self.nw: self.nw + 6] * self.scale


def _interleave(m: int, slip: sp.csr_matrix) -> sp.csr_matrix:
    """(3m, n): rows 3i + 1 and 3i + 2 are the two rows of `slip` (2m, n) for node i, the rows
    3i (the cone's axis) empty."""
    coo = slip.tocoo()
    rows = 3 * (coo.row // 2) + 1 + coo.row % 2
    return sp.csr_matrix((coo.data, (rows, coo.col)), shape=(3 * m, slip.shape[1]))


def _decimated(v: np.ndarray, t: np.ndarray, faces: int) -> tuple[np.ndarray, np.ndarray]:
    """The body decimated to about `faces` triangles by libigl's edge collapse (0: as given)."""
    if not faces or faces >= len(t):
        return v, t
    import igl

    out = igl.decimate(v, t, int(faces))
    return np.asarray(out[0], dtype=np.float64), np.asarray(out[1], dtype=np.int64)


def _on_full_body(v, t, g, coarse_v, coarse_t, coarse_n, traction):
    """Normal and tangential forces (K, 3) at the full body's mould vertices (K,): the coarse
    body's nodal tractions (Vc, 3) in Pa, interpolated at each vertex's closest point on the
    coarse body, times the vertex's Voronoi area, split along its normal."""
    import igl

    contact = mould_vertices(v, t, g)
    areas, normals = triangle_mesh(t, len(v)).measures(v)
    _, face, point = igl.point_mesh_squared_distance(v[contact], coarse_v, coarse_t)
    corners = coarse_v[coarse_t[face]]
    bary = _barycentric(point, corners)
    pressure = np.einsum("ij,ijk,ijk->i", bary, traction[coarse_t[face]],
                         coarse_n[coarse_t[face]])
    tangential = np.einsum("ij,ijk->ik", bary, traction[coarse_t[face]]
                           - np.einsum("ijk,ijk->ij", traction[coarse_t[face]],
                                       coarse_n[coarse_t[face]])[..., None]
                           * coarse_n[coarse_t[face]])
    n = normals[contact]
    a = areas[contact]
    tangential -= np.einsum("ij,ij->i", tangential, n)[:, None] * n
    return (pressure * a)[:, None] * n, tangential * a[:, None], contact


def _barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(P, 3) barycentric coordinates of points (P, 3) in their triangles (P, 3, 3), clipped to
    the triangle."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e0, e1, d = b - a, c - a, points - a
    d00 = np.einsum("ij,ij->i", e0, e0)
    d01 = np.einsum("ij,ij->i", e0, e1)
    d11 = np.einsum("ij,ij->i", e1, e1)
    d20 = np.einsum("ij,ij->i", d, e0)
    d21 = np.einsum("ij,ij->i", d, e1)
    den = np.maximum(d00 * d11 - d01 * d01, 1e-300)
    l1 = (d11 * d20 - d01 * d21) / den
    l2 = (d00 * d21 - d01 * d20) / den
    bary = np.clip(np.stack([1 - l1 - l2, l1, l2], axis=1), 0.0, 1.0)
    return bary / bary.sum(axis=1, keepdims=True)
