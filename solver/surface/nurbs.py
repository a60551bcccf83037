"""The exact limit surface of a regular quad grid as a uniform bicubic B-spline (NURBS).

On a regular quad grid the Catmull-Clark limit surface is the uniform bicubic B-spline of the
control points. Our boundary rule (boundary vertices (a + 6 v + b) / 8, boundary edges at their
midpoints, corners kept) is that B-spline with one row of phantom control points around the net,
each the mirror of its inner neighbour through the boundary point: P_-1 = 2 P_0 - P_1 along
either direction (corners: 4 P_00 - 2 P_10 - 2 P_01 + P_11). Regular Catmull-Clark steps on the
extended net reproduce both boundary rules exactly and keep the phantoms' relation, so the
B-spline of the extended net is our limit surface, boundary curves included: each is the cubic
B-spline of the boundary control points, ending at the corners.

Parameters: control point (i, j) of the grid sits at (u, v) = (i, j); span [i, i + 1] x [j, j + 1]
is control quad (i, j); the level-s vertex (i, j) of the grid is at (i, j) / 2^s. Knots follow
Rhino's convention (no end knots beyond the degree: N + 2 knots for N control points).

A control mesh with creases, or one that is not a grid, has no single B-spline here:
`grid_layout` says so by returning None.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.surface.subdivision import MeshError, Subdivision, _as_faces


@dataclass(frozen=True, eq=False)
class BSplineSurface:
    """A non-rational uniform B-spline surface of degree 3 in both directions.

    points : (Nu, Nv, 3) float, control points (metres), phantoms included.
    knots_u : (Nu + 2,) float; knots_v : (Nv + 2,) float (Rhino's knot convention).
    degree : 3.
    """

    points: np.ndarray
    knots_u: np.ndarray
    knots_v: np.ndarray
    degree: int = 3

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((u0, u1), (v0, v1)), the parameter rectangle the surface covers."""
        d = self.degree
        return ((float(self.knots_u[d - 1]), float(self.knots_u[-d])),
                (float(self.knots_v[d - 1]), float(self.knots_v[-d])))

    def evaluate(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(..., 3) points at parameters u, v (arrays of one shape, inside `domain`)."""
        u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        bu = uniform_cubic_basis(u.ravel(), self.knots_u)
        bv = uniform_cubic_basis(v.ravel(), self.knots_v)
        pts = np.einsum("ki,ijc,kj->kc", bu, self.points, bv)
        return pts.reshape(u.shape + (3,))


def uniform_cubic_basis(t: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(K, N) the cubic B-spline basis functions of N control points on unit-spaced knots (N + 2
    of them, Rhino's convention) at parameters t (K,) in [knots[2], knots[-3]]: on span m
    (between knots m + 2 and m + 3) at local s in [0, 1], functions m..m+3 are
    (1 - s)^3 / 6, (3 s^3 - 6 s^2 + 4) / 6, (-3 s^3 + 3 s^2 + 3 s + 1) / 6 and s^3 / 6; the
    last span is closed on the right."""
    knots = np.asarray(knots, dtype=float)
    count = len(knots) - 2
    if count < 4 or not np.allclose(np.diff(knots), 1.0):
        raise MeshError(f"Expected at least 6 unit-spaced knots, got {knots.tolist()}")
    x = np.asarray(t, dtype=float) - knots[2]
    span = np.clip(np.floor(x), 0, count - 4).astype(np.int64)
    s = x - span
    weights = np.stack([(1 - s) ** 3, 3 * s**3 - 6 * s**2 + 4, -3 * s**3 + 3 * s**2 + 3 * s + 1,
                        s**3], axis=1) / 6
    basis = np.zeros((len(x), count))
    np.put_along_axis(basis, span[:, None] + np.arange(4), weights, axis=1)
    return basis


def grid_layout(n: int, faces, creases=None) -> np.ndarray | None:
    """The (Nu, Nv) grid of vertex indices of a control mesh that is a regular quad grid.

    A grid here: every face a quad, no crease, one rectangular net of (Nu - 1) x (Nv - 1)
    quads covering every vertex once. The layout is oriented so that quad (i, j) is
    ``(G[i, j], G[i + 1, j], G[i + 1, j + 1], G[i, j + 1])`` up to a cyclic shift, so that the
    B-spline's normal (dS/du x dS/dv) points the way the faces do.

    Parameters
    ----------
    n : int
        Number of vertices.
    faces : (F, k) int array or list of index lists
        The control faces.
    creases : iterable of (2,) int pairs, optional
        Sharp edges; any crease makes the answer None.

    Returns
    -------
    (Nu, Nv) int array, or None if the mesh is not such a grid.
    """
    arr, sizes = _as_faces(faces, n)
    if (sizes != 4).any() or arr.shape[1] != 4 or (creases is not None and len(list(creases))):
        return None
    by_edge: dict[tuple[int, int], np.ndarray] = {}
    for quad in arr:
        for k in range(4):
            by_edge[(int(quad[k]), int(quad[(k + 1) % 4]))] = np.roll(quad, -k)
    if len(by_edge) != 4 * len(arr):
        return None  # a directed edge twice: faces wound inconsistently
    faces_of = np.bincount(arr.ravel(), minlength=n)
    corners = np.flatnonzero(faces_of == 1)
    if len(corners) != 4 or (faces_of == 0).any():
        return None
    first = arr[np.flatnonzero((arr == corners[0]).any(axis=1))[0]]
    strip = [np.roll(first, -int(np.flatnonzero(first == corners[0])[0]))]
    while len(strip) <= len(arr):  # along u: the quad across edge (b, c)
        q = strip[-1]
        nxt = by_edge.get((int(q[2]), int(q[1])))
        if nxt is None:
            break
        strip.append(np.roll(nxt, -1))  # (b, b', c', c) from (c, b, b', c')
    strips = [strip]
    while len(strips) <= len(arr):  # along v: the quad across edge (c, d)
        above = [by_edge.get((int(q[3]), int(q[2]))) for q in strips[-1]]
        if any(a is None for a in above):
            if not all(a is None for a in above):
                return None
            break
        strips.append(above)
    quads = np.array(strips)  # (Nv - 1, Nu - 1, 4), each (G00, G10, G11, G01)
    nv, nu = quads.shape[0] + 1, quads.shape[1] + 1
    grid = np.empty((nu, nv), dtype=np.int64)
    grid[:-1, :-1] = quads[:, :, 0].T
    grid[-1, :-1] = quads[:, -1, 1]
    grid[-1, -1] = quads[-1, -1, 2]
    grid[:-1, -1] = quads[-1, :, 3]
    expect = np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]], axis=-1)
    if quads.shape[0] * quads.shape[1] != len(arr) or len(np.unique(grid)) != n or \
            grid.size != n or not np.array_equal(expect, quads.transpose(1, 0, 2)):
        return None
    return grid


