"""A rigid body pressed into a foam block: the evaluation's Winkler law checked against finite
elements on the same set-up.

The evaluation (`solver.contact.settle`, `solver.contact.evaluate.flat_at_same_load`) models a
seat's foam as independent springs: pressure = stiffness x depth (Winkler), `bottom_factor` times
stiffer past the foam's thickness. Here the same foam is an elastic solid, and the same rigid body
is pressed into it along a fixed direction (no turn, no slide: the body is held as
`flat_at_same_load` holds it) until the foam carries a given load:

* the foam block, a flat slab (`slab_mesh`: x across, y up, z forward; its top face y = 0, its
  base y = -thickness fixed, its sides free) or a layer under a surface (`surface_layer_mesh`:
  the surface's triangles extruded along their inward normals through the thickness, the
  layer's far face fixed). Small-strain isotropic linear elasticity on linear tetrahedra,
  assembled by the soft layer's element code (`solver.contact.soft_layer._stiffness`, checked
  there against a mesh from tetgen);
* the contact, unilateral with an initial gap: each node of the foam's loaded face (the
  candidates) has a gap g along its outward normal m to the body's underside (`underside_gaps`:
  the first crossing of the body's skin by the ray from the node along m). The body moves by
  delta along the pressing direction d; linearised, the node may not pass the body:
  (w - delta d) . m <= g (w the node's displacement). The gap is the one of the undeformed
  node, so a node's sideways slide under a curved body is not followed (small strain, small
  slide). The body is rigid: its facets (about 2.3 cm on the default body) are corners the
  elastic foam feels, so its skin is Loop-subdivided first (`smooth_skin`); without that the
  one-node peak on a flat seat grows as the foam's mesh is refined (14.4 kPa at 1.5 cm, 18.6
  at 1 cm), with it it converges (13.0 and 12.9 kPa);
* friction, Coulomb with coefficient mu on the slip of node against body in the face's tangent
  plane, found, as in the soft layer, as the fixed point of Tresca problems, each a convex
  second-order cone programme solved by Clarabel (`solver.contact._conic`); mu = 0 is one
  quadratic programme;
* the load: the body's descent delta is an unknown whose work is load x delta, so the solution,
  of least total potential energy, is the one where the contact forces balance the load along d.

The Winkler law on the same set-up (`winkler_indentation`) loads each candidate node by
stiffness x max(0, delta (-d . m) - g) over its tributary area, delta chosen so that the nodes
carry the load: the evaluation's law on the finite elements' nodes, so the two fields are
compared node by node with the same quadrature (`pressure_figures`, `field_comparison`).

The modulus: a Winkler foam of stiffness k (Pa/m) and thickness h matches a layer of Young's
modulus E = k h under uniaxial stress (free to bulge sideways), the way a foam's compression
test is read; under a wide load the layer is closer to uniaxial strain, stiffer by
E_oed / E = (1 - nu) / ((1 + nu)(1 - 2 nu)) (1.35 at nu = 0.3, 3.79 at 0.45), and its shear
spreads a load to neighbours, both of which the springs lack. The stiffness itself was read off
an indentation test (ASTM D3574's IFD), whose disc presses a layer that is so restrained:
`ifd_modulus` finds the E that reproduces that test (11.7 kPa at nu = 0.3, 8.3 at 0.45, for
200 kPa/m and 10 cm), the other reading of "the same foam". A layer thicker than a surface's
radius of curvature folds over itself (`folded_triangles`): the product's "foam of a given
thickness behind the surface" does not exist there as a solid.

Units: metres, newtons, pascals (figures in kPa where named so).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solver.contact._conic import solve_conic, tangent_frames
from solver.contact.soft_layer import LayerMesh, _interleave, _stiffness, layer_mesh

LOADED_SHARE = 0.05  # a node is loaded where the reference carries over 5 % of its peak pressure


@dataclass(frozen=True, eq=False)
class FoamBlock:
    """A foam block's mesh (`LayerMesh`: the candidate contact nodes numbered first, its fixed
    nodes `outer`) with, for the K candidate nodes, their outward unit `normals` (K, 3) and
    tributary `areas` (K,) m^2 on the loaded face."""

    mesh: LayerMesh
    normals: np.ndarray
    areas: np.ndarray

    @property
    def top(self) -> np.ndarray:
        """(K, 3) the candidate nodes' positions, m."""
        return self.mesh.points[: len(self.areas)]


