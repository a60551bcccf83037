"""Hard geometric guarantees of a fitted surface, checked after the fit.

A fit minimises an energy; nothing in that energy forbids a surface that crosses itself, folds
back, dips under the floor or cuts into a body between its vertices. These checks say whether
the surface (the limit surface on the level-s quads, as `surface.*` holds it) does any of that:

* self-intersections: pairs of its triangles (each quad split along its 0-2 diagonal) that share
  no vertex and yet cross, by the exact separating-axis test of `solver.mesh.self_intersections`;
* folds: the angle between the normals of two quads that share an edge (edges given as sharp,
  the creases, are left out: a crease is a fold by design);
* the floor: the lowest surface point (the mesh is flat between its vertices, so the lowest
  vertex), against the plane y = floor (Y up);
* dense penetration: the deepest point of the surface inside any body, over a grid of 15
  barycentric samples on every triangle (its corners, three points on each edge, three inside),
  so a face cutting into a body between its vertices is seen. Inside is a fast winding number
  above one half; the depth is the exact distance to the closed skin.

Lengths in metres, angles in degrees (a report's figures).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from solver.mesh import box_pairs, meeting_pairs, quad_triangles, self_intersections

FOLD_LIMIT_DEG = 60.0  # neighbouring faces further apart than this are a fold
SLIT_LIMIT_DEG = 150.0  # faces across a crease further apart than this fold back on each
# other: a slit (30 degrees between the faces or less) that no upholstery or solid follows
FLOOR_TOLERANCE = 1e-3  # m the surface may sit below the floor before it counts as under it
PENETRATION_TOLERANCE = 1e-3  # m a body may be cut beyond the margin
SAMPLE_DIVISIONS = 4  # each triangle's edges in this many parts: 15 barycentric samples
FINER_DIVISIONS = 16  # the grid a triangle is searched on again where a cut past the margin
# could lie between its samples (`penetration_between_samples`)
ONE_TO_ONE_MARGIN = 1e-9  # relative: how clearly `one_to_one_over_plane` must see its signs
ONE_TO_ONE_TURNS = 16  # times it may turn its plane towards the triangle facing it least
ONE_TO_ONE_NUDGE = 0.05  # how far each such triangle is turned to face the plane (a cosine)
CROSSING_LEAF = 512  # triangles: a piece this small is searched for crossings pair by pair
PIECES_KEPT = 256  # pieces whose topology `crossing_pairs` keeps for its caller


def quad_normals(vertices: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of quads, the cross product of their diagonals (v2 - v0) x (v3 - v1)
    (zero for a degenerate quad)."""
    v, q = np.asarray(vertices, dtype=np.float64), np.asarray(quads, dtype=np.int64)
    n = np.cross(v[q[:, 2]] - v[q[:, 0]], v[q[:, 3]] - v[q[:, 1]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def neighbour_faces(quads: np.ndarray, sharp_edges: np.ndarray | None = None,
                    across: bool = False) -> np.ndarray:
    """(E, 2) the faces that share each edge, sharp edges left out (`across`: those on sharp
    edges alone): one pair on an edge of two faces (a manifold surface's every inner edge),
    consecutive pairs in face order on one of more (three faces on an edge give two pairs).

    Parameters
    ----------
    quads : (F, k) int
        Quads (k = 4), or triangles (k = 3), or any faces of k corners.
    sharp_edges : (K, 2) int, optional
        Edges (vertex pairs, either order) left out: creases, folds by design.
    """
    q = np.asarray(quads, dtype=np.int64)
    edges = np.sort(np.stack([q, np.roll(q, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    face = np.repeat(np.arange(len(q)), q.shape[1])
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, face = edges[order], face[order]
    keep = np.flatnonzero(np.all(edges[1:] == edges[:-1], axis=1))
    if sharp_edges is not None and len(sharp_edges):
        n = np.int64(edges.max() + 1) if len(edges) else np.int64(1)
        sharp = np.sort(np.asarray(sharp_edges, dtype=np.int64).reshape(-1, 2), axis=1)
        sharp = sharp[sharp.max(axis=1) < n]
        on = np.isin(edges[keep, 0] * n + edges[keep, 1], sharp[:, 0] * n + sharp[:, 1])
        keep = keep[on if across else ~on]
    elif across:
        keep = keep[:0]
    return np.stack([face[keep], face[keep + 1]], axis=1)


def fold_angles(vertices: np.ndarray, quads: np.ndarray,
                sharp_edges: np.ndarray | None = None, across: bool = False) -> np.ndarray:
    """(E,) degrees in [0, 180] between the normals of the two quads on each interior edge
    (`neighbour_faces`: vertices (V, 3), quads (F, 4), sharp edges (K, 2) left out; `across`:
    on the sharp edges alone)."""
    pairs = neighbour_faces(quads, sharp_edges, across)
    normals = quad_normals(vertices, quads)
    dots = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]])
    return np.degrees(np.arccos(np.clip(dots, -1.0, 1.0)))


def disk_border(quads: np.ndarray, n: int) -> np.ndarray | None:
    """The border of a quad mesh of n vertices as one loop of vertex indices (K,), when the
    mesh is a topological disk: every vertex used, connected, consistently oriented (each edge
    on one quad, or on two that run it opposite ways), one border loop and Euler characteristic
    V - E + F = 1. None for any other mesh."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    q = np.asarray(quads, dtype=np.int64)
    edges = np.stack([q, np.roll(q, -1, axis=1)], axis=2).reshape(-1, 2)  # as each quad runs it
    _, inverse, counts = np.unique(edges.min(axis=1) * n + edges.max(axis=1),
                                   return_inverse=True, return_counts=True)
    used = np.zeros(n, dtype=bool)
    used[q.ravel()] = True
    if q.min(initial=0) < 0 or counts.max(initial=0) > 2 or not used.all() or \
            n - len(counts) + len(q) != 1 or \
            len(np.unique(edges[:, 0] * n + edges[:, 1])) < len(edges):
        return None
    border = edges[counts[inverse] == 1]
    after = np.full(n, -1)
    after[border[:, 0]] = border[:, 1]
    if not len(border) or np.bincount(border[:, 0], minlength=n).max() > 1:
        return None
    loop = [int(border[0, 0])]
    while len(loop) <= len(border) and after[loop[-1]] not in (-1, loop[0]):
        loop.append(int(after[loop[-1]]))
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    if len(loop) != len(border) or connected_components(graph, directed=False)[0] != 1:
        return None
    return np.array(loop)


def one_to_one_over_plane(vertices: np.ndarray, triangles: np.ndarray, border: np.ndarray
                          ) -> bool:
    """Whether a triangulated disk (`disk_border`'s `border` loop) projects one-to-one onto
    a plane, and so cannot cross itself: every triangle faces one way (its projection keeps its
    orientation) and the projected border is a simple polygon (no two of its edges meet,
    neighbours but at their corner), each by a margin. A map of a disk that keeps every
    triangle's orientation and is one-to-one on the border is one-to-one (the degree argument),
    so triangles that share no corner lie apart. The way is sought from the disk's vector area,
    turned towards the triangle that faces it least (up to ONE_TO_ONE_TURNS times: a seat's
    flank may stand past upright). False says nothing.

    Parameters
    ----------
    vertices : (V, 3) float
    triangles : (T, 3) int
        The disk's triangles, consistently oriented.
    border : (K,) int
        Its border loop.
    """
    from solver.mesh import face_cross

    v = np.asarray(vertices, dtype=np.float64)
    cross = face_cross(v, triangles)
    unit = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)
    up = cross.sum(axis=0)
    for _ in range(ONE_TO_ONE_TURNS + 1):
        if not np.linalg.norm(up) > 0:
            return False
        up = up / np.linalg.norm(up)
        facing = unit @ up
        worst = int(np.argmin(facing))
        if facing[worst] > ONE_TO_ONE_MARGIN:
            break
        up = up + (ONE_TO_ONE_NUDGE - facing[worst]) * unit[worst]  # it faces up by the nudge
    else:
        return False
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    p = v[border] @ np.stack([side, np.cross(up, side)], axis=1)  # (K, 2) the border, flat
    a, run = p, np.roll(p, -1, axis=0) - p  # edge k runs from p[k] by run[k]
    margin = ONE_TO_ONE_MARGIN * np.max(np.einsum("ij,ij->i", run, run))  # m^2, as `turn`

    def turn(u: np.ndarray, w: np.ndarray) -> np.ndarray:
        return u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]

    after = np.roll(run, -1, axis=0)  # neighbours may not fold back onto each other
    if np.any((np.abs(turn(run, after)) <= margin) & (np.einsum("ij,ij->i", run, after) < 0)):
        return False
    # the other pairs whose extents along the plane's first axis overlap (a sweep)
    lo, hi = np.minimum(a, a + run), np.maximum(a, a + run)
    order = np.argsort(lo[:, 0], kind="stable")
    count = np.searchsorted(lo[order, 0], hi[order, 0], side="right") - np.arange(len(p)) - 1
    i = np.repeat(np.arange(len(p)), count)
    j = i + 1 + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    i, j = order[i], order[j]
    gap = np.abs(i - j)
    apart = (gap == 1) | (gap == len(p) - 1)  # neighbours (the loop's last and first too)
    apart |= (lo[i, 1] > hi[j, 1]) | (lo[j, 1] > hi[i, 1])
    i, j = i[~apart], j[~apart]

    def beside(k: np.ndarray, other: np.ndarray) -> np.ndarray:
        """Whether both ends of edge `other` lie on one side of edge k's line."""
        s, t = turn(run[k], a[other] - a[k]), turn(run[k], a[other] + run[other] - a[k])
        return ((s > margin) & (t > margin)) | ((s < -margin) & (t < -margin))

    return bool(np.all(beside(i, j) | beside(j, i)))


def crossing_pairs(vertices: np.ndarray, triangles: np.ndarray, whole_tried: bool = False,
                   pieces: dict | None = None) -> np.ndarray:
    """(P, 2) the pairs of triangles that share no vertex and yet meet, as
    `solver.mesh.self_intersections` finds them (the same pairs, i < j, in another order),
    quicker on a surface that is mostly a height field over some plane: a piece that is a disk
    and one-to-one over a plane (`one_to_one_over_plane`) cannot cross itself, so the surface is
    cut in two (at the median of its triangles' centres along its longest side) until each piece
    is such a disk or has at most CROSSING_LEAF triangles (searched pair by pair), and only the
    triangles of each half that reach into the other half's box are tried against each other.
    `whole_tried`: the caller knows the whole surface is no such disk (it is not tried again).
    `pieces`: a dict the caller keeps for one triangulation, where each piece's topology (its
    vertices, its triangles over them and its border, which depend on its triangles alone) is
    kept between calls: the surfaces of one fit, and of its warm refits, are mostly cut into
    the same pieces (at most PIECES_KEPT are kept).

    Parameters
    ----------
    vertices : (V, 3) float
    triangles : (F, 3) int
        Consistently oriented (a piece of another orientation is never certified).
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    corners = v[t]
    lo, hi, centre = corners.min(axis=1), corners.max(axis=1), corners.mean(axis=1)
    found = [np.zeros((0, 2), dtype=np.int64)]

    def among(ids: np.ndarray, other: np.ndarray | None = None) -> None:
        """The meeting pairs within ids, or (other given) between ids and other."""
        both = ids if other is None else np.concatenate([ids, other])
        pairs = box_pairs(lo[both], hi[both])
        if other is not None:
            pairs = pairs[(pairs[:, 0] < len(ids)) != (pairs[:, 1] < len(ids))]
        hits = both[meeting_pairs(corners[both], t[both], pairs)]
        found.append(np.sort(hits, axis=1))

    def disk_over_plane(ids: np.ndarray) -> bool:
        key = ids.tobytes()
        known = None if pieces is None else pieces.get(key)
        if known is None:
            used, local = np.unique(t[ids], return_inverse=True)
            local = local.reshape(-1, 3)
            known = (used, local, disk_border(local, len(used)))
            if pieces is not None:
                if len(pieces) >= PIECES_KEPT:
                    pieces.clear()
                pieces[key] = known
        used, local, border = known
        return border is not None and one_to_one_over_plane(v[used], local, border)

    stack = [(np.arange(len(t)), whole_tried)]
    while stack:
        ids, tried = stack.pop()
        if len(ids) <= CROSSING_LEAF:
            among(ids)
            continue
        if not tried and disk_over_plane(ids):
            continue
        axis = int(np.argmax(hi[ids].max(axis=0) - lo[ids].min(axis=0)))
        first = centre[ids, axis] <= np.median(centre[ids, axis])
        if first.all() or not first.any():  # (every centre on the median: no cut there)
            among(ids)
            continue
        a, b = ids[first], ids[~first]
        # the triangles of each half whose boxes reach into the other half's box
        a_near = a[np.all((lo[a] <= hi[b].max(axis=0)) & (hi[a] >= lo[b].min(axis=0)), axis=1)]
        b_near = b[np.all((lo[b] <= hi[a].max(axis=0)) & (hi[b] >= lo[a].min(axis=0)), axis=1)]
        if len(a_near) and len(b_near):
            among(a_near, b_near)
        stack += [(a, False), (b, False)]
    pairs = np.concatenate(found)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def barycentric_weights(divisions: int = SAMPLE_DIVISIONS) -> np.ndarray:
    """((d + 1)(d + 2) / 2, 3) the barycentric grid with each triangle edge in `divisions` (d)
    parts, corners included."""
    i, j = np.meshgrid(np.arange(divisions + 1), np.arange(divisions + 1), indexing="ij")
    inside = (i + j) <= divisions
    a, b = i[inside] / divisions, j[inside] / divisions
    return np.stack([1.0 - a - b, a, b], axis=1)


def barycentric_samples(vertices: np.ndarray, triangles: np.ndarray,
                        divisions: int = SAMPLE_DIVISIONS) -> np.ndarray:
    """(F * (d + 1)(d + 2) / 2, 3) points on every triangle at `barycentric_weights`."""
    weights = barycentric_weights(divisions)
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    return np.einsum("sk,fkd->fsd", weights, corners).reshape(-1, 3)


def penetration_dense(points: np.ndarray, bodies: Sequence[tuple[np.ndarray, np.ndarray]]
                      ) -> float:
    """Largest depth (m) of `points` (P, 3) inside any of the closed bodies ((V, 3) vertices,
    (T, 3) triangles each), 0 if none is inside: the evaluation's `penetration_depth` of the
    points in each body's bounding box."""
    from solver.contact.evaluate import penetration_depth

    deepest = 0.0
    for body_vertices, body_triangles in bodies:
        bv = np.asarray(body_vertices, dtype=np.float64)
        lo, hi = bv.min(axis=0), bv.max(axis=0)
        near = points[np.all((points >= lo) & (points <= hi), axis=1)]
        if len(near):
            deepest = max(deepest, penetration_depth(near, bv, body_triangles))
    return deepest


def sample_spacing(vertices: np.ndarray, triangles: np.ndarray,
                   divisions: int = SAMPLE_DIVISIONS) -> np.ndarray:
    """(F,) each triangle's longest edge over `divisions`: every point of the triangle lies
    within that of one of its `barycentric_samples`."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    return np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1) / divisions


def penetration_between_samples(vertices: np.ndarray, triangles: np.ndarray,
                                bodies: Sequence[tuple[np.ndarray, np.ndarray]], limit: float,
                                divisions: int = SAMPLE_DIVISIONS, *,
                                samples: np.ndarray | None = None,
                                spacing: np.ndarray | None = None) -> float:
    """The deepest cut (m) over a grid `FINER_DIVISIONS` parts to an edge of the triangles
    that could hold a point deeper than `limit` in a body between their samples on the
    `divisions` grid (0 if none could). Measured on the side-lying body of 2026-12-07 (the
    Axis standing pose turned onto its side, its lounger): 30.5 mm on the 15 samples and
    32.0 mm between them, past the 30 mm margin and its 1 mm tolerance.

    Every point of a triangle lies within h (its longest edge over `divisions`) of a sample,
    and a point's depth in a body is at most its distance to the nearest skin vertex (which
    changes no faster than the point moves), so only a triangle with a sample whose distance
    plus h passes `limit` can hold a deeper point; and a point inside a body is no deeper than
    its distance to any point outside, so a triangle with every sample outside cannot when h
    is under `limit`. `samples` and `spacing`: the triangles' `barycentric_samples` and
    `sample_spacing` on the `divisions` grid, when the caller has them."""
    from solver.contact.skins import body_winding, vertex_tree

    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if not len(t):
        return 0.0
    h = sample_spacing(v, t, divisions) if spacing is None else spacing
    per = len(barycentric_weights(divisions))
    samples = barycentric_samples(v, t, divisions) if samples is None else samples
    deepest = 0.0
    for body_vertices, body_triangles in bodies:
        bv = np.asarray(body_vertices, dtype=np.float64)
        bt = np.asarray(body_triangles, dtype=np.int64)
        lo, hi = bv.min(axis=0), bv.max(axis=0)
        near = np.flatnonzero(np.all((samples >= lo) & (samples <= hi), axis=1))
        if not len(near):
            continue
        bound, _ = vertex_tree(bv).query(samples[near])
        owner = near // per
        reach = bound + h[owner] > limit
        near, owner = near[reach], owner[reach]
        inside = body_winding(bv, bt).winding_number(samples[near]) > 0.5 if len(near) else \
            np.zeros(0, dtype=bool)
        wanted = np.unique(np.concatenate([owner[inside], np.flatnonzero(h >= limit)]))
        if len(wanted):
            deepest = max(deepest, penetration_dense(
                barycentric_samples(v, t[wanted], FINER_DIVISIONS), [(bv, bt)]))
    return deepest


def surface_guarantees(vertices: np.ndarray, quads: np.ndarray,
                       bodies: Sequence[tuple[np.ndarray, np.ndarray]], margin: float,
                       floor: float | None = 0.0, *, sharp_edges: np.ndarray | None = None,
                       divisions: int = SAMPLE_DIVISIONS) -> dict:
    """The surface's geometric guarantees, as a JSON-ready dict.

    Parameters
    ----------
    vertices : (V, 3) float
        The surface's vertices, metres, Y up (the limit points of the level-s quads).
    quads : (F, 4) int
        Its quads.
    bodies : sequence of ((Vb, 3) float, (Tb, 3) int)
        The posed bodies' closed skins, metres.
    margin : float
        Metres the surface may sink into a body.
    floor : float or None, default 0.0
        The floor's height y (m); None: no floor to stay above.
    sharp_edges : (K, 2) int, optional
        The surface's sharp edges (vertex pairs), left out of the fold angles.
    divisions : int, default 4
        Each triangle's edges in this many parts for the penetration samples.

    Returns
    -------
    dict
        ``self_intersections`` (int: crossing pairs of triangles that share no vertex),
        ``max_fold_deg`` (float: largest angle between neighbouring quads' normals), ``folds``
        (int: neighbouring pairs over `FOLD_LIMIT_DEG`; sharp edges left out),
        ``max_crease_deg`` (float: the same across the sharp edges alone) and ``slits`` (int:
        pairs across them over `SLIT_LIMIT_DEG`), ``min_height_m`` (float),
        ``below_floor`` (bool: lower than `floor` by more than `FLOOR_TOLERANCE`),
        ``max_penetration_dense_m`` (float), ``margin_m``, ``floor_m`` and ``ok`` (bool: no
        crossing, no fold, no slit, not below the floor, penetration within the margin plus
        `PENETRATION_TOLERANCE`).

    Raises
    ------
    ValueError
        If the shapes are not (V, 3) and (F, 4), or the margin is negative.
    """
    v = np.asarray(vertices, dtype=np.float64)
    q = np.asarray(quads, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f"Expected vertices (V, 3) and quads (F, 4), got {v.shape} and "
                         f"{q.shape}")
    if not margin >= 0:
        raise ValueError(f"Expected a margin >= 0 metres, got {margin}")
    triangles = quad_triangles(q)
    crossings = len(self_intersections(v, triangles))
    angles = fold_angles(v, q, sharp_edges)
    max_fold = float(angles.max()) if len(angles) else 0.0
    folds = int(np.sum(angles > FOLD_LIMIT_DEG))
    creased = fold_angles(v, q, sharp_edges, across=True)
    max_crease = float(creased.max()) if len(creased) else 0.0
    slits = int(np.sum(creased > SLIT_LIMIT_DEG))
    min_height = float(v[:, 1].min())
    below = floor is not None and min_height < floor - FLOOR_TOLERANCE
    samples = barycentric_samples(v, triangles, divisions)
    depth = penetration_dense(samples, bodies)
    limit = margin + PENETRATION_TOLERANCE
    # a point's depth changes no faster than it moves: only where the samples' depth plus
    # their spacing could pass the bar is the surface searched between its samples
    spacing = sample_spacing(v, triangles, divisions)
    if depth + float(spacing.max(initial=0.0)) > limit:
        depth = max(depth, penetration_between_samples(v, triangles, bodies, limit, divisions,
                                                       samples=samples, spacing=spacing))
    ok = crossings == 0 and folds == 0 and slits == 0 and not below and depth <= limit
    return {"self_intersections": int(crossings), "max_fold_deg": max_fold, "folds": folds,
            "max_crease_deg": max_crease, "slits": slits,
            "min_height_m": min_height, "below_floor": bool(below),
            "max_penetration_dense_m": depth, "margin_m": float(margin),
            "floor_m": None if floor is None else float(floor), "ok": bool(ok)}