def bspline_of_grid(control: np.ndarray, grid: np.ndarray) -> BSplineSurface:
    """The exact limit surface of a regular grid control net as a uniform bicubic B-spline.

    Parameters
    ----------
    control : (n, 3) float
        Control vertices, metres.
    grid : (Nu, Nv) int
        Their layout, from `grid_layout` (each side at least 2).

    Returns
    -------
    BSplineSurface
        (Nu + 2) x (Nv + 2) control points (the phantom ring added), uniform knots, domain
        [0, Nu - 1] x [0, Nv - 1]: the control point (i, j) of the grid at (u, v) = (i, j).

    Raises
    ------
    MeshError
        If the grid is smaller than 2 x 2 or indexes outside the control vertices.
    """
    control = np.asarray(control, dtype=np.float64)
    grid = np.asarray(grid)
    if grid.ndim != 2 or min(grid.shape) < 2:
        raise MeshError(f"Expected a grid layout of at least 2 x 2 vertices, got {grid.shape}")
    if control.ndim != 2 or control.shape[1] != 3 or grid.min() < 0 or \
            grid.max() >= len(control):
        raise MeshError(f"Expected control vertices (n, 3) covering the grid's indices, got "
                        f"{control.shape} for indices up to {grid.max()}")
    net = control[grid]
    net = np.concatenate([2 * net[:1] - net[1:2], net, 2 * net[-1:] - net[-2:-1]], axis=0)
    net = np.concatenate([2 * net[:, :1] - net[:, 1:2], net, 2 * net[:, -1:] - net[:, -2:-1]],
                         axis=1)
    nu, nv = grid.shape
    knots_u = np.arange(-2.0, nu + 2.0)
    knots_v = np.arange(-2.0, nv + 2.0)
    return BSplineSurface(net, knots_u, knots_v)


