"""Solids for the workshop: a fitted surface thickened into a closed, watertight, manifold
mesh, checked by libraries (trimesh, manifold3d) and written as STL or 3MF.

Inside the library a solid is in the project's frame: metres, right-handed, Y up. The files
follow the workshop's convention instead: millimetres and Z up, the point (x, y, z) written as
1000 * (x, -z, y), a proper rotation (determinant +1) of +90 degrees about X, so nothing is
mirrored. A 3MF file states its unit (``unit="millimeter"``); STL has none, and millimetres is
the convention every slicer and CAM program assumes.

Two solids are made:

* an offset shell (`thicken`): the surface, a sheet every point of which lies the thickness
  away from it on the side away from the bodies, and side walls joining the two along the
  surface's border;
* a plinth (`plinth`): the surface, its copy dropped onto the floor (y = 0), and side walls.

Where the surface bends away from the bodies more tightly than the thickness (a convex radius
under it), moving each vertex along its normal folds the offset over itself. There the
offset is trimmed as a cutter would leave it: the region within the thickness of those faces
is the union of one convex piece per face (its triangle, and the triangle moved along the
normals of the faces around its corners), merged with the rest of the shell by manifold3d,
so the underside keeps every point the thickness away from the surface and has a valley
where the two sides meet.

A piece swept along normals that turn further than 90 degrees from a nearby triangle (a bend
tighter than the thickness, or a vertex whose faces part widely) reaches through the top in
front of that triangle, even of one sharing a single corner with the piece's own (a 1 cm
solid of `reclining` stood up to 1.7 mm in front of its surface at 11 triangles). So the region
in front of the surface where the pieces reach is cut away from the merged solid (`_front`):
over each such triangle its prism along its normal, over the edges and corners where the
surface bends away the wedges and cones of normals between those prisms, each of them the
part of space nearer the front of its triangle, edge or corner than of anything else, as
far forwards as a piece reaches (and never further than half way to the surface in front).
The prisms' backs are the surface's triangles, so the top stays the surface; corners the
cut leaves a hair's breadth (under `TINY_EDGE`) in front of it are put onto it (slivers the
cut leaves on the top may still lie a tenth of a micrometre off it). `check_solid` measures
what comes out.
"""

from __future__ import annotations

import io
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture.files import write_atomic
from solver.mesh import MeshOrientationError, SurfaceMesh, enclosed_volume, face_cross, \
    face_normals, quad_triangles, self_intersections, vertex_normals
from solver.mesh import boundary_edges as mesh_boundary_edges

THICKNESS_TOLERANCE = 1e-4  # m: the offset's vertices may miss the thickness by this much
# Between vertices, flat faces cut the chords of tight bends, so the two sheets come nearer
# than the thickness there (by the sagitta, edge^2 / 8 r); they cross only at 0, and a solid
# thinner than this share of the thickness anywhere is refused.
CLEARANCE_SHARE = 0.5
Y_UP_TO_Z_UP_MM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]) * 1000.0


class SolidError(ValueError):
    """A surface that cannot be thickened as asked, or a solid that fails its checks."""


@dataclass(frozen=True, eq=False)
class Solid:
    """A closed triangle mesh: vertices (V, 3) metres, Y up; triangles (F, 3) counter-clockwise
    seen from outside. `kind` is "offset" or "plinth"; `thickness` the offset (m, None for a
    plinth); the first `n_surface` vertices are the surface's and `surface_triangles` its
    triangles over them (the solid's top); `trimmed` counts the surface triangles under which
    the offset was trimmed (see the module notes; 0 where moving every vertex along its normal
    made a sound offset, whose next `n_surface` vertices are then their offset copies)."""

    vertices: np.ndarray
    triangles: np.ndarray
    kind: str
    thickness: float | None
    n_surface: int
    surface_triangles: np.ndarray
    trimmed: int = 0


@dataclass(frozen=True)
class SolidCheck:
    """What the libraries say of a solid (see `check_solid`). Lengths m, volume m^3."""

    watertight: bool
    winding_consistent: bool
    manifold_status: str
    volume_m3: float
    folded_faces: int
    thickness_min_m: float | None
    thickness_max_m: float | None
    too_close: int
    clearance_m: float | None = None
    surface_folds: int = 0
    intersecting_pairs: int = 0
    trimmed: int = 0
    closed_in_single: bool = True
    over_surface: int = 0
    hollow_under: int = 0

    @property
    def ok(self) -> bool:
        """Closed, consistently wound, accepted by manifold3d, positive volume, no triangles
        crossing, no fold in the offset, no place nearer the surface than the thickness
        allows, nothing of it in front of the surface (`over_surface`) and no hollow right
        behind it (`hollow_under`), and still closed once
        written in single precision (STL). (A sharp fold of the surface itself,
        `surface_folds`, is named in `problem` as the likely cause.)"""
        return bool(self.watertight and self.winding_consistent and
                    self.manifold_status == "NoError" and self.volume_m3 > 0 and
                    self.folded_faces == 0 and self.too_close == 0 and
                    self.intersecting_pairs == 0 and self.closed_in_single and
                    self.over_surface == 0 and self.hollow_under == 0 and
                    (self.clearance_m is None or self.clearance_m >= CLEARANCE_SHARE *
                     self.thickness_min_m))

    def problem(self) -> str | None:
        """A sentence naming what is wrong, or None."""
        if self.ok:
            return None
        parts = []
        if self.surface_folds:
            parts.append(f"the surface itself folds sharply at {self.surface_folds} edges "
                         f"(neighbouring faces turn by more than 90 degrees)")
        if self.intersecting_pairs:
            parts.append(f"{self.intersecting_pairs} pairs of its triangles cross each other")
        if self.over_surface:
            parts.append(f"it stands in front of the surface (towards the bodies) at "
                         f"{self.over_surface} of the surface's triangles")
        if self.hollow_under:
            parts.append(f"it is hollow right behind the surface at {self.hollow_under} of the "
                         f"surface's triangles")
        if self.folded_faces:
            parts.append(f"{self.folded_faces} offset faces fold over (the surface bends "
                         f"away from the bodies more tightly than the thickness)")
        if self.too_close:
            parts.append(f"the offset comes within {self.thickness_min_m * 1000:.1f} mm of "
                         f"the surface at {self.too_close} vertices (it runs into the surface "
                         f"where the surface bends away from the bodies more tightly than "
                         f"the thickness)")
        if self.clearance_m is not None and \
                self.clearance_m < CLEARANCE_SHARE * self.thickness_min_m:
            parts.append(f"between vertices the offset comes within "
                         f"{self.clearance_m * 1000:.1f} mm of the surface")
        if not self.watertight or not self.winding_consistent:
            parts.append("the mesh is not closed and consistently wound")
        elif not self.closed_in_single:
            parts.append("written in single precision (STL, millimetres) some of its "
                         "corners fuse and it is no longer closed")
        if self.manifold_status != "NoError":
            parts.append(f"manifold3d rejects it ({self.manifold_status})")
        if self.volume_m3 <= 0 and not parts:
            parts.append(f"its volume is {self.volume_m3:.3g} m^3")
        return "; ".join(parts)


def _edges_of(triangles: np.ndarray) -> np.ndarray:
    """(3F, 2) the directed edges of triangles: every 0 -> 1, then 1 -> 2, then 2 -> 0."""
    return np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """`solver.mesh.boundary_edges`, a surface that is no orientable manifold a SolidError."""
    try:
        return mesh_boundary_edges(faces)
    except MeshOrientationError as exc:
        raise SolidError(str(exc)) from None


