"""Solids for the workshop: a fitted surface thickened into a closed, watertight, manifold
mesh, checked by libraries (trimesh, manifold3d) and written as STL or 3MF.

Inside the library a solid is in the project's frame: metres, right-handed, Y up. The files
follow the workshop's convention instead: millimetres and Z up, the point (x, y, z) written as
1000 * (x, -z, y), a proper rotation (determinant +1) of -90 degrees about X, so nothing is
mirrored. A 3MF file states its unit (``unit="millimeter"``); STL has none, and millimetres is
the convention every slicer and CAM program assumes.

Two solids are made:

* an offset shell (`thicken`): the surface, a copy moved by the thickness along the vertex
  normals away from the bodies, and side walls joining the two along the surface's border;
* a plinth (`plinth`): the surface, its copy dropped onto the floor (y = 0), and side walls.

A naive offset folds over where the surface bends away from the bodies more tightly than the
thickness (a convex radius under the thickness); `check_solid` finds such folds and places
where the offset comes nearer the surface than the thickness, and `thicken` refuses to return
a solid that has them.
"""

from __future__ import annotations

import io
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture.files import write_atomic

from solver.mesh import SurfaceMesh, enclosed_volume, face_normals, quad_triangles, \
    self_intersections, vertex_normals

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
    plinth); the first `n_surface` vertices are the surface's, the next `n_surface` their
    offset (or floor) copies, in the same order; the first `n_surface_triangles` triangles
    are the surface's, the next as many their copies' (reversed), then the side walls."""

    vertices: np.ndarray
    triangles: np.ndarray
    kind: str
    thickness: float | None
    n_surface: int
    n_surface_triangles: int


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

    @property
    def ok(self) -> bool:
        """Closed, consistently wound, accepted by manifold3d, positive volume, no triangles
        crossing, no fold in the offset and no place nearer the surface than the thickness
        allows. (A sharp fold of
        the surface itself, `surface_folds`, is named in `problem` as the likely cause.)"""
        return bool(self.watertight and self.winding_consistent and
                    self.manifold_status == "NoError" and self.volume_m3 > 0 and
                    self.folded_faces == 0 and self.too_close == 0 and
                    self.intersecting_pairs == 0 and
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
        if self.manifold_status != "NoError":
            parts.append(f"manifold3d rejects it ({self.manifold_status})")
        if self.volume_m3 <= 0 and not parts:
            parts.append(f"its volume is {self.volume_m3:.3g} m^3")
        return "; ".join(parts)


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
    SolidError
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
        raise SolidError(f"Expected a manifold surface, got an edge shared by "
                         f"{int(counts.max())} faces")
    _, directed = np.unique(edges[:, 0] * n + edges[:, 1], return_counts=True)
    if directed.max(initial=0) > 1:
        raise SolidError("Expected consistently oriented faces, got an edge run the same "
                         "way by two faces")
    return edges[counts[inverse] == 1]


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
    return v, f.astype(np.int64)


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
            check: bool = True) -> Solid:
    """The surface thickened away from the bodies by a constant `thickness`.

    Each vertex is copied `thickness` along minus its area-weighted unit normal (the normals
    point towards the bodies), and side walls close the border.

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

    Returns
    -------
    Solid

    Raises
    ------
    SolidError
        On bad input, or (with `check`) when the offset folds over or runs into the surface.
    """
    v, f = _validate(vertices, faces)
    if not np.isfinite(thickness) or thickness <= 0:
        raise SolidError(f"Expected a thickness > 0 m, got {thickness}")
    tris = f if f.shape[1] == 3 else quad_triangles(f)
    offset = _true_offset(v, tris, v - thickness * vertex_normals(v, tris), thickness)
    solid = Solid(np.concatenate([v, offset]), _close(v, f, offset), "offset",
                  float(thickness), len(v), len(tris))
    if check:
        _raise_if_bad(solid)
    return solid


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
                  len(tris))
    if check:
        _raise_if_bad(solid)
    return solid


def _raise_if_bad(solid: Solid) -> None:
    report = check_solid(solid)
    if not report.ok:
        raise SolidError(f"The {solid.kind} solid is not sound: {report.problem()}")


def check_solid(solid: Solid) -> SolidCheck:
    """Checks a solid with trimesh (closed, consistently wound), manifold3d (status, volume),
    an exact test for triangles crossing each other (`self_intersections`) and, for an
    offset, the offset's distance from the surface and its folds.

    Parameters
    ----------
    solid : Solid

    Returns
    -------
    SolidCheck
        Thickness figures are the least and largest distance from the offset's vertices to
        the surface (None for a plinth); `too_close` counts the vertices nearer than the
        thickness less `THICKNESS_TOLERANCE` (where the offset runs into the surface);
        `clearance_m` is the least distance between the two sheets, probed also at face
        centres both ways and from the surface's vertices.
    """
    import manifold3d
    import trimesh

    mesh = trimesh.Trimesh(solid.vertices, solid.triangles, process=False)
    manifold = manifold3d.Manifold(manifold3d.Mesh(
        vert_properties=np.ascontiguousarray(solid.vertices, dtype=np.float32),
        tri_verts=np.ascontiguousarray(solid.triangles, dtype=np.uint32)))
    status = manifold.status().name
    volume = float(manifold.volume()) if status == "NoError" else \
        enclosed_volume(solid.vertices, solid.triangles)
    folded, low, high, close, clearance = 0, None, None, 0, None
    creases = surface_folds(solid.vertices[:solid.n_surface],
                            solid.triangles[:solid.n_surface_triangles])
    if solid.kind == "offset":
        n = solid.n_surface
        top, bottom = solid.vertices[:n], solid.vertices[n:]
        tris = solid.triangles[:solid.n_surface_triangles]
        folded = int(np.sum(np.einsum("ij,ij->i", face_normals(top, tris),
                                      face_normals(bottom, tris)) <= 0))
        d_out, d_in = offset_distances(top, bottom, tris)
        at_vertices = d_out[:n]
        low, high = float(at_vertices.min()), float(at_vertices.max())
        close = int(np.sum(at_vertices < solid.thickness - THICKNESS_TOLERANCE))
        clearance = float(min(d_out.min(), d_in.min()))
    return SolidCheck(bool(mesh.is_watertight), bool(mesh.is_winding_consistent), status,
                      volume, folded, low, high, close, clearance, creases,
                      len(self_intersections(solid.vertices, solid.triangles)))


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
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    face = np.tile(np.arange(len(t)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, face = edges[order], face[order]
    pair = np.all(edges[1:] == edges[:-1], axis=1)
    dots = np.einsum("ij,ij->i", normals[face[:-1][pair]], normals[face[1:][pair]])
    return int(np.sum(dots < 0))


def offset_distances(top: np.ndarray, bottom: np.ndarray,
                     triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances between a surface and its offset sheet (the same triangles).

    Parameters
    ----------
    top, bottom : (N, 3) float
        The surface and its offset, metres.
    triangles : (F, 3) int

    Returns
    -------
    d_out, d_in : (N + F,) float
        Metres from the offset's vertices then face centres to the surface, and from the
        surface's vertices then face centres to the offset.
    """
    def probes(v):
        return np.concatenate([v, v[triangles].mean(axis=1)])

    d_out = SurfaceMesh.from_triangles(top, triangles).closest(probes(bottom))[0]
    d_in = SurfaceMesh.from_triangles(bottom, triangles).closest(probes(top))[0]
    return d_out, d_in


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
        A zip with one mesh object in unit millimetre, Z up (see `workshop_vertices`).
    """
    from xml.sax.saxutils import quoteattr

    v = workshop_vertices(solid.vertices)
    body = io.StringIO()
    body.write('<?xml version="1.0" encoding="UTF-8"?>\n<model unit="millimeter" '
               'xml:lang="en-US" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/'
               '2015/02">\n<resources><object id="1" type="model" name=' + quoteattr(name) +
               '><mesh><vertices>\n')
    np.savetxt(body, v, fmt='<vertex x="%.4f" y="%.4f" z="%.4f"/>')
    body.write('</vertices><triangles>\n')
    np.savetxt(body, solid.triangles, fmt='<triangle v1="%d" v2="%d" v3="%d"/>')
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