@dataclass(frozen=True, eq=False)
class Indentation:
    """A body pressed into a foam block, on the block's K candidate nodes: the normal force
    (K,) N the body puts on the foam, its `tangential` part (K, 3) N, the pressure (K,) Pa
    (normal force over tributary area), the body's `descent` (m, along the pressing direction),
    the `residual` of the load balance (N), and for the finite elements the fixed point's
    `iterations` and whether it `converged` (the Winkler law: 0 and True)."""

    normal: np.ndarray
    tangential: np.ndarray
    pressure: np.ndarray
    descent: float
    residual: float
    iterations: int = 0
    converged: bool = True


def _tributary(coords: np.ndarray) -> np.ndarray:
    """(n,) lengths each of n sorted 1-D grid coordinates stands for (half of each
    neighbouring interval)."""
    d = np.diff(coords)
    out = np.zeros(len(coords))
    out[:-1] += d / 2
    out[1:] += d / 2
    return out


def slab_mesh(xs: np.ndarray, zs: np.ndarray, depths: np.ndarray) -> FoamBlock:
    """A flat foam slab on a tensor grid: top face y = 0 over the grid xs (nx,) by zs (nz,)
    (m), planes at y = -depths (ny,) (from 0 down to the thickness, increasing), each hexahedron
    split into six tetrahedra around its diagonal (Kuhn's split, conforming between
    neighbours). The candidate nodes are the top face's (numbered first, x fastest), the base
    y = -depths[-1] is fixed, the sides are free.

    Raises ValueError when a coordinate array has fewer than two values or is not strictly
    increasing, or the depths do not start at 0."""
    xs, zs, depths = (np.asarray(a, dtype=np.float64) for a in (xs, zs, depths))
    for name, a in (("xs", xs), ("zs", zs), ("depths", depths)):
        if a.ndim != 1 or len(a) < 2 or np.any(np.diff(a) <= 0):
            raise ValueError(f"Expected {name} strictly increasing with at least 2 values, "
                             f"got {a}")
    if depths[0] != 0:
        raise ValueError(f"Expected depths to start at 0 (the top face), got {depths[0]}")
    nx, nz, ny = len(xs), len(zs), len(depths)
    gx, gz = np.meshgrid(xs, zs)  # (nz, nx): x fastest
    plane = np.column_stack([gx.ravel(), np.zeros(nx * nz), gz.ravel()])
    points = np.concatenate([plane - [0.0, d, 0.0] for d in depths])

    def node(i, k, j):  # x index, z index, depth index
        return j * nx * nz + k * nx + i

    i, k, j = np.meshgrid(np.arange(nx - 1), np.arange(nz - 1), np.arange(ny - 1),
                          indexing="ij")
    i, k, j = i.ravel(), k.ravel(), j.ravel()
    corner = {(a, b, c): node(i + a, k + b, j + c) for a in (0, 1) for b in (0, 1)
              for c in (0, 1)}
    tets = []
    for order in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        step = [0, 0, 0]
        path = [corner[tuple(step)]]
        for axis in order:
            step[axis] = 1
            path.append(corner[tuple(step)])
        tets.append(np.stack(path, axis=1))
    tets = np.concatenate(tets)
    p = points[tets]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]
    k_top = nx * nz
    mesh = LayerMesh(points, tets, np.arange(k_top), np.arange((ny - 1) * k_top, ny * k_top))
    areas = np.outer(_tributary(zs), _tributary(xs)).ravel()
    return FoamBlock(mesh, np.tile([0.0, 1.0, 0.0], (k_top, 1)), areas)


def graded(start: float, stop: float, fine: float, coarse: float, window: tuple[float, float]
           ) -> np.ndarray:
    """Grid coordinates from `start` to `stop` (m): spacing about `fine` inside `window` (lo,
    hi) and about `coarse` outside it."""
    lo, hi = max(window[0], start), min(window[1], stop)
    parts = []
    if lo > start:
        parts.append(np.linspace(start, lo, max(int(np.ceil((lo - start) / coarse)), 1) + 1))
    parts.append(np.linspace(lo, hi, max(int(np.ceil((hi - lo) / fine)), 1) + 1))
    if stop > hi:
        parts.append(np.linspace(hi, stop, max(int(np.ceil((stop - hi) / coarse)), 1) + 1))
    return np.unique(np.concatenate(parts))


