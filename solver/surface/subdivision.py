"""Catmull-Clark subdivision as sparse matrices.

One step maps the vertices V (n, 3) of a polygon mesh (quads, triangles, any mix) to the next
level's vertices `S @ V`, ordered as [vertex points (n), edge points (E), face points (F)], with
all-quad faces. Rules (Catmull and Clark 1978, with the usual boundary and crease rules):

* face point: the mean of the face's vertices;
* edge point: (a + b + f0 + f1) / 4 for an interior smooth edge, (a + b) / 2 on a boundary or a
  crease;
* vertex point of a smooth vertex of valence n: ((n - 2) v + (sum of adjacent face points
  + sum of neighbours) / n) / n, which gives a regular vertex 9/16 for itself, 3/32 for each edge
  neighbour and 1/64 for each diagonal one;
* a vertex on a boundary or on a crease curve (two sharp edges): (a + 6 v + b) / 8 along that
  curve, so boundary curves are cubic B-splines; a vertex with three or more sharp edges, or a
  boundary vertex with a single face (a corner), stays where it is.

A crease (a pair of vertex indices) stays sharp at every level: each half is a crease of the
next. Operators are cached by topology, so a fitting loop that moves vertices never rebuilds them.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np
import scipy.sparse as sp

from solver.mesh import area_weighted_normals, quad_triangles


class MeshError(ValueError):
    """A control mesh the subdivision cannot take (bad faces, non-manifold edges)."""


@dataclass(frozen=True, eq=False)
class Step:
    """One subdivision step: `vertices_next = matrix @ vertices`; `faces` (F', 4) of the next
    level; `creases` (C', 2) of the next level; `boundary` (n',) bool."""

    matrix: sp.csr_matrix
    faces: np.ndarray
    creases: np.ndarray
    boundary: np.ndarray


@dataclass(frozen=True, eq=False)
class Subdivision:
    """Level `level` of a control mesh: `vertices = matrix @ control` and its quad faces.

    matrix : (n_s, n_0) scipy.sparse CSR, rows summing to 1.
    faces : (F_s, 4) int quads of level s.
    steps : the per-level steps, coarse to fine.
    derived : what `kept` built from the topology alone, by name.
    """

    matrix: sp.csr_matrix
    faces: np.ndarray
    level: int
    steps: tuple[Step, ...]
    derived: dict = field(default_factory=dict, repr=False)

    @property
    def triangles(self) -> np.ndarray:
        return self.kept("triangles", lambda: quad_triangles(self.faces))

    def kept(self, name: str, make: Callable[[], Any]) -> Any:
        """What `make` builds from this topology alone (the same faces, creases and level), built
        on first use and kept with the operator (which `subdivision` caches by topology), so
        that the fits of one control mesh build it once. Callers do not modify it."""
        if name not in self.derived:
            self.derived[name] = make()
        return self.derived[name]

    def apply(self, control: np.ndarray) -> np.ndarray:
        """(n_s, 3) vertices of level s for control vertices (n_0, 3)."""
        return self.matrix @ np.asarray(control, dtype=np.float64)

    def normals(self, vertices: np.ndarray) -> np.ndarray:
        """(n_s, 3) unit vertex normals of level-s vertices (area-weighted face normals)."""
        return area_weighted_normals(vertices, self.triangles)


def _as_faces(faces: Sequence[Sequence[int]] | np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Faces as a (F, k_max) array padded with -1, and each face's size."""
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        arr = faces.astype(np.int64)
        sizes = np.full(len(arr), arr.shape[1])
    else:
        rows = [list(map(int, f)) for f in faces]
        if not rows:
            raise MeshError("Expected at least one face, got none")
        kmax = max(len(r) for r in rows)
        arr = np.full((len(rows), kmax), -1, dtype=np.int64)
        sizes = np.array([len(r) for r in rows])
        for i, r in enumerate(rows):
            arr[i, :len(r)] = r
    if len(arr) == 0:
        raise MeshError("Expected at least one face, got none")
    if sizes.min() < 3:
        raise MeshError(f"Expected faces of 3 or more vertices, got one of {sizes.min()}")
    valid = np.arange(arr.shape[1])[None, :] < sizes[:, None]
    used = arr[valid]
    if used.min() < 0 or used.max() >= n:
        raise MeshError(f"Expected face indices in 0..{n - 1}, got {used.min()}..{used.max()}")
    srt = np.sort(np.where(valid, arr, -1), axis=1)
    dup = ((srt[:, 1:] == srt[:, :-1]) & (srt[:, 1:] >= 0)).any(axis=1)
    if dup.any():
        i = int(np.argmax(dup))
        raise MeshError(f"Expected distinct vertices in each face, got face {i}: "
                        f"{arr[i, :sizes[i]].tolist()}")
    return arr, sizes


@dataclass(frozen=True, eq=False)
class _Edges:
    """A polygon mesh's corners and edges: corner k is position ci[k] of face fi[k], from vertex
    a[k]; edge e joins edge_a[e] and edge_b[e], has counts[e] faces and is sharp (a boundary
    or a crease); corner k runs along edge edge_of_corner[k]."""

    fi: np.ndarray
    ci: np.ndarray
    a: np.ndarray
    edge_of_corner: np.ndarray
    counts: np.ndarray
    edge_a: np.ndarray
    edge_b: np.ndarray
    sharp: np.ndarray


def _edges(arr: np.ndarray, sizes: np.ndarray, n: int, creases: np.ndarray | None) -> _Edges:
    fi, ci = np.nonzero(np.arange(arr.shape[1])[None, :] < sizes[:, None])
    a = arr[fi, ci]
    b = arr[fi, (ci + 1) % sizes[fi]]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    keys = lo * n + hi
    uniq, edge_of_corner, counts = np.unique(keys, return_inverse=True, return_counts=True)
    ne = len(uniq)
    if counts.max() > 2:
        bad = uniq[np.argmax(counts)]
        raise MeshError(f"Expected a manifold mesh, got edge ({bad // n}, {bad % n}) shared by "
                        f"{counts.max()} faces")
    sharp = counts == 1  # boundary edges
    if creases is not None and len(creases):
        c = np.sort(np.asarray(creases, dtype=np.int64).reshape(-1, 2), axis=1)
        ck = c[:, 0] * n + c[:, 1]
        pos = np.searchsorted(uniq, ck)
        found = (pos < ne) & (uniq[np.minimum(pos, ne - 1)] == ck)
        if not found.all():
            e = c[np.argmin(found)]
            raise MeshError(f"Expected creases along mesh edges, got ({e[0]}, {e[1]})")
        sharp = sharp.copy()
        sharp[pos] = True
    return _Edges(fi, ci, a, edge_of_corner, counts, uniq // n, uniq % n, sharp)


def _edge_points(g: _Edges, face_pts: sp.csr_matrix, n: int) -> sp.csr_matrix:
    """(E, n): (a + b + f0 + f1) / 4 on smooth edges, (a + b) / 2 on sharp ones."""
    ne, nf = len(g.edge_a), face_pts.shape[0]
    smooth = ~g.sharp
    e_rows = np.concatenate([np.arange(ne), np.arange(ne)])
    e_cols = np.concatenate([g.edge_a, g.edge_b])
    e_vals = np.where(np.concatenate([smooth, smooth]), 0.25, 0.5)
    edge_vert = sp.csr_matrix((e_vals, (e_rows, e_cols)), shape=(ne, n))
    sm_corner = smooth[g.edge_of_corner]
    edge_face = sp.csr_matrix((np.full(sm_corner.sum(), 0.25),
                               (g.edge_of_corner[sm_corner], g.fi[sm_corner])), shape=(ne, nf))
    return edge_vert + edge_face @ face_pts


def _vertex_points(g: _Edges, face_pts: sp.csr_matrix, n: int
                   ) -> tuple[sp.csr_matrix, np.ndarray]:
    """(n, n) the vertex points (smooth, crease-curve and corner rules) and the boundary
    vertices (n,) bool."""
    ne, nf = len(g.edge_a), face_pts.shape[0]
    edge_a, edge_b, sharp = g.edge_a, g.edge_b, g.sharp
    valence = np.bincount(np.concatenate([edge_a, edge_b]), minlength=n)
    n_faces = np.bincount(g.a, minlength=n)
    sharp_count = np.bincount(np.concatenate([edge_a[sharp], edge_b[sharp]]), minlength=n)
    boundary = np.zeros(n, dtype=bool)
    boundary[np.concatenate([edge_a[g.counts == 1], edge_b[g.counts == 1]])] = True
    unused = valence == 0
    corner = (sharp_count >= 3) | (boundary & (n_faces == 1)) | unused
    curve = (sharp_count == 2) & ~corner
    smooth_v = ~corner & ~curve
    nv = np.maximum(valence, 1).astype(float)
    # smooth: (n-2)/n v + 1/n^2 (sum of face points + sum of neighbours)
    vf = sp.csr_matrix((np.ones(len(g.a)), (g.a, g.fi)), shape=(n, nf))  # vertex-face incidence
    adj = sp.csr_matrix((np.ones(2 * ne), (np.concatenate([edge_a, edge_b]),
                                           np.concatenate([edge_b, edge_a]))), shape=(n, n))
    scale = sp.diags(np.where(smooth_v, 1.0 / nv**2, 0.0))
    smooth_part = scale @ (vf @ face_pts + adj) + sp.diags(np.where(smooth_v, (nv - 2) / nv, 0.0))
    # crease curve: 3/4 v + 1/8 each sharp neighbour
    s_rows = np.concatenate([edge_a[sharp], edge_b[sharp]])
    s_cols = np.concatenate([edge_b[sharp], edge_a[sharp]])
    keep = curve[s_rows]
    curve_part = sp.csr_matrix((np.full(keep.sum(), 0.125), (s_rows[keep], s_cols[keep])),
                               shape=(n, n)) + sp.diags(np.where(curve, 0.75, 0.0))
    corner_part = sp.diags(corner.astype(float))
    return smooth_part + curve_part + corner_part, boundary


def subdivide_once(n: int, faces, creases: np.ndarray | None = None) -> Step:
    """The operator of one Catmull-Clark step for a mesh of n vertices (see module docstring)."""
    arr, sizes = _as_faces(faces, n)
    nf = len(arr)
    g = _edges(arr, sizes, n, creases)
    ne = len(g.edge_a)
    face_pts = sp.csr_matrix((1.0 / sizes[g.fi], (g.fi, g.a)), shape=(nf, n))
    vert_pts, boundary = _vertex_points(g, face_pts, n)
    matrix = sp.vstack([vert_pts, _edge_points(g, face_pts, n), face_pts]).tocsr()
    matrix.sum_duplicates()
    matrix.eliminate_zeros()
    # next faces: at each corner i of face f, (v_i, e(i, i+1), f, e(i-1, i))
    prev_c = (g.ci - 1) % sizes[g.fi]
    corner_index = np.full(arr.shape, -1)
    corner_index[g.fi, g.ci] = np.arange(len(g.fi))
    e_prev = g.edge_of_corner[corner_index[g.fi, prev_c]]
    new_faces = np.stack([g.a, n + g.edge_of_corner, n + ne + g.fi, n + e_prev], axis=1)
    # creases of the next level: both halves of each sharp (non-boundary) crease edge
    crease_edges = np.flatnonzero(g.sharp & (g.counts == 2))
    new_creases = np.concatenate([
        np.stack([g.edge_a[crease_edges], n + crease_edges], axis=1),
        np.stack([n + crease_edges, g.edge_b[crease_edges]], axis=1),
    ])
    next_boundary = np.concatenate([boundary, g.counts == 1, np.zeros(nf, dtype=bool)])
    return Step(matrix, new_faces, new_creases, next_boundary)


_CACHE: "OrderedDict[tuple, Subdivision]" = OrderedDict()
_CACHE_SIZE = 64


def _topology_key(n: int, faces, creases, level: int) -> tuple:
    arr, sizes = _as_faces(faces, n)
    c = np.zeros((0, 2), dtype=np.int64) if creases is None else \
        np.sort(np.asarray(creases, dtype=np.int64).reshape(-1, 2), axis=1)
    c = c[np.lexsort(c.T[::-1])] if len(c) else c
    return (n, level, arr.tobytes(), sizes.tobytes(), c.tobytes())


def subdivision(n: int, faces, level: int, creases: Iterable[Sequence[int]] | None = None
                ) -> Subdivision:
    """The composed operator of `level` Catmull-Clark steps for a mesh of n vertices.

    Cached by topology: the same faces, creases and level return the same object.

    Parameters
    ----------
    n : int
        Number of control vertices.
    faces : (F, k) int array or list of index lists
        The control faces (quads, triangles or other polygons), indices into the n vertices.
    level : int
        Number of subdivision steps, >= 0 (0: the identity).
    creases : iterable of (2,) int pairs, optional
        Edges (pairs of vertex indices) to keep sharp at every level.

    Returns
    -------
    Subdivision
        The operator: `matrix` (n_s, n) sparse CSR with rows summing to 1, so that the level's
        vertices are ``matrix @ control`` ((n, 3) metres in, (n_s, 3) metres out), its `faces`
        (F_s, 4) quads (at level 0 the control faces as an (F, k) array, shorter faces padded
        with -1), and the per-level steps.

    Raises
    ------
    MeshError
        If `level` is negative, or the faces or creases are invalid (no faces, faces of fewer
        than three or repeated vertices, indices out of range, non-manifold edges, creases
        that are not mesh edges).
    """
    if level < 0:
        raise MeshError(f"Expected a subdivision level >= 0, got {level}")
    creases_arr = None if creases is None else np.asarray(list(creases), dtype=np.int64)
    key = _topology_key(n, faces, creases_arr, level)
    hit = _CACHE.get(key)
    if hit is not None:
        _CACHE.move_to_end(key)
        return hit
    arr, sizes = _as_faces(faces, n)
    matrix = sp.identity(n, format="csr")
    steps = []
    cur_faces, cur_n, cur_creases = faces, n, creases_arr
    for _ in range(level):
        step = subdivide_once(cur_n, cur_faces, cur_creases)
        steps.append(step)
        matrix = (step.matrix @ matrix).tocsr()
        cur_faces, cur_n, cur_creases = step.faces, step.matrix.shape[0], step.creases
    result = Subdivision(matrix, np.asarray(cur_faces) if level else arr, level, tuple(steps))
    _CACHE[key] = result
    if len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return result


def grid_mesh(size: Sequence[float] = (1.2, 0.8), resolution: Sequence[int] = (8, 6),
              height: float = 0.45) -> tuple[np.ndarray, np.ndarray]:
    """A flat quad grid in the XZ plane at height y, centred on the origin.

    Parameters
    ----------
    size : (2,) float, default (1.2, 0.8)
        Extent along x and along z, metres.
    resolution : (2,) int, default (8, 6)
        (faces along x, faces along z), each at least 1.
    height : float, default 0.45
        The grid's y, metres.

    Returns
    -------
    vertices : (V, 3) float
        Grid points, metres, V = (nx + 1) (nz + 1); point i (nz + 1) + k is the i-th along x
        and the k-th along z.
    quads : (F, 4) int
        F = nx nz quads, ordered so that face normals point up (+Y).

    Raises
    ------
    MeshError
        If a resolution is below 1.
    """
    nx, nz = (int(r) for r in resolution)
    if nx < 1 or nz < 1:
        raise MeshError(f"Expected a grid resolution of at least 1 x 1, got {resolution}")
    xs = np.linspace(-size[0] / 2, size[0] / 2, nx + 1)
    zs = np.linspace(-size[1] / 2, size[1] / 2, nz + 1)
    gx, gz = np.meshgrid(xs, zs, indexing="ij")
    verts = np.stack([gx.ravel(), np.full(gx.size, float(height)), gz.ravel()], axis=1)
    idx = np.arange((nx + 1) * (nz + 1)).reshape(nx + 1, nz + 1)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1)
    return verts, quads.reshape(-1, 4)