def _validate(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise SolidError(f"Expected finite surface vertices (N, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] not in (3, 4) or len(f) == 0 or \
            not np.issubdtype(f.dtype, np.integer):
        raise SolidError(f"Expected integer faces (F, 3) or (F, 4), got {f.shape} {f.dtype}")
    if f.min() < 0 or f.max() >= len(v):
        raise SolidError(f"Expected face indices in 0..{len(v) - 1}, got "
                         f"{int(f.min())}..{int(f.max())}")
    f = f.astype(np.int64)
    # a triangle without area has no normal to offset along (its NaN reached the trimming's
    # tree queries, which failed without naming the surface)
    tris = f if f.shape[1] == 3 else quad_triangles(f)
    flat = np.flatnonzero(np.linalg.norm(face_cross(v, tris), axis=1) <= 0.0)
    if len(flat):
        face = int(flat[0]) % len(f)  # (`quad_triangles` puts every quad's halves F apart)
        raise SolidError(f"Expected surface faces with area, got {len(flat)} triangles "
                         f"without (face {face}: corners {f[face].tolist()} at "
                         f"{np.round(v[f[face]], 6).tolist()} m)")
    return v, f


def _close(top: np.ndarray, faces: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """Triangles of the surface (as it is), its copy (reversed) and the side walls."""
    n = len(top)
    tris = faces if faces.shape[1] == 3 else quad_triangles(faces)
    border = boundary_edges(faces)
    if len(border) == 0:
        raise SolidError("Expected a surface with a border, got a closed one")
    a, b = border[:, 0], border[:, 1]
    # the surface runs a -> b, so the wall runs b -> a on top and a' -> b' below
    walls = np.concatenate([np.stack([b, a, a + n], axis=1), np.stack([b, a + n, b + n], axis=1)])
    return np.concatenate([tris, tris[:, ::-1] + n, walls])


def thicken(vertices: np.ndarray, faces: np.ndarray, thickness: float, *,
            check: bool = True, trim: bool = True) -> Solid:
    """The surface thickened away from the bodies by a constant `thickness`.

    Each vertex is copied `thickness` along minus its area-weighted unit normal (the normals
    point towards the bodies), the copy's triangles are split until their middles lie within
    3/4 `THICKNESS_TOLERANCE` of the thickness too (each new vertex put the thickness from
    the surface), and side walls close the border. Where that offset folds over,
    runs into the surface or crosses itself (the surface bends away from the bodies more
    tightly than the thickness), it is trimmed (with `trim`): see the module notes.

    Parameters
    ----------
    vertices : (N, 3) float
        The surface, metres, Y up.
    faces : (F, 4) or (F, 3) int
        Its quads or triangles, counter-clockwise seen from the bodies.
    thickness : float
        Metres, > 0.
    check : bool, default True
        Run `check_solid` and raise if it fails.
    trim : bool, default True
        Split and trim the offset as above (False: return the vertices' copies as they are,
        sound or not).

    Returns
    -------
    Solid

    Raises
    ------
    SolidError
        On bad input, or (with `check`) when the solid fails its checks.
    """
    v, f = _validate(vertices, faces)
    if not np.isfinite(thickness) or thickness <= 0:
        raise SolidError(f"Expected a thickness > 0 m, got {thickness}")
    t = float(thickness)
    tris = f if f.shape[1] == 3 else quad_triangles(f)
    offset = _true_offset(v, tris, v - t * vertex_normals(v, tris), t)
    plain = Solid(np.concatenate([v, offset]), _close(v, f, offset), "offset", t, len(v), tris)
    unsound = _unsound_faces(plain) if trim else None
    if unsound is None:
        solid = plain
    elif unsound.any():
        solid = _trimmed(v, tris, offset, t, unsound)
    else:
        solid = Solid(*_offset_shell(v, tris, offset, t), "offset", t, len(v), tris)
    if check:
        _raise_if_bad(solid)
    return solid


MAX_SPLITS = 1  # times the offset sheet's triangles may be split into four
MAX_SHEET = 400_000  # triangles of the offset sheet beyond which it is not split (memory)


def _offset_shell(v: np.ndarray, tris: np.ndarray, offset: np.ndarray,
                  t: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a closed shell: the surface (`v`, `tris`), its offset sheet
    (`offset`, the copies of `v`, then the vertices splitting adds) and walls along the
    border. The sheet's triangles are split into four while a middle lies further than 3/4
    `THICKNESS_TOLERANCE` from the thickness (the chords of a curved sheet), each new vertex
    put `t` from the surface."""
    n = len(v)
    mesh = SurfaceMesh.from_triangles(v, tris)
    bottom, sheet = offset.copy(), np.asarray(tris, dtype=np.int64)
    chains = [list(edge) for edge in boundary_edges(tris).tolist()]  # along the border
    if not chains:
        raise SolidError("Expected a surface with a border, got a closed one")
    for _ in range(MAX_SPLITS):
        if 4 * len(sheet) > MAX_SHEET:
            break
        middles = bottom[sheet].mean(axis=1)
        if np.abs(mesh.closest(middles)[0] - t).max() <= 0.75 * THICKNESS_TOLERANCE:
            break
        edges = _edges_of(sheet)
        pairs, inverse = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True)
        halves = len(bottom) + np.arange(len(pairs))
        bottom = np.concatenate([bottom, _at_thickness(
            mesh, 0.5 * (bottom[pairs[:, 0]] + bottom[pairs[:, 1]]), t)])
        m = halves[inverse.ravel()].reshape(3, -1).T  # halves of edges 01, 12, 20
        a, b, c = sheet.T
        sheet = np.concatenate([np.stack([a, m[:, 0], m[:, 2]], axis=1),
                                np.stack([m[:, 0], b, m[:, 1]], axis=1),
                                np.stack([m[:, 2], m[:, 1], c], axis=1), m])
        half = dict(zip(map(tuple, pairs.tolist()), halves.tolist()))
        chains = [chain[:1] + [x for p, q in zip(chain[:-1], chain[1:])
                               for x in (half[(min(p, q), max(p, q))], q)]
                  for chain in chains]
    walls = []
    for chain in chains:  # the surface runs a -> b: the wall fans from b over the copies
        a, b = chain[0], chain[-1]
        walls.append([b, a, n + a])
        walls.extend([b, n + p, n + q] for p, q in zip(chain[:-1], chain[1:]))
    triangles = np.concatenate([tris, sheet[:, ::-1] + n, np.asarray(walls, dtype=np.int64)])
    return np.concatenate([v, bottom]), triangles


def _at_thickness(mesh: SurfaceMesh, points: np.ndarray, t: float) -> np.ndarray:
    """Points moved along the line from their closest surface point to `t` from it."""
    dist, _, _, _, closest = mesh.closest(points)
    away = (points - closest) / np.maximum(dist, 1e-300)[:, None]
    return closest + t * away


def _unsound_faces(solid: Solid, rings: int = 2) -> np.ndarray:
    """(F,) bool: the surface triangles whose part of a plain offset is unsound (its offset
    folds over, a corner's copy lies nearer the surface than the thickness allows, or its
    offset or wall crosses another triangle), grown by `rings` rings of neighbours and closed
    so that the sound rest has no two triangles meeting at a corner only."""
    n, tris, t = solid.n_surface, solid.surface_triangles, solid.thickness
    top, bottom = solid.vertices[:n], solid.vertices[n:]
    nf = len(tris)
    bad = np.einsum("ij,ij->i", face_normals(top, tris), face_normals(bottom, tris)) <= 0
    mesh = SurfaceMesh.from_triangles(top, tris)
    near = mesh.closest(bottom)[0] < t - THICKNESS_TOLERANCE
    bad |= near[tris].any(axis=1)
    # a copy's middle nearer than its chord explains (where the copies' directions part by an
    # angle a, a chord of the thickness's sphere lies t (1 - cos a/2) inside) comes near
    # another part of the surface
    directions = (top - bottom) / t
    spread = np.stack([np.einsum("ij,ij->i", directions[tris[:, i]], directions[tris[:, j]])
                       for i, j in ((0, 1), (1, 2), (2, 0))], axis=1).min(axis=1)
    chord = t * (1.0 - np.sqrt(np.clip(0.5 * (1.0 + spread), 0.0, 1.0)))
    middle = mesh.closest(bottom[tris].mean(axis=1))[0]
    bad |= t - middle > 2.0 * chord + THICKNESS_TOLERANCE
    # under a bend away from the bodies a little wider than the thickness the copy's sheet is
    # tight, and its chords stand out past the thickness by more than splitting mends
    bad |= middle - t > 0.5 * THICKNESS_TOLERANCE * 4 ** MAX_SPLITS
    crossing = self_intersections(solid.vertices, solid.triangles).ravel()
    # the solid's triangles: the surface's, their offsets, then the walls (two per border edge)
    offsets = crossing[(crossing >= nf) & (crossing < 2 * nf)] - nf
    bad[offsets] = True
    walls = crossing[crossing >= 2 * nf] - 2 * nf
    if len(walls):
        border = boundary_edges(tris)
        corners = np.unique(border[walls % len(border)])
        bad |= np.isin(tris, corners).any(axis=1)
    if not bad.any():
        return bad
    adjacency = _vertex_faces(tris, n)
    for _ in range(rings):
        bad = np.asarray(adjacency.T @ (adjacency @ bad) > 0).ravel()
    while True:  # a vertex where the sound part meets itself at a corner only joins the rest
        good = tris[~bad]
        if len(good) == 0:
            return bad
        edges = np.sort(_edges_of(good), axis=1)
        key, count = np.unique(edges, axis=0, return_counts=True)
        open_ends = np.bincount(key[count == 1].ravel(), minlength=n)
        pinched = open_ends > 2
        if not pinched.any():
            return bad
        bad |= pinched[tris].any(axis=1)


def _vertex_faces(tris: np.ndarray, n: int):
    """(n, F) sparse incidence of vertices and triangles."""
    import scipy.sparse as sp

    rows = tris.ravel()
    cols = np.repeat(np.arange(len(tris)), 3)
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, len(tris)))


# The convex piece of a trimmed triangle: its corners' copies along the directions of the
# normals of the faces around any of them (spherical triangles between a vertex normal and each
# two neighbouring face normals, sampled finely enough that a chord of the thickness's sphere
# cuts it by at most SAGITTA); and points slightly wider than the triangle half-way down, so that
# neighbouring pieces overlap in volume rather than touch in a plane.
SAGITTA = 5e-5  # m
WIDEN = 1e-3  # of the distance from the triangle's centre
TURN = 0.1  # cosine: a face of the underside turned further from where it faced is refused
SHORT_EDGE = 3e-4  # m: shorter edges of the trimmed underside are collapsed (`_collapse_short`)
MAX_FLIPS = 4  # rounds of cap flips in one pass of the snap
TINY_EDGE = 1e-5  # m: shorter edges anywhere on the trimmed solid are collapsed


def _trimmed(v: np.ndarray, tris: np.ndarray, offset: np.ndarray, t: float,
             unsound: np.ndarray) -> Solid:
    """The plain offset of the sound triangles merged (manifold3d) with one convex piece per
    unsound triangle, less the region in front of the surface the pieces reach into
    (`_front`); the surface's vertices first."""
    import manifold3d

    normals = face_normals(v, tris)
    incidence = _vertex_faces(tris, len(v)).tocsr()
    step = 2.0 * np.arccos(1.0 - SAGITTA / t)
    # pieces also under the sound faces at the seam: the plain offset's wall there leans
    # between their normals and the trimmed ones', so their own sweep must reach past it
    seam = np.zeros(len(v), dtype=bool)
    seam[tris[unsound].ravel()] = True
    swept = unsound | seam[tris].any(axis=1)
    # and under the border's triangles: the plain wall follows the copies of the border's
    # vertices, which a face there bending away more steeply leans out past
    rim = np.zeros(len(v), dtype=bool)
    rim[boundary_edges(tris).ravel()] = True
    swept |= rim[tris].any(axis=1)
    around = {}  # vertex -> the directions of the normals around it
    for corner in np.unique(tris[swept]):
        ring = incidence.indices[incidence.indptr[corner]:incidence.indptr[corner + 1]]
        around[corner] = _directions(v[corner] - offset[corner], normals[ring], tris[ring],
                                     step)
    pieces, swept_points = [], []
    for face in np.flatnonzero(swept):
        corners = v[tris[face]]
        widened = corners + WIDEN * (corners - corners.mean(axis=0)) - 0.5 * t * normals[face]
        # every corner along every direction: the triangle swept over the directions' cap
        directions = np.vstack([around[c] for c in tris[face]])
        below = (corners[:, None, :] - t * directions[None, :, :]).reshape(-1, 3)
        swept_points.append(np.vstack([corners, widened, below]))
        pieces.append(manifold3d.Manifold.hull_points(swept_points[-1]))
    union = manifold3d.Manifold.batch_boolean(pieces, manifold3d.OpType.Add)
    good = ~unsound
    if good.any():
        used = np.unique(tris[good])
        index = np.full(len(v), -1)
        index[used] = np.arange(len(used))
        union = union + _manifold(*_offset_shell(v[used], index[tris[good]], offset[used], t))
    front = _front(v, tris, normals, swept_points, t)
    if front is not None:
        union = union - front
    if union.status().name != "NoError":
        raise SolidError(f"Trimming the offset failed: manifold3d says "
                         f"{union.status().name}")
    mesh = union.to_mesh64()
    out_v = np.array(mesh.vert_properties, dtype=np.float64)[:, :3]
    out_t = np.asarray(mesh.tri_verts, dtype=np.int64)
    # where pieces meet, their faces cut chords a fraction of a millimetre inside the
    # thickness: the underside's vertices (over the surface's inside, past half the
    # thickness) are put the thickness away, as the plain offset's are
    surface = SurfaceMesh.from_triangles(v, tris)
    dist, signed, _, face, closest = surface.closest(out_v)
    # corners the cut in front left a hair's breadth in front of the surface go onto it
    onto = (dist > 0) & (dist < TINY_EDGE) & (signed > 0)
    out_v[onto], dist[onto] = closest[onto], 0.0
    under = (dist > 0.5 * t) & ~_on_border(surface, boundary_edges(tris), face, closest)
    target = closest + t * (out_v - closest) / np.maximum(dist, 1e-300)[:, None]
    up = face_normals(v, tris)[surface.closest(out_v[out_t].mean(axis=1))[3]]
    from scipy.spatial import cKDTree

    fixed = cKDTree(v).query(out_v)[0] <= 1e-9  # the surface's own vertices
    out_v, out_t, keep, alive = _collapse_short(out_v, out_t, under, fixed, target, up,
                                                SHORT_EDGE)
    out_v = _snap(out_v, out_t, target[keep], under[keep], up[alive])
    # vertices the snap brought together (one closest point, one direction) are joined
    out_v, out_t, fixed = _collapse_tiny(out_v, out_t, fixed[keep])
    out_v, out_t, fixed = _mend(out_v, out_t, fixed, surface, boundary_edges(tris), t)
    out_v, out_t, fixed = _collapse_tiny(out_v, out_t, fixed)
    out_v = _part_touching(out_v, out_t, fixed)
    out_v, out_t, fixed = _unsliver(out_v, out_t, fixed)
    return _surface_first(v, tris, out_v, out_t, t, int(unsound.sum()))


FRONT_REACH = 1.25  # of the thickness: how far in front of the surface pieces are cut away
FRONT_GAP = 0.5  # share of the way to the surface in front that the cut may reach
FRONT_LEAN = 0.02  # how far the cut's prisms lean out (of their length) and its cones spread
FRONT_SLACK = 1e-9  # m: a point further than this in front of a plane is in front of it


def _front(v: np.ndarray, tris: np.ndarray, normals: np.ndarray, swept: list, t: float):
    """The region in front of the surface (towards the bodies) that the trimmed pieces reach
    into, as a manifold3d solid whose back is the surface itself (None if they reach into
    none of it).

    It is the union of convex parts: over each triangle a piece may reach into, its prism
    (the triangle moved along its normal, the far end leaning out by `FRONT_LEAN` of the
    length, so that neighbouring prisms overlap rather than meet the pieces' faces in a
    plane); over each edge between two of those where the surface bends away from the
    bodies, the wedge between their normals; over each vertex all of whose faces have one and
    around which the surface bends away on every side, the cone of their normals (wedges and
    cones spread by `FRONT_LEAN`). Each part is the region nearer the front of its triangle,
    edge or vertex than of any other, so none reaches behind the surface. Each reaches
    `FRONT_REACH` times the thickness forwards (a piece lies within the thickness of its
    triangle), or `FRONT_GAP` of the way to the surface in front if that is nearer (not to
    cut into the solid behind a part of the surface facing this one).

    Parameters
    ----------
    v : (N, 3) float
        The surface's vertices, metres.
    tris : (F, 3) int
        Its triangles.
    normals : (F, 3) float
        Their unit normals (towards the bodies).
    swept : list of (P, 3) float
        The points each trimmed piece is the hull of, its triangle's corners first.
    t : float
        The thickness, metres.
    """
    import manifold3d
    from scipy.spatial import cKDTree

    corners = v[tris]
    centres = corners.mean(axis=1)
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max()
    reach = FRONT_REACH * t
    swept_corners = np.vstack([points[:3] for points in swept])
    faces = np.flatnonzero(np.isfinite(cKDTree(swept_corners).query(
        centres, distance_upper_bound=t + reach + 2.0 * longest)[0]))
    # the rays from each triangle's middle and its corners (drawn a little in) forwards
    starts = np.concatenate([centres[faces, None], 0.9 * corners[faces] +
                             0.1 * centres[faces, None]], axis=1)
    length = np.minimum(reach, FRONT_GAP * _free_ahead(
        v, tris, starts, normals[faces], faces, reach / FRONT_GAP, longest))
    out = corners[faces] - centres[faces, None]
    lean = FRONT_LEAN * length[:, None, None] * out / np.linalg.norm(out, axis=2,
                                                                    keepdims=True)
    hulls = np.concatenate([corners[faces], corners[faces] + length[:, None, None] *
                            normals[faces, None] + lean], axis=1)  # (len(faces), 6, 3)
    # each hull lies in front of its triangle's plane and inside the three planes through
    # its edges along its normal, each moved out past the hull's furthest point
    sides = np.roll(corners[faces], -1, axis=1) - corners[faces]  # edge k: corner k to k + 1
    walls = np.cross(sides, normals[faces, None])
    walls /= np.linalg.norm(walls, axis=2, keepdims=True)
    bounds = np.einsum("kwj,kmj->kwm", walls, hulls).max(axis=2)
    level = np.einsum("ij,ij->i", corners[faces, 0], normals[faces])
    tree = cKDTree(centres[faces])
    reached = np.zeros(len(faces), dtype=bool)
    for points in swept:
        middle = points.mean(axis=0)
        size = np.linalg.norm(points - middle, axis=1).max()
        near = np.asarray(tree.query_ball_point(middle, size + reach + longest),
                          dtype=np.int64)
        near = near[~reached[near]]
        ahead = (points @ normals[faces[near]].T - level[near]).max(axis=0) > FRONT_SLACK
        inside = (np.einsum("kwj,mj->kwm", walls[near], points).min(axis=2) <
                  bounds[near] - FRONT_SLACK).all(axis=1)
        reached[near[ahead & inside]] = True
    if not reached.any():
        return None
    pieces = [manifold3d.Manifold.hull_points(hulls[k]) for k in np.flatnonzero(reached)]
    ahead = np.zeros(len(tris))
    ahead[faces[reached]] = length[reached]
    # where the surface bends away from the bodies: across an edge (the far corner of the
    # triangle across lies behind this one's plane), around a vertex (every neighbour lies
    # behind every face around it)
    for p, q, fa, fc in _ridges(v, tris, normals):
        size = min(ahead[fa], ahead[fc])
        if size > 0:
            spread = _spread(normals[[fa, fc]])
            ends = v[[p, q]]
            pieces.append(manifold3d.Manifold.hull_points(np.vstack(
                [ends, ends[0] + size * spread, ends[1] + size * spread])))
    incidence = _vertex_faces(tris, len(v)).tocsr()
    for c in np.unique(tris[faces[reached]]).tolist():
        around = incidence.indices[incidence.indptr[c]:incidence.indptr[c + 1]]
        size = ahead[around].min()
        if size > 0 and not np.any((v[np.setdiff1d(tris[around], [c])] - v[c]) @
                                   normals[around].T > FRONT_SLACK):
            pieces.append(manifold3d.Manifold.hull_points(np.vstack(
                [v[c], v[c] + size * _spread(normals[around])])))
    return manifold3d.Manifold.batch_boolean(pieces, manifold3d.OpType.Add)


def _spread(directions: np.ndarray) -> np.ndarray:
    """Unit directions moved `FRONT_LEAN` further from their mean."""
    mean = directions.mean(axis=0)
    out = directions + FRONT_LEAN * (directions - mean)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _ridges(v: np.ndarray, tris: np.ndarray, normals: np.ndarray) -> list:
    """(p, q, a, c) for every edge p-q between triangles a and c where the surface bends away
    from the bodies (the far corner of c lies behind a's plane)."""
    edges = _edges_of(tris)
    owner = np.tile(np.arange(len(tris)), 3)
    key = np.sort(edges, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, owner = key[order], owner[order]
    pair = np.flatnonzero(np.all(key[1:] == key[:-1], axis=1))
    a, c = owner[pair], owner[pair + 1]
    p, q = key[pair, 0], key[pair, 1]
    far = tris[c][(tris[c] != p[:, None]) & (tris[c] != q[:, None])]
    bends = np.einsum("ij,ij->i", v[far] - v[p], normals[a]) < -FRONT_SLACK
    return list(zip(p[bends].tolist(), q[bends].tolist(), a[bends].tolist(),
                    c[bends].tolist()))


def _free_ahead(v: np.ndarray, tris: np.ndarray, starts: np.ndarray, directions: np.ndarray,
                own: np.ndarray, limit: float, longest: float, chunk: int = 256) -> np.ndarray:
    """(R,) how far each triangle `own` may go along its `directions` before any of the rays
    from its `starts` (R, S, 3) meets another triangle of the surface (Moeller-Trumbore),
    at most `limit`. Candidates are the triangles whose middles lie near points sampled
    along the rays (no further apart than the longest edge), `chunk` triangles at a time."""
    from scipy.spatial import cKDTree

    corners = v[tris]
    tree = cKDTree(corners.mean(axis=1))
    free = np.full(len(own), limit)
    steps = int(np.clip(np.ceil(limit / max(longest, 1e-12)), 1, 32))
    along_ray = (np.arange(steps) + 0.5) * limit / steps
    radius = 0.5 * limit / steps + np.linalg.norm(starts - starts.mean(axis=1, keepdims=True),
                                                  axis=2).max() + longest
    for first in range(0, len(own), chunk):
        rows = np.arange(first, min(first + chunk, len(own)))
        samples = starts[rows].mean(axis=1)[:, None] + along_ray[None, :, None] * \
            directions[rows, None]
        found = tree.query_ball_point(samples.reshape(-1, 3), radius)
        ray = np.repeat(np.repeat(rows, steps), [len(c) for c in found])
        if len(ray) == 0:
            continue
        tri = np.concatenate([np.asarray(c, dtype=np.int64) for c in found])
        pairs = np.unique(ray * len(tris) + tri)
        ray, tri = pairs // len(tris), pairs % len(tris)
        mine = tri == own[ray]
        ray, tri = ray[~mine], tri[~mine]
        triangle = corners[tri]
        for k in range(starts.shape[1]):
            hit, far = _ray_hits(starts[ray, k], directions[ray], triangle)
            hit &= far > 1e-9
            np.minimum.at(free, ray[hit], far[hit])
    return free


def _ray_hits(origin: np.ndarray, direction: np.ndarray, triangles: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Rays from `origin` along `direction` ((K, 3) each, or (3,) for all) against the
    triangles (K, 3, 3), one each (the Moller-Trumbore test): (K,) whether each ray's line
    crosses its triangle, and how far along the direction (any sign; 0 where it does not)."""
    a = triangles[:, 0]
    e1, e2 = triangles[:, 1] - a, triangles[:, 2] - a
    d = np.broadcast_to(direction, a.shape)
    pvec = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    ok = np.abs(det) > 1e-18
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = origin - a
    u = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    w = np.einsum("ij,ij->i", qvec, d) * inv
    along = np.einsum("ij,ij->i", e2, qvec) * inv
    return ok & (u >= 0) & (w >= 0) & (u + w <= 1), along


SLIVER_HEIGHT = 1e-6  # m: a triangle of the trimmed solid lower than this is taken away
SLIVER_EDGE = 1e-4  # m: ... by collapsing its shortest edge when that is shorter than this
SLIVER_ROUNDS = 8


def _unsliver(vertices: np.ndarray, triangles: np.ndarray, fixed: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The slivers where merged pieces meet taken away: a triangle under `SLIVER_HEIGHT` high
    (a cap: its third corner lies on its longest edge) has that edge flipped with the triangle
    across it (`_flip_caps`, which leaves the shape as it was: the corner lies in both
    triangles' plane), or, where the flip would turn a face over (the corner lies within a
    fraction of a millimetre of an end of the edge, among more slivers), its shortest edge
    collapsed when shorter than `SLIVER_EDGE` (`_collapse`: manifold, no face turned by more
    than 60 degrees, a `fixed` vertex kept in place); up to `SLIVER_ROUNDS` rounds. The
    surface's own triangles (three corners `fixed`) are never flipped. Written in single
    precision, a sliver's normal can turn over, and readers that merge corners find
    zero-volume pieces. Returns the vertices, the triangles and which of them are `fixed`."""
    def slivers():
        corners = vertices[triangles]
        cross = face_cross(vertices, triangles)
        sides = np.linalg.norm(np.roll(corners, -1, axis=1) - corners, axis=2)
        low = (np.linalg.norm(cross, axis=1) < SLIVER_HEIGHT * sides.max(axis=1)) & \
            ~fixed[triangles].all(axis=1)
        return np.flatnonzero(low), cross, sides

    for _ in range(SLIVER_ROUNDS):
        low, cross, _ = slivers()
        if not len(low):
            break
        flipped = _flip_caps(vertices, triangles, low, cross, held=fixed[triangles].all(axis=1))
        low, _, sides = slivers()  # (those the flips could not take)
        k = sides[low].argmin(axis=1)  # edge k runs from corner k to corner k + 1
        span = sides[low, k]
        rows = triangles[low]
        pairs = np.stack([rows[np.arange(len(k)), k], rows[np.arange(len(k)), (k + 1) % 3]],
                         axis=1)[span < SLIVER_EDGE]
        keep = np.ones(len(vertices), dtype=bool)
        if len(pairs):
            vertices, triangles, keep, _ = _collapse(
                vertices, triangles, pairs[np.argsort(span[span < SLIVER_EDGE])], fixed,
                np.zeros((len(triangles), 3)))
            fixed = fixed[keep]
        if not flipped and keep.all():
            break
    return vertices, triangles, fixed


MEND_ROUNDS = 4


def _collapse_tiny(vertices: np.ndarray, triangles: np.ndarray, fixed: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges shorter than `TINY_EDGE` off the surface collapsed (`_collapse_short`), again
    while any collapses: in a cluster of them one may only take once its neighbour has.
    Returns the vertices, the triangles and which of them are `fixed`."""
    for _ in range(MEND_ROUNDS):
        up = np.zeros((len(triangles), 3))  # unused: no turn is judged under TINY_EDGE
        vertices, triangles, keep = _collapse_short(
            vertices, triangles, np.zeros(len(vertices), dtype=bool), fixed, vertices, up,
            0.0)[:3]
        fixed = fixed[keep]
        if keep.all():
            break
    return vertices, triangles, fixed


def _mend(vertices: np.ndarray, triangles: np.ndarray, fixed: np.ndarray,
          surface: SurfaceMesh, edges: np.ndarray, t: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The trimmed solid's last faults removed: a vertex of the underside the snap left short
    of the thickness (its move would have turned a face over), and the corners of a face
    where the underside folds, each collapsed into the nearest neighbour that takes it
    (`_collapse` with the merged vertex at the neighbour's place: no face turns by more than
    60 degrees or towards the bodies), for up to `MEND_ROUNDS` rounds. Such vertices sit
    among slivers where merged pieces meet, a fraction of a millimetre from a neighbour.
    Returns the vertices, the triangles and which of them are `fixed`."""
    for _ in range(MEND_ROUNDS):
        faults = _sheet_faults(vertices, triangles, fixed, surface, edges, t)
        short = np.zeros(0, dtype=np.int64) if faults.distance is None else \
            faults.corners[faults.distance < t - THICKNESS_TOLERANCE]
        faulty = np.unique(np.concatenate([short, triangles[faults.folds].ravel()]))
        faulty = faulty[~fixed[faulty]]
        if len(faulty) == 0:
            break
        ends = _edges_of(triangles)
        ends = np.concatenate([ends, ends[:, ::-1]])
        pairs = ends[np.isin(ends[:, 1], faulty)]  # (kept, removed)
        pairs = pairs[~fixed[pairs[:, 0]]]  # never onto the surface: no thickness left there
        span = np.linalg.norm(vertices[pairs[:, 0]] - vertices[pairs[:, 1]], axis=1)
        # the surface's normal under each triangle a collapse may turn (around the faulty)
        up = np.zeros((len(triangles), 3))
        near = np.flatnonzero(np.isin(triangles, pairs).any(axis=1))
        up[near] = surface.face_normals[surface.closest(
            vertices[triangles[near]].mean(axis=1))[3]]
        vertices, triangles, keep, _ = _collapse(vertices, triangles, pairs[np.argsort(span)],
                                                 fixed, up, at_first=True)
        fixed = fixed[keep]
        if keep.all():
            break
    return vertices, triangles, fixed


def _collapse_short(vertices: np.ndarray, triangles: np.ndarray, movable: np.ndarray,
                    fixed: np.ndarray, target: np.ndarray, up: np.ndarray, length: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Edges between two `movable` vertices of a closed triangle mesh that are shorter than
    `length`, or that moving both ends to `target` would shrink below a quarter or turn
    round, collapsed to their middles, shortest first, where that keeps the mesh a manifold
    (the two ends share no neighbour but the edge's two opposite corners), turns no
    triangle by more than 60 degrees and none towards the bodies (see `_snap`; `up`, per
    triangle). Where merged pieces meet they leave clusters of slivers a fraction of a
    millimetre across, which a move of a tenth of a millimetre turns over. Edges shorter
    than `TINY_EDGE` collapse wherever a manifold allows, but never move a `fixed` vertex
    (the surface's): the merge leaves corners a fraction of a micrometre apart, which a
    file in single precision would fuse.

    Returns the vertices, the triangles, which of the given vertices remain (renumbered in
    order) and which of the given triangles remain."""
    a, b = _edges_of(triangles).T
    now = vertices[b] - vertices[a]
    span = np.linalg.norm(now, axis=1)
    later = np.einsum("ij,ij->i", now, target[b] - target[a])
    tiny = (span < TINY_EDGE) & ~(fixed[a] & fixed[b])
    pick = ((span < length) | (later < 0.25 * span ** 2)) & movable[a] & movable[b]
    pick = (pick | tiny) & (a < b)
    order = np.flatnonzero(pick)[np.argsort(span[pick])]
    return _collapse(vertices, triangles, np.stack([a[order], b[order]], axis=1), fixed, up)


def _collapse(vertices: np.ndarray, triangles: np.ndarray, pairs: np.ndarray,
              fixed: np.ndarray, up: np.ndarray, at_first: bool = False
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The edges `pairs` (p, q) of a closed triangle mesh collapsed in order, q into p, each
    where both ends remain, the mesh stays a manifold (the ends share no neighbour but the
    edge's two opposite corners) and, unless the edge is shorter than `TINY_EDGE`, no
    triangle turns by more than 60 degrees or towards the bodies (from at most half along
    `up`, per triangle, to more than 0.4 along it). The merged vertex goes to the middle, or
    stays at p's place with `at_first`; a `fixed` end never moves. Returns the vertices, the
    triangles, which of the given vertices remain (renumbered in order) and which of the
    given triangles remain."""
    vertices, triangles = vertices.copy(), triangles.copy()
    faces_of: dict[int, set[int]] = {}
    near = np.flatnonzero(np.isin(triangles, np.unique(pairs)).any(axis=1))
    for face in near.tolist():
        for corner in triangles[face].tolist():
            faces_of.setdefault(corner, set()).add(face)
    alive = np.ones(len(triangles), dtype=bool)
    gone = np.zeros(len(vertices), dtype=bool)
    for p, q in pairs.tolist():
        if gone[p] or gone[q] or (fixed[p] and fixed[q]):
            continue
        shared = faces_of[p] & faces_of[q]
        if len(shared) != 2:
            continue
        link_p = set(triangles[list(faces_of[p])].ravel().tolist()) - {p}
        link_q = set(triangles[list(faces_of[q])].ravel().tolist()) - {q}
        opposite = set(triangles[list(shared)].ravel().tolist()) - {p, q}
        if link_p & link_q != opposite:
            continue
        if fixed[q]:
            if at_first:
                continue
            p, q = q, p  # the surface's vertex stays where it is
        middle = vertices[p] if fixed[p] or at_first else 0.5 * (vertices[p] + vertices[q])
        if np.linalg.norm(vertices[p] - vertices[q]) >= TINY_EDGE:
            rest = sorted((faces_of[p] | faces_of[q]) - shared)
            corners = triangles[rest]
            before = face_cross(vertices, corners)
            moved = vertices.copy()
            moved[[p, q]] = middle
            after = face_cross(moved, corners)
            size, size_before = np.linalg.norm(after, axis=1), np.linalg.norm(before, axis=1)
            if np.any(np.einsum("ij,ij->i", before, after) <= 0.5 * size_before * size):
                continue
            towards = np.einsum("ij,ij->i", after, up[rest]) > 0.4 * size
            if np.any(towards & (np.einsum("ij,ij->i", before, up[rest]) <=
                                 0.5 * size_before)):
                continue
        vertices[p] = middle
        for face in faces_of[q] - shared:
            triangles[face][triangles[face] == q] = p
            faces_of[p].add(face)
        for face in shared:
            alive[face] = False
            for corner in triangles[face].tolist():
                faces_of[corner].discard(face)
        gone[q] = True
    keep = ~gone
    index = np.cumsum(keep) - 1
    return vertices[keep], index[triangles[alive]], keep, alive


def _part_touching(vertices: np.ndarray, triangles: np.ndarray,
                   fixed: np.ndarray) -> np.ndarray:
    """Corners of the solid that are not joined by an edge and yet lie within `TINY_EDGE` of
    each other (where merged pieces touch, manifold3d keeps two corners at one point) parted:
    of each such group one stays (a `fixed` one if there is one) and the k-th of the others
    moves k `TINY_EDGE` into the solid, along minus its normal (moved alike, two would stay
    together). An edge as short that no collapse could take is lengthened (`_lengthen`).
    Written in single precision they would fuse, and the file would no longer be closed."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    used = np.unique(triangles)
    pairs = cKDTree(vertices[used]).query_pairs(TINY_EDGE, output_type="ndarray")
    if len(pairs) == 0:
        return vertices
    pairs = used[pairs]
    n = len(vertices)
    edges = _edges_of(triangles)
    joined = np.isin(pairs.min(axis=1) * n + pairs.max(axis=1),
                     edges.min(axis=1) * n + edges.max(axis=1))
    vertices = vertices.copy()
    for p, q in pairs[joined].tolist():  # edges the collapse could not take
        vertices = _lengthen(vertices, triangles, p, q, fixed)
    pairs = pairs[~joined]
    if len(pairs) == 0:
        return vertices
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    label = connected_components(graph, directed=False)[1]
    members = np.unique(pairs)
    # within a group, fixed corners first (they stay), then by index
    members = members[np.lexsort((members, ~fixed[members], label[members]))]
    group = label[members]
    first = np.r_[True, group[1:] != group[:-1]]
    rank = np.arange(len(members)) - np.maximum.accumulate(np.where(first, np.arange(
        len(members)), 0))
    moving = (rank > 0) & ~fixed[members]
    with np.errstate(invalid="ignore", divide="ignore"):  # corners no triangle uses
        normals = np.nan_to_num(vertex_normals(vertices, triangles))
    vertices[members[moving]] -= (TINY_EDGE * rank[moving])[:, None] * \
        normals[members[moving]]
    return vertices


def _lengthen(vertices: np.ndarray, triangles: np.ndarray, p: int, q: int,
              fixed: np.ndarray) -> np.ndarray:
    """An edge p-q shorter than `TINY_EDGE` that no collapse may take (its ends share a
    neighbour besides the edge's opposite corners) lengthened: the end with fewer triangles
    (not a `fixed` one) moves `TINY_EDGE` / 4 along the sheet, towards the middle of its
    neighbours that are not the other end's, or else off the sheet along its normal (inwards,
    then outwards), unless that turns one of its faces over. In place; returns `vertices`."""
    rings = [triangles[(triangles == k).any(axis=1)] for k in (p, q)]
    if fixed[p] or (not fixed[q] and len(rings[1]) < len(rings[0])):
        p, q = q, p
        rings.reverse()
    if fixed[p]:
        return vertices
    own = np.setdiff1d(rings[0], np.concatenate([rings[1].ravel(), [p]]))
    if len(own) == 0:
        own = np.setdiff1d(rings[0], [p, q])
    # along the sheet first; where that turns a face over (a corner inside its neighbour's
    # fan, every face of it a sliver), off the sheet along its normal, either way
    before = face_cross(vertices, rings[0])
    normal = before.sum(axis=0)  # p's area-weighted normal (its ring's faces)
    big = np.linalg.norm(before, axis=1) > 0
    for away in (vertices[own].mean(axis=0) - vertices[p], -normal, normal):
        size = np.linalg.norm(away)
        if not size > 0:
            continue
        moved = vertices.copy()
        moved[p] += 0.25 * TINY_EDGE * away / size
        after = face_cross(moved, rings[0])
        if np.all(np.einsum("ij,ij->i", before[big], after[big]) > 0):
            vertices[p] = moved[p]
            return vertices
    return vertices  # every move turns a face over: the edge stays


def _snap(vertices: np.ndarray, triangles: np.ndarray, target: np.ndarray,
          movable: np.ndarray, up: np.ndarray, passes: int = 16) -> np.ndarray:
    """`vertices` moved towards `target` where `movable`, in `passes` steps: in each, every
    vertex that has further to go than a micrometre goes there, or half as far each time a
    move of it was refused (down to a sixteenth), unless its move turns a face over (the
    cosine of its normal with where it faced first falls to `TURN`) or towards the bodies
    (from at most half along `up`, the normal of the surface under each triangle, to more
    than 0.4 along it). A vertex held back in one pass (its neighbours had not moved yet)
    may go in the next. A turned cap (a corner moved across the long edge of a flat
    triangle) is mended by flipping that edge (`triangles` changes in place)."""
    start = face_cross(vertices, triangles)
    start_size = np.linalg.norm(start, axis=1)
    facing_before = np.einsum("ij,ij->i", start, up) > 0.5 * start_size
    share = np.ones(len(vertices))
    vertices = vertices.copy()
    for _ in range(passes):
        gap = target - vertices
        trying = movable & (np.linalg.norm(gap, axis=1) > 1e-6)
        if not trying.any():
            break
        held = np.zeros(len(vertices), dtype=bool)
        flips = 0
        while trying.any():
            moved = vertices.copy()
            moved[trying] += share[trying, None] * gap[trying]
            after = face_cross(moved, triangles)
            size = np.linalg.norm(after, axis=1)
            turned = np.einsum("ij,ij->i", start, after) <= TURN * start_size * size
            turned |= ~facing_before & (np.einsum("ij,ij->i", after, up) > 0.4 * size)
            turned &= trying[triangles].any(axis=1)
            if not turned.any():
                vertices = moved
                break
            if flips < MAX_FLIPS and _flip_caps(moved, triangles, np.flatnonzero(turned),
                                                start):
                flips += 1
                start_size = np.linalg.norm(start, axis=1)
                continue  # a cap's long edge flipped: try the same moves again
            stuck = np.unique(triangles[turned])
            held[stuck] |= trying[stuck]
            trying[stuck] = False
        share[held] = np.maximum(0.5 * share[held], 1.0 / 16)
    return vertices


def _flip_caps(moved: np.ndarray, triangles: np.ndarray, faces: np.ndarray,
               start: np.ndarray, held: np.ndarray | None = None) -> bool:
    """Flips the longest edge of each of `faces` that is a cap (an angle over 150 degrees)
    where the two triangles made across the other diagonal face, with the moved corners,
    within 60 degrees of where the old two faced (`start`, updated), and neither is `held`
    (a mask over the triangles); in place. Returns whether any edge flipped."""
    n = len(moved)
    corners = moved[triangles[faces]]
    sides = np.linalg.norm(np.roll(corners, -1, axis=1) - corners, axis=2)  # edge k: k -> k+1
    k = sides.argmax(axis=1)
    longest = sides[np.arange(len(faces)), k]
    cap = longest >= 0.98 * (sides.sum(axis=1) - longest)  # largest angle over ~150 degrees
    if not cap.any():
        return False
    edges = _edges_of(triangles)
    keys = edges.min(axis=1) * n + edges.max(axis=1)
    order = np.argsort(keys)
    keys, owners = keys[order], np.tile(np.arange(len(triangles)), 3)[order]
    touched, made = set(), set()
    flipped = False
    for face, corner in zip(faces[cap].tolist(), k[cap].tolist()):
        p, q, r = (int(triangles[face][(corner + i) % 3]) for i in range(3))
        key = min(p, q) * n + max(p, q)
        lo, hi = np.searchsorted(keys, [key, key + 1])
        across = [f for f in owners[lo:hi].tolist() if f != face]
        if len(across) != 1 or face in touched or across[0] in touched:
            continue
        other = across[0]
        if held is not None and (held[face] or held[other]):
            continue
        apex = int(np.setdiff1d(triangles[other], [p, q])[0])
        diagonal = min(r, apex) * n + max(r, apex)
        if diagonal in made or np.searchsorted(keys, diagonal + 1) > np.searchsorted(
                keys, diagonal):
            continue  # the two apexes are joined already
        new = np.array([[p, apex, r], [apex, q, r]])
        facing = start[face] + start[other]
        after = face_cross(moved, new)
        if np.any(after @ facing <= 0.5 * np.linalg.norm(after, axis=1) *
                  np.linalg.norm(facing)):
            continue
        triangles[face], triangles[other] = new
        start[face] = start[other] = 0.5 * facing
        touched.update((face, other))
        made.add(diagonal)
        flipped = True
    return flipped


def _directions(up: np.ndarray, ring: np.ndarray, ring_tris: np.ndarray,
                step: float) -> np.ndarray:
    """Unit directions covering the normals around a vertex: for each two faces of its ring
    that share an edge, the spherical triangle of the vertex's own direction (`up`, from its
    offset copy to the vertex) and their normals, sampled on a barycentric grid no coarser
    than `step` radians."""
    centre = up / np.linalg.norm(up)
    out = [centre[None], ring]
    k = len(ring)
    for i in range(k):
        for j in range(i + 1, k):
            if len(np.intersect1d(ring_tris[i], ring_tris[j])) < 2:
                continue  # not neighbours
            a, b = ring[i], ring[j]
            widest = max(np.arccos(np.clip(x @ y, -1.0, 1.0))
                         for x, y in ((centre, a), (centre, b), (a, b)))
            m = int(np.ceil(widest / step))
            if m <= 1:
                continue
            u, w = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
            keep = u + w <= m
            u, w = u[keep] / m, w[keep] / m
            d = (1 - u - w)[:, None] * centre + u[:, None] * a + w[:, None] * b
            out.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    return np.vstack(out)


def _manifold(vertices: np.ndarray, triangles: np.ndarray):
    import manifold3d

    return manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(vertices, dtype=np.float64),
        tri_verts=np.ascontiguousarray(triangles, dtype=np.uint64)))


def _surface_first(v: np.ndarray, tris: np.ndarray, out_v: np.ndarray, out_t: np.ndarray,
                   t: float, trimmed: int) -> Solid:
    """The merged mesh renumbered so that the surface's vertices come first, as they were.
    A surface vertex the merge left out (where coplanar pieces met, their triangles are
    joined) stays, used by no triangle."""
    from scipy.spatial import cKDTree

    dist, nearest = cKDTree(out_v).query(v)
    found = dist <= 1e-9
    rest = np.setdiff1d(np.arange(len(out_v)), nearest[found])
    renumber = np.empty(len(out_v), dtype=np.int64)
    renumber[nearest[found]] = np.flatnonzero(found)
    renumber[rest] = len(v) + np.arange(len(rest))
    return Solid(np.concatenate([v, out_v[rest]]), renumber[out_t], "offset", t, len(v), tris,
                 trimmed)


def _true_offset(v: np.ndarray, tris: np.ndarray, offset: np.ndarray, thickness: float,
                 rounds: int = 4) -> np.ndarray:
    """Pushes offset vertices a little short of the thickness (the vertex normal only
    approximates the directions of the faces around it) out along the line from their closest
    surface point. A vertex short by more than a fifth of the thickness is left: the offset
    runs into another part of the surface there, and `check_solid` reports it."""
    mesh = SurfaceMesh.from_triangles(v, tris)
    for _ in range(rounds):
        dist, _, _, _, closest = mesh.closest(offset)
        short = (dist < thickness - 0.1 * THICKNESS_TOLERANCE) & (dist > 0.8 * thickness)
        if not short.any():
            break
        away = (offset[short] - closest[short]) / dist[short, None]
        offset[short] = closest[short] + thickness * away
    return offset


def plinth(vertices: np.ndarray, faces: np.ndarray, *, floor: float = 0.0,
           check: bool = True) -> Solid:
    """The volume between the surface and the floor: the surface, its shadow on the plane
    y = `floor`, and vertical side walls.

    Parameters
    ----------
    vertices : (N, 3) float
        The surface, metres, Y up; every vertex above the floor.
    faces : (F, 4) or (F, 3) int
        Its faces, counter-clockwise seen from the bodies (from above where it faces up).
    floor : float, default 0.0
        The floor's height, metres.
    check : bool, default True
        Run `check_solid` and raise if it fails.

    Raises
    ------
    SolidError
        If a vertex is not above the floor, or the surface overhangs itself (its shadow
        folds, so the plinth would not be a solid), or (with `check`) a library rejects it.
    """
    v, f = _validate(vertices, faces)
    if v[:, 1].min() <= floor:
        raise SolidError(f"Expected every surface vertex above the floor y = {floor} m, got "
                         f"one at y = {v[:, 1].min():.4f} m")
    tris = f if f.shape[1] == 3 else quad_triangles(f)
    shadow = v.copy()
    shadow[:, 1] = floor
    up = face_normals(v, tris)[:, 1]
    flat = np.cross(shadow[tris[:, 1]] - shadow[tris[:, 0]],
                    shadow[tris[:, 2]] - shadow[tris[:, 0]])[:, 1]
    if np.any(flat * np.sign(up.sum()) <= 0):
        raise SolidError(f"Expected a surface seen from above without overhangs, got "
                         f"{int(np.sum(flat * np.sign(up.sum()) <= 0))} triangles whose "
                         f"shadow on the floor is folded or empty")
    if up.sum() < 0:
        raise SolidError("Expected a surface whose normals point up, towards the bodies; "
                         "a plinth under a surface facing down has no inside")
    solid = Solid(np.concatenate([v, shadow]), _close(v, f, shadow), "plinth", None, len(v),
                  tris)
    if check:
        _raise_if_bad(solid)
    return solid


def _raise_if_bad(solid: Solid) -> None:
    report = check_solid(solid)
    if not report.ok:
        raise SolidError(f"The {solid.kind} solid is not sound: {report.problem()}")


def check_solid(solid: Solid) -> SolidCheck:
    """Checks a solid with trimesh (closed, consistently wound), manifold3d (status, volume),
    an exact test for triangles crossing each other (`self_intersections`, deeper than
    `CROSSING_DEPTH`), libigl's winding number in front of the surface and behind it
    (`over_surface`: the surface's triangles with the solid `FRONT_PROBE` in front of their
    middles; `hollow_under`: those without it `FRONT_PROBE` behind) and, for
    an offset, the underside's distance from the surface and its folds.

    Parameters
    ----------
    solid : Solid

    Returns
    -------
    SolidCheck
        For an offset (None for a plinth): the underside is every triangle of the solid that
        is not the surface's and lies over the surface's inside (not beside its border) at
        least half the thickness away; those facing the bodies are `folded_faces`, the others
        the underside proper. Thickness figures are the least and largest distance from the
        underside's vertices to the surface; `too_close` counts those nearer than the
        thickness less `THICKNESS_TOLERANCE`; `clearance_m` is the least distance between
        the underside and the surface, probed also at its triangles' centres and from the
        surface's vertices.
    """
    import manifold3d
    import trimesh

    mesh = trimesh.Trimesh(solid.vertices, solid.triangles, process=False)
    manifold = manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(solid.vertices, dtype=np.float64),
        tri_verts=np.ascontiguousarray(solid.triangles, dtype=np.uint64)))
    status = manifold.status().name
    volume = float(manifold.volume()) if status == "NoError" else \
        enclosed_volume(solid.vertices, solid.triangles)
    folded, low, high, close, clearance = 0, None, None, 0, None
    top = solid.vertices[:solid.n_surface]
    creases = surface_folds(top, solid.surface_triangles)
    if solid.kind == "offset":
        folded, low, high, close, clearance = _underside(solid)
    crossing = self_intersections(solid.vertices, solid.triangles, depth=CROSSING_DEPTH)
    # what an STL reader sees: single-precision millimetres, corners welded by position
    single = workshop_vertices(solid.vertices).astype(np.float32)
    corners, weld = np.unique(single, axis=0, return_inverse=True)
    welded = trimesh.Trimesh(corners.astype(np.float64), weld.ravel()[solid.triangles],
                             process=False)
    return SolidCheck(bool(mesh.is_watertight), bool(mesh.is_winding_consistent), status,
                      volume, folded, low, high, close, clearance, creases, len(crossing),
                      solid.trimmed, bool(welded.is_watertight), *_beside_top(solid))


# m: how far in front of each of the surface's triangles (towards the bodies) the solid is
# looked for; none of it may lie there (the surface is the solid's top). The trimmed pieces,
# swept along the normals of the faces around their corners, reached through it where those
# turn by more than 90 degrees from a face (a sharp crease; a bend tight for the faces' size:
# `reclining`'s 3 cm solid stood up to 4 mm in front of its surface).
FRONT_PROBE = THICKNESS_TOLERANCE


def _beside_top(solid: Solid) -> tuple[int, int]:
    """How many of the surface's triangles have the solid in front of them, and how many
    lack it right behind them: the points `FRONT_PROBE` from the triangle's middle along its
    normal (towards the bodies) and against it, inside the solid or not by libigl's winding
    number (the top is the surface: solid behind it, none in front; a trim that cut away the
    solid under a ridge left a hollow behind the surface, which the underside's distances do
    not see)."""
    import igl

    top = solid.vertices[:solid.n_surface]
    tris = np.asarray(solid.surface_triangles, dtype=np.int64)
    middles, normals = top[tris].mean(axis=1), face_normals(top, tris)
    probes = np.concatenate([middles + FRONT_PROBE * normals, middles - FRONT_PROBE * normals])
    winding = np.abs(igl.fast_winding_number(
        np.ascontiguousarray(solid.vertices, dtype=np.float64),
        np.ascontiguousarray(solid.triangles, dtype=np.int64), probes)) > 0.5
    return int(np.sum(winding[:len(tris)])), int(np.sum(~winding[len(tris):]))


# m: triangles of a solid cross only where they overlap deeper than this, and a triangle
# thinner than this (its least height) folds nothing. Where the trimmed offset's pieces meet,
# the merge leaves slivers and flat caps whose corners lie micrometres off a line; a
# workshop's tolerance (0.1 mm) is ten times coarser.
CROSSING_DEPTH = 1e-5


def _underside(solid: Solid):
    """(folded faces, least and largest thickness, vertices too close, clearance) of an
    offset solid (see `check_solid`)."""
    t = solid.thickness
    surface = SurfaceMesh.from_triangles(solid.vertices[:solid.n_surface],
                                         solid.surface_triangles)
    edges = boundary_edges(solid.surface_triangles)
    on_surface = np.arange(len(solid.vertices)) < solid.n_surface
    faults = _sheet_faults(solid.vertices, solid.triangles, on_surface, surface, edges, t)
    if faults.distance is None or not len(faults.distance):
        # (an underside with no corner over the surface's inside, as under a single quad,
        # has no thickness to measure there)
        return len(faults.folds), None, None, 0, None
    low, high = float(faults.distance.min()), float(faults.distance.max())
    inside = np.setdiff1d(np.arange(solid.n_surface), edges)
    d_in = SurfaceMesh.from_triangles(solid.vertices, solid.triangles[faults.sheet]).closest(
        surface.vertices[inside])[0]
    return len(faults.folds), low, high, int(np.sum(faults.distance <
                                                    t - THICKNESS_TOLERANCE)), \
        float(min(faults.middle.min(), d_in.min(initial=np.inf), low))


@dataclass(frozen=True)
class _Faults:
    """The underside of an offset (see `_sheet_faults`): `sheet` (indices of its triangles),
    `folds` (of those that fold), `corners` (its vertices over the surface's inside) with their
    `distance` from the surface (None if there is no underside) and the distance of its
    triangles' middles, `middle`."""

    sheet: np.ndarray
    folds: np.ndarray
    corners: np.ndarray
    distance: np.ndarray | None
    middle: np.ndarray


def _sheet_faults(vertices: np.ndarray, triangles: np.ndarray, on_surface: np.ndarray,
                  surface: SurfaceMesh, edges: np.ndarray, t: float) -> _Faults:
    """The underside of a solid offset `t` from `surface` (whose vertices are `on_surface`
    and border `edges`): every triangle with no corner on the surface whose middle lies over
    the surface's inside (not beside its border) at least half the thickness away. Those
    facing the bodies whose line from the surface folds the underside deeper than
    `THICKNESS_TOLERANCE` (`_fold_depths`) are folds."""
    chosen = np.flatnonzero(~on_surface[triangles].any(axis=1))  # the walls meet the surface
    tris = triangles[chosen]
    dist, _, _, face, closest = surface.closest(vertices[tris].mean(axis=1))
    sheet = ~_on_border(surface, edges, face, closest) & (dist >= 0.5 * t)
    facing = np.einsum("ij,ij->i", face_normals(vertices, tris), surface.face_normals[face])
    # a sliver thinner than CROSSING_DEPTH (left where merged pieces meet) has no meaningful
    # normal; a fold faces the bodies, a step where pieces meet stands across
    corners = vertices[tris]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    sliver = np.linalg.norm(face_cross(vertices, tris), axis=1) < CROSSING_DEPTH * longest
    candidates = np.flatnonzero(sheet & (facing > 0.5) & ~sliver)
    depth = _fold_depths(vertices, tris, closest[candidates],
                         vertices[tris[candidates]].mean(axis=1), t)
    folds = chosen[candidates[depth > THICKNESS_TOLERANCE]]
    if not sheet.any():
        return _Faults(chosen[sheet], folds, np.zeros(0, dtype=np.int64), None, dist[sheet])
    ends = np.unique(tris[sheet])
    d_corner, _, _, c_face, c_closest = surface.closest(vertices[ends])
    inner = ~_on_border(surface, edges, c_face, c_closest)
    return _Faults(chosen[sheet], folds, ends[inner], d_corner[inner], dist[sheet])


def _fold_depths(vertices: np.ndarray, underside: np.ndarray, feet: np.ndarray,
                 points: np.ndarray, t: float) -> np.ndarray:
    """(P,) how deep the underside folds on each line from a surface point (`feet`) through
    a point of a face that turns towards the bodies (`points`): the span, along the line,
    between the first and the last of the `underside` triangles it passes through (ray and
    triangle by the Moeller-Trumbore test) past half the thickness `t`. A sheet that folds
    back on itself is crossed three times or more; a flap a few micrometres deep where
    merged pieces met spans as little."""
    from scipy.spatial import cKDTree

    if len(points) == 0:
        return np.zeros(0)
    corners = vertices[underside]
    centres = corners.mean(axis=1)
    reach = np.linalg.norm(corners - centres[:, None], axis=2).max()
    tree = cKDTree(centres)
    depths = np.zeros(len(points))
    for k, (foot, point) in enumerate(zip(feet, points)):
        direction = (point - foot) / max(np.linalg.norm(point - foot), 1e-300)
        # triangles within reach of the line's first 2 t, sampled
        samples = foot + np.outer(np.linspace(0.0, 2.0 * t, 32), direction)
        near = np.unique(np.concatenate(
            tree.query_ball_point(samples, reach + 0.1 * t))).astype(np.int64)
        hit, along = _ray_hits(foot, direction, corners[near])
        hit &= (along > 0) & (along < 2.0 * t)
        if hit.sum() >= 2:
            depths[k] = float(np.ptp(along[hit]))
    return depths


def _on_border(surface: SurfaceMesh, edges: np.ndarray, face: np.ndarray,
               points: np.ndarray) -> np.ndarray:
    """(P,) bool: which closest points (on triangles `face` of `surface`) lie within
    `THICKNESS_TOLERANCE` of the surface's border `edges` (of an edge of their triangle that
    no other triangle shares, or of a corner on the border): points beside the border, on
    the side walls."""
    corners = surface.triangles[face]
    a, b, c = (surface.vertices[corners[:, k]] for k in range(3))
    ab, ac, ap = b - a, c - a, points - a
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((ab, ab), (ab, ac), (ac, ac)))
    d20, d21 = np.einsum("ij,ij->i", ap, ab), np.einsum("ij,ij->i", ap, ac)
    den = np.maximum(d00 * d11 - d01 * d01, 1e-300)
    wb = (d11 * d20 - d01 * d21) / den
    wc = (d00 * d21 - d01 * d20) / den
    weights = np.stack([1.0 - wb - wc, wb, wc], axis=1)  # of corners 0, 1, 2
    twice_area = np.sqrt(den)
    key = {tuple(e) for e in np.sort(edges, axis=1).tolist()}
    result = np.zeros(len(points), dtype=bool)
    for k in range(3):  # the edge opposite corner k, at weight x altitude from the point
        i, j = corners[:, (k + 1) % 3], corners[:, (k + 2) % 3]
        length = np.linalg.norm(surface.vertices[j] - surface.vertices[i], axis=1)
        near = weights[:, k] * twice_area / np.maximum(length, 1e-300) < THICKNESS_TOLERANCE
        if near.any():
            pair = np.sort(np.stack([i[near], j[near]], axis=1), axis=1)
            result[np.flatnonzero(near)] |= np.array([tuple(e) in key for e in pair.tolist()])
    rim = np.zeros(len(surface.vertices), dtype=bool)  # a triangle may touch it at a corner
    rim[edges.ravel()] = True
    for k in range(3):
        result |= rim[corners[:, k]] & (np.linalg.norm(
            points - surface.vertices[corners[:, k]], axis=1) < THICKNESS_TOLERANCE)
    return result


def surface_folds(vertices: np.ndarray, triangles: np.ndarray) -> int:
    """How many edges of a triangle surface join faces whose normals are more than 90 degrees
    apart (a sharp fold, not a smooth bend).

    Parameters
    ----------
    vertices : (V, 3) float
    triangles : (F, 3) int

    Returns
    -------
    int
    """
    t = np.asarray(triangles, dtype=np.int64)
    normals = face_normals(vertices, t)
    edges = np.sort(_edges_of(t), axis=1)
    face = np.tile(np.arange(len(t)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, face = edges[order], face[order]
    pair = np.all(edges[1:] == edges[:-1], axis=1)
    dots = np.einsum("ij,ij->i", normals[face[:-1][pair]], normals[face[1:][pair]])
    return int(np.sum(dots < 0))


def workshop_vertices(vertices: np.ndarray) -> np.ndarray:
    """The workshop's coordinates of scene points.

    Parameters
    ----------
    vertices : (V, 3) float
        Metres, Y up.

    Returns
    -------
    (V, 3) float
        Millimetres, Z up: (x, y, z) -> 1000 (x, -z, y), a rotation (no mirror).
    """
    return np.asarray(vertices, dtype=np.float64) @ Y_UP_TO_Z_UP_MM.T


def write_stl(path: str | os.PathLike, solid: Solid) -> Path:
    """Writes a binary STL atomically, in millimetres with Z up (see the module notes).

    Parameters
    ----------
    path : str or os.PathLike
    solid : Solid

    Returns
    -------
    pathlib.Path
        The path written.
    """
    import trimesh

    path = Path(path)
    mesh = trimesh.Trimesh(workshop_vertices(solid.vertices), solid.triangles, process=False)
    write_atomic(path, mesh.export(file_type="stl"))
    return path


_CONTENT_TYPES = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">'
    '<Default Extension="rels" '
    'ContentType="application/vnd.openxmlformats-package.relationships+xml"/>'
    '<Default Extension="model" '
    'ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>')
_RELS = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">'
    '<Relationship Target="/3D/3dmodel.model" Id="rel0" '
    'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')


def model_3mf(solid: Solid, name: str = "sitrelax solid") -> bytes:
    """The 3MF package of a solid.

    Parameters
    ----------
    solid : Solid
    name : str
        The mesh object's name.

    Returns
    -------
    bytes
        A zip with one mesh object in unit millimetre, Z up (see `workshop_vertices`), with
        the vertices its triangles use.
    """
    from xml.sax.saxutils import quoteattr

    used, triangles = np.unique(solid.triangles, return_inverse=True)
    v = workshop_vertices(solid.vertices[used])
    triangles = triangles.reshape(-1, 3)
    body = io.StringIO()
    body.write('<?xml version="1.0" encoding="UTF-8"?>\n<model unit="millimeter" '
               'xml:lang="en-US" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/'
               '2015/02">\n<resources><object id="1" type="model" name=' + quoteattr(name) +
               '><mesh><vertices>\n')
    np.savetxt(body, v, fmt='<vertex x="%.4f" y="%.4f" z="%.4f"/>')
    body.write('</vertices><triangles>\n')
    np.savetxt(body, triangles, fmt='<triangle v1="%d" v2="%d" v3="%d"/>')
    body.write('</triangles></mesh></object></resources>\n'
               '<build><item objectid="1"/></build></model>\n')
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("[Content_Types].xml", _CONTENT_TYPES)
        zf.writestr("_rels/.rels", _RELS)
        zf.writestr("3D/3dmodel.model", body.getvalue())
    return buf.getvalue()


def write_3mf(path: str | os.PathLike, solid: Solid, name: str = "sitrelax solid") -> Path:
    """Writes a 3MF file atomically (millimetres, Z up; see `model_3mf`).

    Parameters
    ----------
    path : str or os.PathLike
    solid : Solid
    name : str
        The mesh object's name.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    path = Path(path)
    write_atomic(path, model_3mf(solid, name))
    return path