def surface_layer_mesh(vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray,
                       thickness: float, layers: int = 4, extrusion: np.ndarray | None = None
                       ) -> FoamBlock:
    """A foam layer of `thickness` (m) under a surface: its triangles (F, 3) extruded from the
    vertices (V, 3) against their unit outward `normals` (V, 3) (towards the body), or along
    `extrusion` (V, 3) or (3,) when given, the far face at vertex + thickness x extrusion
    (straight down to a flat base: (0, -(y - base) / thickness, 0)), in `layers`
    prisms (`soft_layer.layer_mesh`); the candidate nodes are the surface's vertices used by
    the triangles, the far face is fixed. Tributary areas are a third of each triangle's area
    per corner. A layer thicker than the surface's radius of curvature folds over itself
    (`folded_triangles` finds where)."""
    t = np.asarray(triangles, dtype=np.int64)
    n = np.asarray(normals, dtype=np.float64)
    along = -n if extrusion is None else np.broadcast_to(
        np.asarray(extrusion, dtype=np.float64), n.shape)
    mesh = layer_mesh(vertices, t, along, thickness, layers)
    area = np.linalg.norm(np.cross(vertices[t[:, 1]] - vertices[t[:, 0]],
                                   vertices[t[:, 2]] - vertices[t[:, 0]]), axis=1) / 6.0
    share = np.zeros(len(vertices))
    np.add.at(share, t, area[:, None])
    return FoamBlock(mesh, np.asarray(normals, dtype=np.float64)[mesh.base], share[mesh.base])


def folded_triangles(block: FoamBlock, triangles: np.ndarray) -> np.ndarray:
    """(F,) bool: the surface triangles (F, 3) (numbered as the surface's vertices the block
    was extruded from) whose image on the block's fixed far face is turned over against them:
    where the layer folds over itself, its elements are tangled."""
    local = np.full(int(block.mesh.base.max()) + 1, -1)
    local[block.mesh.base] = np.arange(len(block.mesh.base))
    t = local[np.asarray(triangles, dtype=np.int64)]
    near, far = block.top, block.mesh.points[block.mesh.outer]

    def cross(p):
        return np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])

    return np.einsum("ij,ij->i", cross(near), cross(far)) <= 0


def underside_gaps(points: np.ndarray, directions: np.ndarray, vertices: np.ndarray,
                   triangles: np.ndarray) -> np.ndarray:
    """(K,) m: how far each ray from points (K, 3) along unit directions (K, 3) runs before it
    first crosses one of the body's triangles (F, 3) of vertices (V, 3) (inf where it crosses
    none, or only behind its start): libigl's ray casting, a ray at a time."""
    import igl

    p = np.ascontiguousarray(points, dtype=np.float64)
    d = np.ascontiguousarray(directions, dtype=np.float64)
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    t = np.ascontiguousarray(triangles, dtype=np.int64)
    out = np.full(len(p), np.inf)
    for k in range(len(p)):
        # every hit, sorted (with `first`, libigl's binding reports a hit that is none for a
        # ray that misses)
        ahead = [hit[1] for hit in igl.ray_mesh_intersect(p[k], d[k], v, t, False) or ()
                 if hit[1] >= -1e-9]
        if ahead:
            out[k] = min(ahead)
    return out


def winkler_indentation(gaps: np.ndarray, areas: np.ndarray, cosines: np.ndarray, load: float,
                        stiffness: float, thickness: float, bottom_factor: float = 20.0
                        ) -> Indentation:
    """The evaluation's Winkler law on the same set-up: candidate nodes with gaps (K,) m,
    tributary areas (K,) m^2 and cosines (K,) between the pressing direction and each node's
    inward normal (1 on a flat seat pressed straight down); the body descends by delta until
    sum of areas x pressure = load (N), pressure = stiffness (Pa/m) x depth,
    `bottom_factor` times stiffer past `thickness` (m), depth = max(0, delta cos - gap). The
    normal forces' balance of the load is along the normals (exact on a flat seat)."""
    from scipy.optimize import brentq

    g, a, cs = (np.asarray(x, dtype=np.float64) for x in (gaps, areas, cosines))
    reach = np.isfinite(g) & (cs > 0)
    extra = (bottom_factor - 1.0) * stiffness

    def pressure(delta: float) -> np.ndarray:
        depth = np.where(reach, np.maximum(delta * np.where(reach, cs, 0.0)
                                           - np.where(reach, g, 0.0), 0.0), 0.0)
        return stiffness * depth + extra * np.maximum(depth - thickness, 0.0)

    def short(delta: float) -> float:
        return load - float(a * cs @ pressure(delta))

    low = float(np.min(g[reach] / cs[reach]))
    high = low + 0.01
    while short(high) > 0:
        high += high - low
    delta = brentq(short, low, high, xtol=1e-12)
    p = pressure(delta)
    return Indentation(p * a, np.zeros((len(a), 3)), p, delta, abs(short(delta)))


