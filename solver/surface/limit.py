"""Exact Catmull-Clark limit positions of a quad mesh's vertices, as a sparse operator.

Subdividing without end moves every vertex to a point of the limit surface; the limit mask
gives that point directly, ``limit = L @ vertices``, under the same rules as
`solver.surface.subdivision`:

* a smooth vertex of valence n (no sharp edge): (n^2 v + 4 sum(e_i) + sum(d_i)) / (n (n + 5)),
  e_i the edge neighbours and d_i the vertices diagonal to v in its quads (the standard
  Catmull-Clark limit mask; a regular vertex: 16/36, 4/36 per edge neighbour, 1/36 per diagonal);
* a vertex on a boundary or crease curve (two sharp edges a-v-b): (a + 4 v + b) / 6, the limit
  of the cubic B-spline rule (a + 6 v + b) / 8 that the curve follows;
* a corner (three or more sharp edges, a boundary vertex of one face, an unused vertex): itself;
* a dart (one sharp edge ending inside the surface): the dominant left eigenvector of the
  vertex's own one-ring subdivision matrix, read from the subdivision step itself.

Masks need quads (the ring's diagonal vertex): any level s >= 1 is all quads, and a level-0
control mesh of quads works directly.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np
import scipy.sparse as sp

from solver.surface.subdivision import (MeshError, Subdivision, _as_faces, _edges,
                                        subdivide_once, subdivision)


def limit_operator(n: int, quads, creases: Iterable[Sequence[int]] | None = None
                   ) -> sp.csr_matrix:
    """The (n, n) operator taking a quad mesh's vertices to their limit positions.

    Parameters
    ----------
    n : int
        Number of vertices.
    quads : (F, 4) int
        The mesh's quads (a level s >= 1 of `subdivision`, or a quad control mesh).
    creases : iterable of (2,) int pairs, optional
        The sharp edges, as `subdivision` takes them (at the same level as `quads`).

    Returns
    -------
    scipy.sparse.csr_matrix
        (n, n), rows summing to 1: ``limit = L @ vertices`` ((n, 3) metres in and out).

    Raises
    ------
    MeshError
        If a face is not a quad, or the faces or creases are invalid.
    """
    arr, sizes = _as_faces(quads, n)
    if arr.shape[1] != 4 or (sizes != 4).any():
        raise MeshError(f"Expected quads for the limit masks, got faces of "
                        f"{sorted(set(sizes.tolist()))} vertices (subdivide once first)")
    creases_arr = None if creases is None else np.asarray(list(creases), dtype=np.int64)
    g = _edges(arr, sizes, n, creases_arr)
    ends = np.concatenate([g.edge_a, g.edge_b])
    others = np.concatenate([g.edge_b, g.edge_a])
    valence = np.bincount(ends, minlength=n)
    n_faces = np.bincount(g.a, minlength=n)
    sharp2 = np.concatenate([g.sharp, g.sharp])
    sharp_count = np.bincount(ends[sharp2], minlength=n)
    boundary = np.zeros(n, dtype=bool)
    boundary[ends[np.concatenate([g.counts == 1, g.counts == 1])]] = True
    corner = (sharp_count >= 3) | (boundary & (n_faces == 1)) | (valence == 0)
    curve = (sharp_count == 2) & ~corner
    dart = (sharp_count == 1) & ~corner
    smooth = (sharp_count == 0) & ~corner
    nv = np.maximum(valence, 1).astype(float)
    denom = nv * (nv + 5)
    diag = arr[g.fi, (g.ci + 2) % 4]  # the vertex across each corner's quad
    centre_s, edge_s, diag_s = np.flatnonzero(smooth), smooth[ends], smooth[g.a]
    centre_c, edge_c = np.flatnonzero(curve), curve[ends] & sharp2
    centre_k = np.flatnonzero(corner)
    # smooth: centre n^2, edge neighbours 4, diagonals 1, over n (n + 5); curves: (a + 4 v + b)
    # / 6 along their two sharp edges; corners: themselves
    rows = np.concatenate([centre_s, ends[edge_s], g.a[diag_s], centre_c, ends[edge_c],
                           centre_k])
    cols = np.concatenate([centre_s, others[edge_s], diag[diag_s], centre_c, others[edge_c],
                           centre_k])
    vals = np.concatenate([nv[smooth] ** 2 / denom[smooth], 4.0 / denom[ends[edge_s]],
                           1.0 / denom[g.a[diag_s]], np.full(len(centre_c), 4.0 / 6.0),
                           np.full(edge_c.sum(), 1.0 / 6.0), np.ones(len(centre_k))])
    matrix = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    if dart.any():
        matrix = matrix + _dart_rows(n, arr, creases_arr, g, np.flatnonzero(dart), diag)
    matrix.sum_duplicates()
    return matrix.tocsr()


def _dart_rows(n: int, arr: np.ndarray, creases, g, darts: np.ndarray,
               diag: np.ndarray) -> sp.csr_matrix:
    """Rows of the limit operator at darts: the left eigenvector for eigenvalue 1 of each
    dart's one-ring subdivision matrix (centre, edge neighbours, quad diagonals)."""
    step = subdivide_once(n, arr, creases).matrix.tocsr()
    ne = len(g.edge_a)
    rows, cols, vals = [], [], []
    for v in darts:
        edges = np.flatnonzero((g.edge_a == v) | (g.edge_b == v))
        nbrs = np.where(g.edge_a[edges] == v, g.edge_b[edges], g.edge_a[edges])
        corners = np.flatnonzero(g.a == v)
        old = np.concatenate([[v], nbrs, diag[corners]])
        new = np.concatenate([[v], n + edges, n + ne + g.fi[corners]])
        local = step[new][:, old].toarray()
        if not np.allclose(local.sum(axis=1), 1.0) or \
                not np.allclose(step[new].sum(axis=1).A1, 1.0):
            raise AssertionError("a dart's one-ring is not closed under subdivision")
        # l (M - I) = 0 with sum(l) = 1, in the least-squares sense (exact here)
        system = np.vstack([(local - np.eye(len(old))).T, np.ones(len(old))])
        rhs = np.zeros(len(old) + 1)
        rhs[-1] = 1.0
        mask = np.linalg.lstsq(system, rhs, rcond=None)[0]
        rows.append(np.full(len(old), v)), cols.append(old), vals.append(mask)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n, n))


