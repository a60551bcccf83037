"""Triangle and quad meshes: the one home of face products, normals, areas, volumes and
closest-point queries, for bodies and surfaces alike.

Vertices are (V, 3) float metres, triangles (F, 3) and quads (F, 4) int, counter-clockwise seen
from the side a face's normal points to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

import solver.threads  # noqa: F401  (libigl's thread count, set before libigl first runs)


def quad_triangles(quads: np.ndarray) -> np.ndarray:
    """(2F, 3) triangles of (F, 4) quads, each split along its 0-2 diagonal."""
    quads = np.asarray(quads)
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


def face_cross(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(F, 3) (b - a) x (c - a) of each triangle (a, b, c): twice its area along its normal."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    return np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])


def face_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of the triangles (zero-area faces give a zero vector)."""
    n = face_cross(vertices, triangles)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def area_weighted_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 3) unit vertex normals, the area-weighted mean of the incident faces' normals
    (libigl's `per_vertex_normals`, area weighting)."""
    import igl

    return igl.per_vertex_normals(np.asarray(vertices, dtype=np.float64),
                                  np.asarray(triangles, dtype=np.int64),
                                  igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA)


def enclosed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Volume (m^3) a closed, outward-oriented triangle mesh encloses (divergence theorem)."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles)]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


def volume_centroid(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(3,) centroid of the volume a closed triangle mesh encloses."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c))  # six times each tetrahedron's volume
    return vol @ (a + b + c) / (4.0 * vol.sum())


def faces_problem(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """What is wrong with a face list (indices out of range, repeated corners, no area), or
    None. faces : (F, 3) triangles or (F, 4) quads."""
    if faces.min() < 0 or faces.max() >= len(vertices):
        return (f"expected face indices in 0..{len(vertices) - 1}, got "
                f"{int(faces.min())}..{int(faces.max())}")
    ordered = np.sort(faces, axis=1)
    if np.any(ordered[:, 1:] == ordered[:, :-1]):
        return "expected distinct vertices in every face"
    corner = vertices[faces]
    with np.errstate(over="ignore", invalid="ignore"):  # (huge coordinates: inf, not none)
        area = np.linalg.norm(np.cross(corner[:, 2] - corner[:, 0], corner[:, -1] - corner[:, 1]),
                              axis=1)
    if np.any(area < 1e-10):
        return f"expected faces of non-zero area; face {int(np.argmin(area))} has none"
    return None


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
        """(V,) Voronoi (mixed) areas (m^2) and (V, 3) area-weighted unit normals."""
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
    """(V, 3) unit normals, area-weighted (the fast path of `area_weighted_normals`)."""
    return triangle_mesh(triangles, len(vertices)).measures(vertices)[1]


class SurfaceMeshError(ValueError):
    """A surface no distance query can be made on (empty, ill-indexed, not finite)."""


@dataclass(frozen=True, eq=False)
class SurfaceMesh:
    """A triangle surface for distance queries: vertices (N, 3), triangles (F, 3), unit face
    normals (F, 3) pointing to the side bodies rest on. Made by `from_triangles` (or
    `from_quads`, `from_faces`), which `check` the surface first."""

    vertices: np.ndarray
    triangles: np.ndarray
    face_normals: np.ndarray

    @staticmethod
    def check(v: np.ndarray, t: np.ndarray) -> None:
        """A SurfaceMeshError unless vertices v (N, 3) are finite and triangles t (F, 3) index
        them, neither empty (libigl's search tree on an empty or ill-indexed mesh ends the
        process with no error)."""
        if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3:
            raise SurfaceMeshError(f"Expected a surface of (N, 3) vertices and (F, 3) "
                                   f"triangles, got {v.shape} and {t.shape}")
        if not len(v) or not len(t):
            raise SurfaceMeshError(f"Expected a surface with vertices and faces, got "
                                   f"{len(v)} vertices and {len(t)} faces")
        if t.min() < 0 or t.max() >= len(v):
            raise SurfaceMeshError(f"Expected face indices in 0..{len(v) - 1}, got "
                                   f"{t.min()}..{t.max()}")
        if not np.all(np.isfinite(v)):
            raise SurfaceMeshError(f"Expected finite surface vertices, got "
                                   f"{int(np.sum(~np.isfinite(v).all(axis=1)))} that are not")

    @classmethod
    def from_quads(cls, vertices: np.ndarray, quads: np.ndarray) -> "SurfaceMesh":
        return cls.from_triangles(vertices, quad_triangles(quads))

    @classmethod
    def from_triangles(cls, vertices: np.ndarray, triangles: np.ndarray) -> "SurfaceMesh":
        v = np.asarray(vertices, dtype=np.float64)
        t = np.asarray(triangles, dtype=np.int64)
        cls.check(v, t)  # (before the normals index the vertices)
        return cls(v, t, face_normals(v, t))

    @classmethod
    def from_faces(cls, vertices: np.ndarray, faces: np.ndarray) -> "SurfaceMesh":
        """From (F, 4) quads or (F, 3) triangles."""
        faces = np.asarray(faces)
        return cls.from_quads(vertices, faces) if faces.shape[1] == 4 else \
            cls.from_triangles(vertices, faces)

    def tree(self):
        """The surface's bounding-box tree (libigl's AABB), built on first use and kept."""
        tree = self.__dict__.get("_tree")
        if tree is None:
            import igl

            tree = igl.AABB()
            tree.init(self.vertices, self.triangles)
            object.__setattr__(self, "_tree", tree)
        return tree

    def vertex_tree(self):
        """A k-d tree of the surface's vertices (scipy's cKDTree) and its longest edge (m),
        built on first use and kept: every surface point lies within that edge of a vertex."""
        kept = self.__dict__.get("_vertex_tree")
        if kept is None:
            from scipy.spatial import cKDTree

            corners = self.vertices[self.triangles]
            edge = float(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max())
            kept = (cKDTree(self.vertices), edge)
            object.__setattr__(self, "_vertex_tree", kept)
        return kept

    def closest(self, points: np.ndarray):
        """Unsigned distance (P,), signed distance along the closest face's normal (P,), whether
        the closest point lies inside its face (not on the surface's border) (P,), the closest
        face (P,) and the closest point (P, 3)."""
        points = np.asarray(points, dtype=np.float64)
        sq, face, closest = self.tree().squared_distance(self.vertices, self.triangles, points)
        dist = np.sqrt(sq)
        offset = points - closest
        signed = np.einsum("ij,ij->i", offset, self.face_normals[face])
        # over the surface: the offset runs along the normal (not sideways off an edge)
        over = np.abs(signed) >= 0.95 * dist - 1e-9
        return dist, signed, over, face, closest


def self_intersections(vertices: np.ndarray, triangles: np.ndarray,
                       chunk: int = 200_000, depth: float = 0.0) -> np.ndarray:
    """(P, 2) pairs of triangles that share no vertex and yet meet, i < j.

    Broad phase: the triangles' bounding boxes binned on a uniform grid (cells twice the
    median box); narrow phase: the separating-axis test (the two normals, the nine products
    of their edges, and the six in-plane edge normals for coplanar triangles), vectorised.

    Parameters
    ----------
    vertices : (V, 3) float
    triangles : (F, 3) int
    chunk : int
        Pairs tested at once (memory bound).
    depth : float
        Metres two triangles must overlap by along every axis to count (0: touching counts).

    Returns
    -------
    (P, 2) int
        Triangle indices of each crossing pair.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    corners = v[t]
    return meeting_pairs(corners, t, box_pairs(corners.min(axis=1), corners.max(axis=1)),
                         chunk, depth)


def meeting_pairs(corners: np.ndarray, triangles: np.ndarray, pairs: np.ndarray,
                  chunk: int = 200_000, depth: float = 0.0) -> np.ndarray:
    """The `pairs` (P, 2) of triangles (corners (F, 3, 3), vertex indices (F, 3)) that share no
    vertex and yet meet (`self_intersections`' narrow phase, on candidate pairs)."""
    a, b = pairs[:, 0], pairs[:, 1]
    ta, tb = triangles[a], triangles[b]
    shared = np.zeros(len(a), dtype=bool)
    for i in range(3):  # nine comparisons of columns: no (P, 3, 3) array
        for j in range(3):
            shared |= ta[:, i] == tb[:, j]
    a, b = a[~shared], b[~shared]
    hits = [np.zeros((0, 2), dtype=np.int64)]
    for s in range(0, len(a), chunk):
        ka, kb = a[s:s + chunk], b[s:s + chunk]
        meet = _no_separating_axis(corners[ka], corners[kb],
                                   -depth if depth > 0 else 1e-12)
        hits.append(np.stack([ka[meet], kb[meet]], axis=1))
    return np.concatenate(hits)


def box_pairs(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(P, 2) pairs i < j of boxes (lo, hi: (F, 3)) that overlap.

    Boxes of about one size (a surface's triangles): two boxes overlap only where their
    centres lie within the sum of their half diagonals, so a k-d tree's pairs of centres within
    twice the largest half diagonal hold every overlapping pair. Otherwise the boxes are binned
    on a uniform grid (cells twice the median box)."""
    half = 0.5 * np.linalg.norm(hi - lo, axis=1)
    if len(lo) > 1 and half.max() <= 2.0 * np.median(half):
        from scipy.spatial import cKDTree

        pairs = cKDTree(0.5 * (lo + hi)).query_pairs(2.0 * half.max() + 1e-12,
                                                      output_type="ndarray")  # i < j
        keep = np.arange(len(pairs))
        for axis in range(3):  # one axis at a time, each on the pairs the ones before left
            a, b = pairs[keep, 0], pairs[keep, 1]
            low, high = lo[:, axis], hi[:, axis]
            keep = keep[(low[a] <= high[b]) & (low[b] <= high[a])]
        return pairs[keep]
    return _grid_box_pairs(lo, hi)


def _grid_box_pairs(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """`box_pairs` by binning the boxes on a uniform grid (cells twice the median box)."""
    size = 2.0 * np.median((hi - lo).max(axis=1)) + 1e-12
    first = np.floor((lo - lo.min(axis=0)) / size).astype(np.int64)
    span = np.floor((hi - lo.min(axis=0)) / size).astype(np.int64) - first + 1
    count = span.prod(axis=1)
    owner = np.repeat(np.arange(len(lo)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    sy, sz = span[owner, 1], span[owner, 2]
    cell = first[owner] + np.stack([k // (sy * sz), (k // sz) % sy, k % sz], axis=1)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    order = np.argsort(key, kind="stable")
    key, owner = key[order], owner[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], len(key)]
    partners = np.repeat(ends, ends - starts) - np.arange(len(key)) - 1  # later in the cell
    i = np.repeat(np.arange(len(key)), partners)
    j = i + 1 + np.arange(partners.sum()) - np.repeat(np.cumsum(partners) - partners, partners)
    a, b = owner[i], owner[j]
    overlap = np.all((lo[a] <= hi[b]) & (lo[b] <= hi[a]), axis=1) & (a != b)
    n = np.int64(len(lo))
    unique = np.unique(np.minimum(a, b)[overlap] * n + np.maximum(a, b)[overlap])
    return np.stack([unique // n, unique % n], axis=1)


def _no_separating_axis(p: np.ndarray, q: np.ndarray, gap: float = 1e-12) -> np.ndarray:
    """(P,) whether triangles p[k] and q[k] ((P, 3, 3) corners) meet: no axis parts them by
    more than `gap` metres. Most pairs are parted by one triangle's plane: only the others are
    tried on every axis."""
    meet = np.zeros(len(p), dtype=bool)
    rest = np.flatnonzero(~(_plane_parts(p, q, gap) | _plane_parts(q, p, gap)))
    if len(rest):
        meet[rest] = _no_axis_parts(p[rest], q[rest], gap)
    return meet


def _plane_parts(p: np.ndarray, q: np.ndarray, gap: float) -> np.ndarray:
    """(P,) whether the plane of triangle p[k] parts it from q[k] by more than `gap` (the
    first two of the separating-axis test's axes, as `_no_axis_parts` measures them)."""
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 1])
    length = np.linalg.norm(n, axis=1)
    n = n / np.maximum(length, 1e-300)[:, None]
    pp, qq = np.einsum("pk,pvk->pv", n, p), np.einsum("pk,pvk->pv", n, q)
    apart = np.maximum(pp.min(axis=1) - qq.max(axis=1), qq.min(axis=1) - pp.max(axis=1))
    return (apart > gap) & (length >= 1e-300)


def _no_axis_parts(p: np.ndarray, q: np.ndarray, gap: float) -> np.ndarray:
    """(P,) whether no axis of the separating-axis test parts triangles p[k] and q[k] by more
    than `gap` metres."""
    ep, eq = np.roll(p, -1, axis=1) - p, np.roll(q, -1, axis=1) - q
    n_p, n_q = np.cross(ep[:, 0], ep[:, 1]), np.cross(eq[:, 0], eq[:, 1])
    axes = np.concatenate([n_p[:, None], n_q[:, None],
                           np.cross(ep[:, :, None], eq[:, None, :]).reshape(-1, 9, 3),
                           np.cross(n_p[:, None], ep), np.cross(n_q[:, None], eq)], axis=1)
    length = np.linalg.norm(axes, axis=2, keepdims=True)
    axes = axes / np.maximum(length, 1e-300)
    pp, qq = np.einsum("pak,pvk->pav", axes, p), np.einsum("pak,pvk->pav", axes, q)
    apart = np.maximum(pp.min(axis=2) - qq.max(axis=2), qq.min(axis=2) - pp.max(axis=2))
    apart[length[..., 0] < 1e-300] = -np.inf  # parallel edges give no axis
    return ~(apart > gap).any(axis=1)


class MeshOrientationError(ValueError):
    """A surface that is no orientable manifold (an edge of three faces, or run one way twice)."""


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """The border's edges of a surface, each as its one face runs it.

    Parameters
    ----------
    faces : (F, 3) or (F, 4) int

    Returns
    -------
    (B, 2) int
        Vertex pairs (a, b) with the face running a -> b.

    Raises
    ------
    MeshOrientationError
        If an edge is shared by more than two faces or run the same way twice (not an
        orientable manifold surface).
    """
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)
    # an edge as one integer (a sort of integers, not of rows): either way, and as run
    n = int(edges.max(initial=0)) + 1
    _, inverse, counts = np.unique(edges.min(axis=1) * n + edges.max(axis=1),
                                   return_inverse=True, return_counts=True)
    if counts.max(initial=0) > 2:
        raise MeshOrientationError(f"Expected a manifold surface, got an edge shared by "
                         f"{int(counts.max())} faces")
    _, directed = np.unique(edges[:, 0] * n + edges[:, 1], return_counts=True)
    if directed.max(initial=0) > 1:
        raise MeshOrientationError("Expected consistently oriented faces, got an edge run the same "
                         "way by two faces")
    return edges[counts[inverse] == 1]


class MeshSplitError(ValueError):
    """A quad that cannot be split (out of range, an edge shared by more than two quads)."""


def split_quad(vertices: np.ndarray, quads: np.ndarray, face: int,
               creases=()) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """Splits one quad of a quad mesh into four and keeps the mesh all quads.

    A quad halved across two opposite edges leaves its neighbours a vertex in the middle of an
    edge, which no quad can take; so the cut runs on through the strip of quads either way (a
    loop cut, as a modeller makes one): each quad of the face's row and column is halved, the
    face itself (and any quad both cuts cross) quartered. New vertices sit at the middle of the
    edges they split and at the centre of the quartered quads, so the control net keeps its
    shape; existing vertices keep their indices, the new ones follow them.

    Parameters
    ----------
    vertices : (n, 3) float, metres.
    quads : (F, 4) int, counter-clockwise; a quad's new quads keep its orientation.
    face : the quad to split, 0..F-1.
    creases : control edges (i, j) kept sharp; a split one becomes its two halves.

    Returns
    -------
    vertices : (n + k, 3) float; quads : (F', 4) int; creases : list of (i, j).
    """
    v = np.asarray(vertices, dtype=np.float64)
    q = np.asarray(quads, dtype=np.int64)
    if q.ndim != 2 or q.shape[1] != 4:
        raise MeshSplitError(f"Expected (F, 4) quads, got shape {q.shape}")
    if not 0 <= face < len(q):
        raise MeshSplitError(f"Expected a face in 0..{len(q) - 1}, got {face}")
    sides: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for g, quad in enumerate(q.tolist()):
        for i in range(4):
            a, b = quad[i], quad[(i + 1) % 4]
            sides.setdefault((min(a, b), max(a, b)), []).append((g, i))
    for edge, users in sides.items():
        if len(users) > 2:
            raise MeshSplitError(f"Expected every edge on at most two quads, edge {list(edge)} "
                                 f"is on {len(users)}")

    def key(g: int, i: int) -> tuple[int, int]:
        a, b = q[g, i], q[g, (i + 1) % 4]
        return (int(min(a, b)), int(max(a, b)))

    cut: set[tuple[int, int]] = set()
    for first in (0, 1, 2, 3):  # both ways along both strips through the face
        g, i = face, first
        while key(g, i) not in cut:
            cut.add(key(g, i))
            across = [(h, j) for h, j in sides[key(g, i)] if h != g]
            if not across:
                break
            h, j = across[0]
            g, i = h, (j + 2) % 4
    middle = {edge: len(v) + k for k, edge in enumerate(sorted(cut))}
    new = [v, np.array([(v[a] + v[b]) / 2 for a, b in sorted(cut)]).reshape(-1, 3)]
    count = len(v) + len(cut)
    out = []
    for g, quad in enumerate(q.tolist()):
        split = [key(g, i) in cut for i in range(4)]
        if not any(split):
            out.append(quad)
            continue
        if all(split):
            mid = [middle[key(g, i)] for i in range(4)]
            new.append(v[quad].mean(axis=0)[None])
            c, count = count, count + 1
            out += [[quad[0], mid[0], c, mid[3]], [mid[0], quad[1], mid[1], c],
                    [c, mid[1], quad[2], mid[2]], [mid[3], c, mid[2], quad[3]]]
            continue
        # a strip passes once: two opposite edges cut; turn the quad so they are 0-1 and 2-3
        r = split.index(True)
        assert split[(r + 2) % 4] and not split[(r + 1) % 4], "a strip crosses opposite edges"
        a, b, c_, d = (quad[(r + k) % 4] for k in range(4))
        m0, m2 = middle[key(g, r)], middle[key(g, (r + 2) % 4)]
        out += [[a, m0, m2, d], [m0, b, c_, m2]]
    halves = []
    for i, j in creases:
        edge = (min(i, j), max(i, j))
        halves += [(i, middle[edge]), (middle[edge], j)] if edge in middle else [(i, j)]
    return np.concatenate(new), np.array(out, dtype=np.int64), halves