def grid_patches(n: int, faces, creases=None) -> list[np.ndarray] | None:
    """The grid layouts of the regular patches of a grid control net cut by full crease lines.

    A crease running the whole way along a grid line, from boundary to boundary, makes the two
    sides independent: its vertices follow the crease's cubic B-spline, its ends and crossings
    are corners, exactly the boundary rule of each side. So each patch between such lines is a
    grid whose limit surface is `bspline_of_grid` of its own vertices.

    Parameters
    ----------
    n : int
        Number of vertices.
    faces : (F, 4) int
        The control quads.
    creases : iterable of (2,) int pairs, optional
        Sharp edges.

    Returns
    -------
    list of (Nu_k, Nv_k) int arrays (the whole grid when there is no crease), or None when the
    mesh is no grid or a crease does not run along a whole grid line.
    """
    grid = grid_layout(n, faces)
    if grid is None:
        return None
    pairs = [] if creases is None else [tuple(sorted(map(int, c))) for c in creases]
    along_u = {tuple(sorted(e)): j for j in range(grid.shape[1])
               for e in zip(grid[:-1, j], grid[1:, j])}  # edges of the line v = j
    along_v = {tuple(sorted(e)): i for i in range(grid.shape[0])
               for e in zip(grid[i, :-1], grid[i, 1:])}  # edges of the line u = i
    lines_u, lines_v = {}, {}
    for pair in pairs:
        if pair in along_u:
            lines_u.setdefault(along_u[pair], set()).add(pair)
        elif pair in along_v:
            lines_v.setdefault(along_v[pair], set()).add(pair)
        else:
            raise MeshError(f"Expected creases along mesh edges, got {pair}")
    cuts_v = _full_lines(lines_u, grid.shape[0] - 1, grid.shape[1] - 1)
    cuts_u = _full_lines(lines_v, grid.shape[1] - 1, grid.shape[0] - 1)
    if cuts_u is None or cuts_v is None:
        return None
    return [grid[a:b + 1, c:d + 1] for a, b in zip(cuts_u[:-1], cuts_u[1:])
            for c, d in zip(cuts_v[:-1], cuts_v[1:])]


def _full_lines(lines: dict, edges_per_line: int, last: int) -> list[int] | None:
    """The cut positions 0, ..., last from crease lines (index -> their edges): None when an
    inner line is creased only in part (boundary lines are sharp anyway)."""
    inner = sorted(k for k in lines if 0 < k < last)
    if any(len(lines[k]) != edges_per_line for k in inner):
        return None
    return [0, *inner, last]


def subdivided_grid(grid: np.ndarray, sub: Subdivision, faces) -> np.ndarray:
    """The layout of a grid control net's level-s vertices, from the subdivision's ordering
    (vertex points, then edge points by sorted edge, then face points by face), without
    walking the fine mesh.

    Parameters
    ----------
    grid : (Nu, Nv) int
        The control net's layout (`grid_layout`).
    sub : Subdivision
        The net's subdivision to level s.
    faces : (F, 4) int
        The control quads `sub` was made from.

    Returns
    -------
    ((Nu - 1) 2^s + 1, (Nv - 1) 2^s + 1) int
        Level-s vertex indices; entry (i 2^s, j 2^s) is the control vertex grid[i, j].
    """
    grid, n, faces = np.asarray(grid), int(sub.matrix.shape[1]), np.asarray(faces)
    for step in sub.steps:
        a, b = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
        keys = np.unique(np.minimum(a, b) * n + np.maximum(a, b))
        rows, cols = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
        rows[grid], cols[grid] = np.indices(grid.shape)
        face_at = np.empty((grid.shape[0] - 1, grid.shape[1] - 1), dtype=np.int64)
        face_at[rows[faces].min(axis=1), cols[faces].min(axis=1)] = np.arange(len(faces))

        def edge_point(p, q):
            return n + np.searchsorted(keys, np.minimum(p, q) * n + np.maximum(p, q))

        fine = np.empty((2 * grid.shape[0] - 1, 2 * grid.shape[1] - 1), dtype=np.int64)
        fine[::2, ::2] = grid
        fine[1::2, ::2] = edge_point(grid[:-1], grid[1:])
        fine[::2, 1::2] = edge_point(grid[:, :-1], grid[:, 1:])
        fine[1::2, 1::2] = n + len(keys) + face_at
        grid, n, faces = fine, step.matrix.shape[0], np.asarray(step.faces)
    return grid