def fe_indentation(block: FoamBlock, gaps: np.ndarray, direction: np.ndarray, load: float, *,
                   youngs: float, poisson: float, mu: float = 0.0, tol: float = 1e-3,
                   max_iterations: int = 30) -> Indentation:
    """A rigid body pressed by `load` (N) along the unit `direction` (3,) into the foam block
    (see the module docstring), by finite elements: Young's modulus `youngs` (Pa), Poisson's
    ratio `poisson`, Coulomb friction `mu` between body and foam (0: frictionless, one
    programme); gaps (K,) m from each candidate node along its normal to the body (inf: the
    body is not above it).

    Returns the `Indentation` on the block's candidate nodes. Raises ValueError on an
    out-of-range parameter, `solver.contact._conic.ConicError` when Clarabel fails."""
    if not (load > 0 and youngs > 0 and -1 < poisson < 0.5 and mu >= 0):
        raise ValueError("Expected load > 0, youngs > 0, -1 < poisson < 0.5 and mu >= 0, got "
                         f"load={load}, youngs={youngs}, poisson={poisson}, mu={mu}")
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    gaps = np.asarray(gaps, dtype=np.float64)
    if gaps.shape != block.areas.shape:
        raise ValueError(f"Expected gaps of shape {block.areas.shape}, got {gaps.shape}")
    stiff, free = _stiffness(block.mesh, youngs, poisson)
    problem = _PressProblem(stiff, free, block.normals, gaps, d, load)
    normal = np.zeros(len(gaps))
    converged = False
    for iterations in range(1, max_iterations + 1):
        force, descent = problem.solve(mu * np.maximum(normal, 0.0))
        new = -np.einsum("ij,ij->i", force, block.normals)  # the body pushes against m
        change = np.abs(new - normal).max() / max(np.abs(new).max(), 1e-300)
        normal = new
        if mu == 0 or change < tol:
            converged = True
            break
    tangential = force + normal[:, None] * block.normals
    residual = float(np.linalg.norm(force.sum(axis=0) @ d - load))
    return Indentation(normal, tangential, normal / block.areas, descent, residual, iterations,
                       converged)