def limit_matrix(n: int, faces, level: int, creases: Iterable[Sequence[int]] | None = None
                 ) -> sp.csr_matrix:
    """The (n_s, n) operator from control vertices to the limit positions of level s's
    vertices: ``L_s @ S_s`` with `S_s` the level's subdivision matrix.

    Parameters
    ----------
    n : int
        Number of control vertices.
    faces : (F, k) int array or list of index lists
        The control faces; with non-quads the level must be at least 1.
    level : int
        The subdivision level s >= 0 whose vertices are taken to the limit.
    creases : iterable of (2,) int pairs, optional
        Control edges kept sharp.

    Returns
    -------
    scipy.sparse.csr_matrix
        (n_s, n), rows summing to 1; ``matrix @ control`` gives (n_s, 3) points on the limit
        surface, in the order (and with the quads) of ``subdivision(n, faces, level, creases)``.
        Built once per topology and kept with that subdivision: not to be modified.

    Raises
    ------
    MeshError
        As `subdivision` does, or for non-quad control faces at level 0.
    """
    sub = subdivision(n, faces, level, creases)
    level_creases = creases if level == 0 else sub.steps[-1].creases
    return sub.kept("limit", lambda: (limit_operator(sub.matrix.shape[0], sub.faces,
                                                     level_creases) @ sub.matrix).tocsr())


def limit_positions(control: np.ndarray, faces, level: int,
                    creases: Iterable[Sequence[int]] | None = None) -> np.ndarray:
    """The limit-surface points of level s's vertices (see `limit_matrix`).

    Parameters
    ----------
    control : (n, 3) float
        Control vertices, metres.
    faces : (F, k) int array or list of index lists
        The control faces (non-quads need a level of at least 1).
    level : int
        The subdivision level s >= 0.
    creases : iterable of (2,) int pairs, optional
        Control edges kept sharp.

    Returns
    -------
    (n_s, 3) float
        Points on the limit surface, metres, one per level-s vertex in its order.

    Raises
    ------
    MeshError
        For control vertices of another shape, or as `limit_matrix` does.
    """
    control = np.asarray(control, dtype=np.float64)
    if control.ndim != 2 or control.shape[1] != 3:
        raise MeshError(f"Expected control vertices of shape (n, 3), got {control.shape}")
    return limit_matrix(len(control), faces, level, creases) @ control


def limit_of_level(sub: Subdivision, vertices: np.ndarray,
                   creases: Iterable[Sequence[int]] | None = None) -> np.ndarray:
    """(n_s, 3) the limit points of a level's vertices (n_s, 3) metres, `sub` the level's
    `Subdivision` (its last step carries the level's creases; at level 0 `creases`, the
    control creases, are used)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.shape != (sub.matrix.shape[0], 3):
        raise MeshError(f"Expected level-{sub.level} vertices of shape "
                        f"({sub.matrix.shape[0]}, 3), got {vertices.shape}")
    level_creases = creases if sub.level == 0 else sub.steps[-1].creases
    return limit_operator(len(vertices), sub.faces, level_creases) @ vertices