def regular_face_patches(n: int, faces, creases=None) -> tuple[np.ndarray, np.ndarray]:
    """The faces of any control mesh whose limit surface is one uniform bicubic B-spline
    patch, and the patch's 4 x 4 control vertices.

    A quad is regular when each of its corners is an inner vertex of four quads and no crease
    ends at it: then a Catmull-Clark step makes its four sub-quads regular too, from the
    quad's own ring of 16 control vertices only, and its limit surface is the uniform
    bicubic B-spline of that ring (whatever the mesh does further out).

    Parameters
    ----------
    n : int
        Number of vertices.
    faces : (F, k) int array or list of index lists
        The control faces, consistently wound.
    creases : iterable of (2,) int pairs, optional
        Sharp edges.

    Returns
    -------
    faces : (P,) int
        Indices of the regular faces.
    rings : (P, 4, 4) int
        Their rings: ring[i, j] is the control vertex at (u, v) = (i - 1, j - 1) of the patch
        over the face, whose corners (a, b, c, d) sit at (0, 0), (1, 0), (1, 1), (0, 1).
    """
    arr, sizes = _as_faces(faces, n)
    quad = sizes == 4
    directed: dict[tuple[int, int], int] = {}
    for f, (face, size) in enumerate(zip(arr.tolist(), sizes.tolist())):
        for k in range(size):
            directed[(face[k], face[(k + 1) % size])] = f
    inner = np.ones(n, dtype=bool)
    for a, b in directed:
        if (b, a) not in directed:
            inner[[a, b]] = False
    quads_at = np.zeros(n, dtype=np.int64)
    faces_at = np.zeros(n, dtype=np.int64)
    valid = np.arange(arr.shape[1])[None, :] < sizes[:, None]
    np.add.at(faces_at, arr[valid], 1)
    np.add.at(quads_at, arr[quad, :4].ravel(), 1)
    sharp = np.zeros(n, dtype=bool)
    for pair in [] if creases is None else creases:
        sharp[list(map(int, pair))] = True
    regular = inner & (faces_at == 4) & (quads_at == 4) & ~sharp

    def across(a: int, b: int) -> tuple[int, int]:
        """The far corners (next to a, next to b) of the quad across the edge a -> b."""
        face = arr[directed[(b, a)], :4].tolist()
        k = face.index(b)  # face runs b -> a -> x -> y
        return face[(k + 2) % 4], face[(k + 3) % 4]

    def diagonal(corner: int, one: int, other: int) -> int:
        """The corner opposite `corner` of the quad holding the edges to `one` and `other`."""
        face = arr[directed[(one, corner)], :4].tolist()
        k = face.index(corner)  # face runs one -> corner -> other -> far
        if face[(k + 1) % 4] != other:
            raise MeshError("a regular vertex's quads do not close around it")
        return face[(k + 2) % 4]

    found, rings = [], []
    for f in np.flatnonzero(quad & regular[arr[:, :4].clip(0)].all(axis=1)).tolist():
        a, b, c, d = arr[f, :4].tolist()
        ring = np.empty((4, 4), dtype=np.int64)
        ring[1, 1], ring[2, 1], ring[2, 2], ring[1, 2] = a, b, c, d
        ring[1, 0], ring[2, 0] = across(a, b)
        ring[3, 1], ring[3, 2] = across(b, c)
        ring[2, 3], ring[1, 3] = across(c, d)
        ring[0, 2], ring[0, 1] = across(d, a)
        ring[0, 0] = diagonal(a, ring[1, 0], ring[0, 1])
        ring[3, 0] = diagonal(b, ring[3, 1], ring[2, 0])
        ring[3, 3] = diagonal(c, ring[2, 3], ring[3, 2])
        ring[0, 3] = diagonal(d, ring[0, 2], ring[1, 3])
        if len(np.unique(ring)) == 16:
            found.append(f)
            rings.append(ring)
    return np.asarray(found, dtype=np.int64), np.asarray(rings, dtype=np.int64).reshape(-1, 4, 4)


def bspline_of_ring(control: np.ndarray, ring: np.ndarray) -> BSplineSurface:
    """The patch of one regular face (`regular_face_patches`): its 16 control vertices as a
    uniform bicubic B-spline over the domain [0, 1] x [0, 1]."""
    knots = np.arange(-2.0, 4.0)
    return BSplineSurface(np.asarray(control, dtype=np.float64)[np.asarray(ring)], knots,
                          knots.copy())