class _PressProblem:
    """The block's Tresca problems, set up once: min 1/2 w' K w - load delta + sum g_k |s_k|
    over the free nodal displacements w and the body's descent delta, subject to
    (w_k - delta d) . m_k <= gap_k at the candidate nodes that have a body above them, s_k the
    slip (w_k - delta d) in the tangent plane of m_k. Scaled so that Clarabel sees numbers near
    1 (displacements by the load over the candidate nodes' stiffness)."""

    def __init__(self, stiff, free, normals, gaps, direction, load):
        self.k = k = len(normals)
        assert np.array_equal(free[:k], np.arange(k)), "the candidate nodes must be free"
        dofs = (3 * free[:, None] + np.arange(3)).reshape(-1)
        self.stiff = stiff[dofs][:, dofs].tocsr()
        self.nw = len(dofs)
        self.load = load
        diag = self.stiff.diagonal()[: 3 * k].reshape(k, 3).sum(axis=1)
        self.length = load / np.sort(diag)[-max(k // 4, 1):].sum()
        self.p = sp.block_diag([self.stiff * (self.length / load), sp.csr_matrix((1, 1))],
                               format="csc")
        self.c = np.concatenate([np.zeros(self.nw), [-1.0]])
        self.normals, self.direction = normals, direction
        self.reach = np.flatnonzero(np.isfinite(gaps))
        self.gaps = gaps
        self.t1, self.t2 = tangent_frames(normals)

    def _relative(self, directions, nodes):
        """Rows (len(nodes), nw + 1): e . (w_node - delta d) / length."""
        m = len(nodes)
        rows = np.repeat(np.arange(m), 3)
        cols = (3 * nodes[:, None] + np.arange(3)).reshape(-1)
        layer = sp.csr_matrix((directions.reshape(-1), (rows, cols)), shape=(m, self.nw))
        body = sp.csr_matrix(-(directions @ self.direction)[:, None])
        return sp.hstack([layer, body], format="csr")

    def solve(self, bound: np.ndarray) -> tuple[np.ndarray, float]:
        """(K, 3) forces of the body on the foam (N, the nodal reactions K w) and the body's
        descent (m) for friction bounds `bound` (K,) in N."""
        k, reach = self.k, self.reach
        rubbing = np.intersect1d(np.flatnonzero(bound > 0), reach)
        m = len(rubbing)
        gap = self._relative(self.normals[reach], reach)
        blocks = [sp.hstack([gap, sp.csr_matrix((len(reach), m))])]
        rhs = [self.gaps[reach] / self.length]
        if m:
            slip = sp.vstack([self._relative(self.t1[rubbing], rubbing),
                              self._relative(self.t2[rubbing], rubbing)]).tocsr()
            slip = slip[np.arange(2 * m).reshape(2, m).T.reshape(-1)]  # (t1, t2) of each node
            axis = sp.csr_matrix((-np.ones(m), (3 * np.arange(m), np.arange(m))),
                                 shape=(3 * m, m))
            blocks.append(sp.hstack([_interleave(m, -slip), axis]))
            rhs.append(np.zeros(3 * m))
        a = sp.vstack(blocks, format="csc")
        p = sp.block_diag([self.p, sp.csr_matrix((m, m))], format="csc")
        c = np.concatenate([self.c, bound[rubbing] / self.load])
        x, _ = solve_conic(p, c, a, np.concatenate(rhs), 0, len(reach), m)
        w = x[: self.nw] * self.length
        force = (self.stiff[: 3 * k] @ w).reshape(k, 3)
        return force, float(x[self.nw] * self.length)


def pressure_figures(points: np.ndarray, areas: np.ndarray, pressure: np.ndarray,
                     floor: float = 0.0) -> dict:
    """A pressure mat's figures of nodes at points (K, 3) m, tributary areas (K,) m^2 carrying
    pressure (K,) Pa: ``peak_kpa`` (one node's), ``peak_10cm2_kpa`` (the largest mean pressure
    over the nodes within a disc of 10 cm^2 round a node, area weighted: less sensitive to the
    node spacing than one node's, near a pressure singularity), ``mean_kpa`` (load over contact
    area), ``contact_area_m2`` (the nodes above `floor` Pa), ``load_n`` and
    ``centre_of_pressure_m`` ((3,) list)."""
    from scipy.spatial import cKDTree

    on = pressure > floor
    force = np.where(on, pressure, 0.0) * areas
    load = float(force.sum())
    area = float(areas[on].sum())
    loaded = np.flatnonzero(on)
    tree = cKDTree(points)
    near = tree.query_ball_point(points[loaded], np.sqrt(10e-4 / np.pi))
    index = max((float(force[n].sum() / areas[n].sum()) for n in near), default=0.0)
    return {"peak_kpa": float(pressure.max()) / 1e3, "peak_10cm2_kpa": index / 1e3,
            "mean_kpa": load / area / 1e3,
            "contact_area_m2": area, "load_n": load,
            "centre_of_pressure_m": [float(v) for v in force @ points / load]}


def field_comparison(reference: np.ndarray, model: np.ndarray, areas: np.ndarray) -> dict:
    """How far a model's pressure (K,) is from a reference's (K,) (Pa, on the same nodes of
    tributary areas (K,)): RMSE of the fields each normalised by its own peak, over the loaded
    nodes (reference above `LOADED_SHARE` of its peak) and over the nodes either loads, area
    weighted (``rmse_loaded``, ``rmse_contact``), the same for the trivial baselines (``zero_*``:
    no pressure; ``uniform_*``: the reference's load spread evenly over its loaded nodes,
    normalised: 1 there), RMSE in kPa over the loaded nodes (``rmse_loaded_kpa``, and
    ``uniform_loaded_kpa`` for the even spread), and the peak ratio model / reference."""
    r = np.asarray(reference, dtype=np.float64)
    m = np.asarray(model, dtype=np.float64)
    loaded = r > LOADED_SHARE * r.max()
    either = loaded | (m > LOADED_SHARE * m.max())
    rn, mn = r / r.max(), m / m.max()
    uniform = loaded.astype(float)
    even = float(r[loaded] @ areas[loaded] / areas[loaded].sum())

    def rmse(a, b, where):
        w = areas[where]
        return float(np.sqrt(w @ (a[where] - b[where]) ** 2 / w.sum()))

    return {"rmse_loaded": rmse(rn, mn, loaded), "zero_loaded": rmse(rn, 0 * rn, loaded),
            "uniform_loaded": rmse(rn, uniform, loaded),
            "rmse_contact": rmse(rn, mn, either), "zero_contact": rmse(rn, 0 * rn, either),
            "uniform_contact": rmse(rn, uniform, either),
            "rmse_loaded_kpa": rmse(r, m, loaded) / 1e3,
            "uniform_loaded_kpa": rmse(r, np.full_like(r, even), loaded) / 1e3,
            "peak_ratio": float(m.max() / r.max())}


def pressing_skin(normals: np.ndarray, areas: np.ndarray, triangles: np.ndarray,
                  rotation: np.ndarray, supported: np.ndarray | None = None) -> np.ndarray:
    """(G, 3) the triangles of the skin that presses a flat seat as `flat_at_same_load` sees it:
    all three corners supported (all when `supported` (V,) is None), with an area, and facing
    down once the body's unit normals (V, 3) are turned by its settle's `rotation` (3,)
    (rotation vector, rad)."""
    from scipy.spatial.transform import Rotation

    turned = normals @ Rotation.from_rotvec(rotation).as_matrix().T
    pressing = (areas * np.maximum(-turned[:, 1], 0.0)) > 0
    if supported is not None:
        pressing &= supported
    return triangles[pressing[triangles].all(axis=1)]


def smooth_skin(vertices: np.ndarray, triangles: np.ndarray, levels: int = 2
                ) -> tuple[np.ndarray, np.ndarray]:
    """The patch of skin triangles (G, 3) of vertices (V, 3), Loop-subdivided `levels` times
    (trimesh): its vertices (V', 3) and (4^levels G, 3) triangles. A rigid body's facets
    (about 2.3 cm on the default body) are corners an elastic foam feels (pressure peaks at
    their edges that grow as the foam's mesh is refined); the subdivided skin is smooth to
    within its smaller facets, as skin is. The Winkler law hardly notices."""
    import trimesh

    t = np.asarray(triangles, dtype=np.int64)
    if levels <= 0:
        return np.asarray(vertices, dtype=np.float64), t
    used = np.unique(t)
    local = np.full(len(vertices), -1, dtype=np.int64)
    local[used] = np.arange(len(used))
    v, f = trimesh.remesh.subdivide_loop(np.asarray(vertices, dtype=np.float64)[used],
                                         local[t], iterations=levels)
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def flat_slab_indentation(vertices: np.ndarray, triangles: np.ndarray, load: float, *,
                          stiffness: float = 200e3, thickness: float = 0.1,
                          bottom_factor: float = 20.0, poisson: float = 0.3, mu: float = 0.0,
                          spacing: float = 0.015, size: float = 0.6,
                          depths: np.ndarray | None = None, subdivisions: int = 2,
                          youngs: float | None = None) -> dict:
    """A rigid body pressed straight down (y is up), held without turning or sliding, into a
    flat foam slab until the slab carries `load`: by finite elements (Young's modulus
    stiffness x thickness, the Winkler stiffness read as uniaxial stress) and by the
    evaluation's Winkler law on the slab's nodes (`flat_at_same_load`'s law).

    Parameters
    ----------
    vertices : (V, 3) float
        The body as held, metres.
    triangles : (G, 3) int
        The skin that presses the seat (`pressing_skin`).
    load : float
        N the slab carries.
    stiffness, thickness, bottom_factor : float
        The foam: Pa per metre, m, and how much stiffer the Winkler law is past the thickness.
    poisson, mu : float
        The finite elements' Poisson's ratio and the Coulomb friction between body and foam.
    spacing : float, default 0.015
        Node spacing (m) over the skin's footprint (3 cm beyond it).
    size : float, default 0.6
        The slab's side, m, centred under the footprint of the skin below the Winkler seat.
    depths : (ny,) float, optional
        Node planes below the top, 0 to `thickness` (default: 1, 2, 3.5, 5, 7 cm, then the base,
        in tenths of the thickness).
    subdivisions : int, default 2
        Loop subdivisions of the pressing skin before its gaps are measured (`smooth_skin`).
    youngs : float, optional
        The finite elements' Young's modulus, Pa (default stiffness x thickness).

    Returns
    -------
    dict
        ``block`` (`FoamBlock`, its top face at the body's lowest pressing point, shifted back
        to the scene's height in ``top_y``), ``gaps`` (K,) m, ``fe`` and ``winkler``
        (`Indentation`), ``fe_figures`` and ``winkler_figures`` (`pressure_figures`, points at
        the scene's height), ``comparison`` (`field_comparison` of Winkler against the finite
        elements), and the finite elements' run time ``fe_seconds``.
    """
    import time

    if not len(triangles) or load <= 0:
        raise ValueError(f"Expected pressing triangles and load > 0, got {len(triangles)} "
                         f"triangles and load={load}")
    v, t = smooth_skin(vertices, triangles, subdivisions)
    skin = np.unique(t)
    low = float(v[skin, 1].min())
    # the skin's footprint where the Winkler seat would load it (vertex shares of the
    # triangles' areas projected on the seat)
    cross = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])[:, 1]
    share = np.zeros(len(v))
    np.add.at(share, t, np.abs(cross)[:, None] / 6.0)
    guess = winkler_indentation(v[skin, 1] - low, share[skin], np.ones(len(skin)), load,
                                stiffness, thickness, bottom_factor)
    on = skin[v[skin, 1] - low < guess.descent]
    lo, hi = v[on].min(axis=0), v[on].max(axis=0)
    cx, cz = (lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2
    margin = 0.04
    xs = graded(cx - size / 2, cx + size / 2, spacing, 0.03, (lo[0] - margin, hi[0] + margin))
    zs = graded(cz - size / 2, cz + size / 2, spacing, 0.03, (lo[2] - margin, hi[2] + margin))
    if depths is None:
        depths = thickness * np.array([0.0, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0])
    block = slab_mesh(xs, zs, depths)
    gaps = underside_gaps(block.top, block.normals, v - [0.0, low, 0.0], t)
    start = time.perf_counter()
    modulus = stiffness * thickness if youngs is None else youngs
    fe = fe_indentation(block, gaps, [0.0, -1.0, 0.0], load, youngs=modulus,
                        poisson=poisson, mu=mu)
    seconds = time.perf_counter() - start
    winkler = winkler_indentation(gaps, block.areas, np.ones(len(gaps)), load, stiffness,
                                  thickness, bottom_factor)
    points = block.top + [0.0, low, 0.0]
    return {"block": block, "top_y": low, "gaps": gaps, "fe": fe, "winkler": winkler,
            "fe_figures": pressure_figures(points, block.areas, fe.pressure,
                                           floor=1e-4 * fe.pressure.max()),
            "winkler_figures": pressure_figures(points, block.areas, winkler.pressure),
            "comparison": field_comparison(fe.pressure, winkler.pressure, block.areas),
            "fe_seconds": seconds}


def surface_layer_indentation(surface_vertices: np.ndarray, surface_triangles: np.ndarray,
                              vertices: np.ndarray, triangles: np.ndarray, load: float, *,
                              stiffness: float = 200e3, thickness: float = 0.1,
                              bottom_factor: float = 20.0, poisson: float = 0.3,
                              mu: float = 0.0, layers: int = 4, subdivisions: int = 2,
                              reach: float | None = None, behind: float = 0.15,
                              youngs: float | None = None, base: float | None = None) -> dict:
    """A rigid body pressed straight down (y is up), held without turning or sliding, into a
    foam layer of `thickness` under a surface (`surface_layer_mesh`, extruded against the
    surface's normals) until the foam carries `load` along gravity: by finite elements (E =
    stiffness x thickness) and by the evaluation's Winkler law on the layer's nodes (depth along
    each node's normal, the body's descent projected on it less the gap).

    Parameters
    ----------
    surface_vertices : (S, 3) float
        The surface, metres, its triangles `surface_triangles` (T, 3) facing the body.
    vertices : (V, 3) float
        The body as held (it may already be sunk into the surface: gaps are measured from
        `behind` metres behind each node, and may be negative).
    triangles : (G, 3) int
        The skin that presses the surface (e.g. the supported parts').
    load : float
        N the layer carries along gravity.
    stiffness, thickness, bottom_factor, poisson, mu : float
        As `flat_slab_indentation`.
    layers : int, default 4
        Prisms through the thickness.
    subdivisions : int, default 2
        Loop subdivisions of the skin (`smooth_skin`).
    reach : float, optional
        Build the foam only on the surface's triangles with a corner whose gap is below
        `reach` (m; default: all of them).
    behind : float, default 0.15
        How far behind the surface the gap rays start, m.
    youngs : float, optional
        The finite elements' Young's modulus, Pa (default stiffness x thickness).
    base : float, optional
        Instead of a layer of `thickness` along the normals, the foam is a block carved to the
        surface with a flat base at y = `base` (m, fixed): each vertex extruded straight down
        to it (the Winkler law keeps `thickness` for its bottoming).

    Returns
    -------
    dict
        ``block``, ``gaps``, ``fe``, ``winkler``, ``fe_figures``, ``winkler_figures``,
        ``comparison``, ``fe_seconds`` as `flat_slab_indentation` gives them, and ``folded``
        (bool per triangle of the layer's surface, `folded_triangles`) with ``triangles``,
        the surface triangles the foam was built on.
    """
    import time

    from solver.mesh import vertex_normals

    s = np.asarray(surface_vertices, dtype=np.float64)
    st = np.asarray(surface_triangles, dtype=np.int64)
    v, t = smooth_skin(vertices, triangles, subdivisions)
    normals = vertex_normals(s, st)
    gaps_all = underside_gaps(s - behind * normals, normals, v, t) - behind
    if reach is not None:
        st = st[(gaps_all[st] < reach).any(axis=1)]
    extrusion = None
    if base is not None:
        if np.any(s[np.unique(st), 1] <= base):
            raise ValueError(f"Expected the base below the surface, got base={base} and the "
                             f"surface's lowest point {s[np.unique(st), 1].min()}")
        extrusion = np.zeros_like(s)
        extrusion[:, 1] = -(s[:, 1] - base) / thickness
    block = surface_layer_mesh(s, st, normals, thickness, layers, extrusion)
    gaps = gaps_all[block.mesh.base]
    cosines = block.normals[:, 1]
    start = time.perf_counter()
    modulus = stiffness * thickness if youngs is None else youngs
    fe = fe_indentation(block, gaps, [0.0, -1.0, 0.0], load, youngs=modulus,
                        poisson=poisson, mu=mu)
    seconds = time.perf_counter() - start
    winkler = winkler_indentation(gaps, block.areas, cosines, load, stiffness, thickness,
                                  bottom_factor)
    return {"block": block, "gaps": gaps, "fe": fe, "winkler": winkler,
            "fe_figures": pressure_figures(block.top, block.areas, fe.pressure,
                                           floor=1e-4 * fe.pressure.max()),
            "winkler_figures": pressure_figures(block.top, block.areas, winkler.pressure),
            "comparison": field_comparison(fe.pressure, winkler.pressure, block.areas),
            "fe_seconds": seconds, "folded": folded_triangles(block, st), "triangles": st}


def ifd_modulus(stiffness: float = 200e3, thickness: float = 0.1, poisson: float = 0.3, *,
                spacing: float = 0.01) -> float:
    """Young's modulus (Pa) of the elastic foam that reads as the Winkler `stiffness` (Pa/m)
    in the test the stiffness was taken from: ASTM D3574's indentation force deflection, a
    flat circular indenter of 203 mm (50 in^2, 323 cm^2) pressed 25 % into a 380 x 380 mm
    sample of `thickness` (m) on a rigid base (fixed here), whose force the Winkler law reads
    as stiffness x area x depth. Found by finite elements on a slab of node `spacing` (m),
    frictionless: linear, so one solve scales E = k h x (the finite elements' sink / the
    Winkler sink at the same force). Measured: 11.7 kPa at nu = 0.3 and 8.3 kPa at 0.45 for
    the default foam (200 kPa/m, 10 cm; 1 cm and 7.5 mm nodes agree within 0.3 %), against
    k h = 20 kPa."""
    half, radius = 0.19, 0.1015
    xs = np.linspace(-half, half, int(round(2 * half / spacing)) + 1)
    block = slab_mesh(xs, xs, thickness * np.array([0, .05, .1, .2, .3, .45, .6, .8, 1.0]))
    inside = np.hypot(block.top[:, 0], block.top[:, 2]) <= radius
    depth = 0.25 * thickness
    force = stiffness * np.pi * radius ** 2 * depth
    youngs = stiffness * thickness
    fe = fe_indentation(block, np.where(inside, 0.0, np.inf), [0.0, -1.0, 0.0], force,
                        youngs=youngs, poisson=poisson)
    return youngs * fe.descent / depth
