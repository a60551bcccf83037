"""Workshop drawings: sections through each person and the overall dimensions, as DXF
(ezdxf) and PNG.

Inside the library lengths are metres, Y up. A DXF drawing is in millimetres ($INSUNITS = 4).
A section is drawn in its own plane: across the page the distance along the section's
horizontal direction from the person's pelvis, up the page the height above the floor
(y = 0). The overall drawing is the workshop's plan and side elevation, Z up: a point
(x, y, z) of the scene is (x, -z, y) in the workshop's frame, so the plan shows (x, -z) and the
elevation (-z, y), in millimetres.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from capture.files import write_atomic

from solver.mesh import quad_triangles

LAYERS = {"SURFACE": 5, "BODY": 1, "SOLID": 8, "FLOOR": 3, "DIMENSIONS": 7}  # ACI colours
# the dimensions' look: millimetres shown as they are, whole (the EZDXF style's own values,
# and each dimension's override as well)
DIMENSION_STYLE = {"dimtxt": 12.0, "dimasz": 8.0, "dimdec": 0, "dimlfac": 1.0}


class DrawingError(ValueError):
    """A section or drawing that cannot be made as asked."""


@dataclass(frozen=True, eq=False)
class Section:
    """A vertical section: its `name`, the plane's `origin` (3,) and horizontal direction
    `along` (3,) (unit), and its curves by layer ("SURFACE", "BODY", "SOLID"), each a list of
    (K, 2) polylines (distance along, height) in metres."""

    name: str
    origin: np.ndarray
    along: np.ndarray
    curves: dict = field(default_factory=dict)

    def extent(self, layer: str = "SURFACE") -> tuple[np.ndarray, np.ndarray] | None:
        """(2,) lower and upper corner of a layer's curves, or None if it has none."""
        lines = self.curves.get(layer) or []
        if not lines:
            return None
        pts = np.concatenate(lines)
        return pts.min(axis=0), pts.max(axis=0)


def plane_section(vertices: np.ndarray, triangles: np.ndarray, origin, normal) -> list:
    """Where a plane cuts a triangle mesh: a list of (K, 3) polylines (closed ones repeat
    their first point), metres.

    Parameters
    ----------
    vertices : (V, 3) float
    triangles : (F, 3) int, or (F, 4) quads (split along their 0-2 diagonal)
    origin : (3,) float
        A point of the plane.
    normal : (3,) float
        The plane's normal (any length > 0).

    Returns
    -------
    list of (K, 3) float
        The cut's polylines, metres.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if t.ndim == 2 and t.shape[1] == 4:
        t = quad_triangles(t)
    n = np.asarray(normal, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or \
            not np.linalg.norm(n) > 0:
        raise DrawingError(f"Expected vertices (V, 3), triangles (F, 3) and a non-zero "
                           f"normal, got {v.shape}, {t.shape}, {n}")
    d = (v - np.asarray(origin, dtype=np.float64)) @ (n / np.linalg.norm(n))
    d[d == 0] = 1e-15  # a vertex on the plane counts as in front, so every cut is an edge's
    side = d[t] > 0
    cut = np.flatnonzero(side.any(axis=1) & ~side.all(axis=1))
    segments = []
    for tri in t[cut]:
        crossed = [(int(a), int(b)) for a, b in ((tri[0], tri[1]), (tri[1], tri[2]),
                                                 (tri[2], tri[0])) if (d[a] > 0) != (d[b] > 0)]
        segments.append(tuple(tuple(sorted(e)) for e in crossed))
    return [_edge_point(v, d, chain) for chain in _chains(segments)]


def _edge_point(v: np.ndarray, d: np.ndarray, edges: list) -> np.ndarray:
    a = np.array([e[0] for e in edges])
    b = np.array([e[1] for e in edges])
    w = (d[a] / (d[a] - d[b]))[:, None]
    return v[a] * (1 - w) + v[b] * w


def _chains(segments: list) -> list[list]:
    """Joins segments (pairs of edge keys) sharing an edge into chains of edge keys."""
    touching: dict = {}
    for k, (e, f) in enumerate(segments):
        touching.setdefault(e, []).append(k)
        touching.setdefault(f, []).append(k)
    used = np.zeros(len(segments), dtype=bool)
    chains = []
    ends = [e for e, ks in touching.items() if len(ks) == 1]  # open chains start at an end
    for start in ends + list(touching):
        if all(used[k] for k in touching[start]):
            continue
        chain, here = [start], start
        while True:
            nxt = [k for k in touching[here] if not used[k]]
            if not nxt:
                break
            used[nxt[0]] = True
            e, f = segments[nxt[0]]
            here = f if e == here else e
            chain.append(here)
        chains.append(chain)
    return chains


def section(name: str, origin, along, meshes: dict) -> Section:
    """A vertical section of several meshes.

    Parameters
    ----------
    name : str
    origin : (3,) float
        A point of the plane (a person's pelvis), metres.
    along : (3,) float
        The section's direction; its vertical part is dropped.
    meshes : dict
        {layer: (vertices (V, 3), faces (F, 3|4))}.

    Returns
    -------
    Section
        Curves in the plane's (distance along from `origin`, height) coordinates, metres.

    Raises
    ------
    DrawingError
        If `along` is vertical.
    """
    along = np.asarray(along, dtype=np.float64).copy()
    along[1] = 0.0
    if not np.linalg.norm(along) > 1e-9:
        raise DrawingError(f"Expected a horizontal direction for section {name!r}, got "
                           f"a vertical one")
    along /= np.linalg.norm(along)
    origin = np.asarray(origin, dtype=np.float64)
    normal = np.cross(along, [0.0, 1.0, 0.0])
    curves = {}
    for layer, (vertices, faces) in meshes.items():
        lines = plane_section(vertices, faces, origin, normal)
        curves[layer] = [np.stack([(p - origin) @ along, p[:, 1]], axis=1) for p in lines
                         if len(p) > 1]
    return Section(name, origin, along, curves)


def _new_document():
    import ezdxf

    doc = ezdxf.new("R2010", setup=True)
    doc.units = ezdxf.units.MM
    doc.header["$INSUNITS"] = 4
    doc.header["$MEASUREMENT"] = 1
    for name, color in LAYERS.items():
        doc.layers.add(name, color=color)
    # ezdxf's EZDXF style shows metres in centimetres (a length factor of 100): here the
    # style itself shows the drawing's millimetres, whole, as they are, for a CAD program
    # that draws a dimension from its style and not from each entity's override
    style = doc.dimstyles.get("EZDXF")
    for key, value in DIMENSION_STYLE.items():
        style.dxf.set(key, value)
    return doc


def _polyline(msp, points: np.ndarray, layer: str) -> None:
    """points (K, 2) as an LWPOLYLINE on `layer`: a closed one (flagged so, its first point
    not repeated) when the curve ends where it starts, as a loop does."""
    closed = len(points) > 3 and np.allclose(points[0], points[-1], rtol=0.0, atol=1e-9)
    msp.add_lwpolyline(points[:-1] if closed else points, close=closed,
                       dxfattribs={"layer": layer})


def _dimension(msp, p1, p2, base, angle: float) -> None:
    dim = msp.add_linear_dim(base=base, p1=p1, p2=p2, angle=angle, dimstyle="EZDXF",
                             override=dict(DIMENSION_STYLE),
                             dxfattribs={"layer": "DIMENSIONS"})
    dim.render()


def _save(doc, path: Path) -> Path:
    import io

    buf = io.StringIO()
    doc.write(buf)
    write_atomic(path, buf.getvalue().encode("utf-8"))
    return path


def write_section_dxf(path: str | os.PathLike, sec: Section) -> Path:
    """Writes one section as DXF, millimetres.

    Parameters
    ----------
    path : str or os.PathLike
    sec : Section

    Returns
    -------
    pathlib.Path
        The file written: the curves as LWPOLYLINEs on their layers, the floor as a LINE, a
        DIMENSION of the surface's length along the section and one of its top's height above
        the floor, and a TEXT saying both.

    Raises
    ------
    DrawingError
        If the section misses the surface.
    """
    doc = _new_document()
    msp = doc.modelspace()
    for layer, lines in sec.curves.items():
        for line in lines:
            _polyline(msp, line * 1000.0, layer)
    box = sec.extent("SURFACE")
    if box is None:
        raise DrawingError(f"Section {sec.name!r} does not cut the surface")
    lo, hi = box[0] * 1000.0, box[1] * 1000.0
    msp.add_line((lo[0] - 50, 0), (hi[0] + 50, 0), dxfattribs={"layer": "FLOOR"})
    _dimension(msp, (lo[0], 0), (hi[0], 0), (0, -60), 0)
    top = np.concatenate(sec.curves["SURFACE"]) * 1000.0
    peak = top[np.argmax(top[:, 1])]
    _dimension(msp, (hi[0], 0), (hi[0], peak[1]), (hi[0] + 80, 0), 90)
    msp.add_text(f"{sec.name}: length {hi[0] - lo[0]:.0f} mm, top {peak[1]:.0f} mm above "
                 f"the floor (mm)", height=12,
                 dxfattribs={"layer": "DIMENSIONS"}).set_placement((lo[0], -110))
    return _save(doc, Path(path))


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """The border of a surface as loops of vertex indices, in its faces' direction.

    Parameters
    ----------
    faces : (F, 3) or (F, 4) int

    Returns
    -------
    list of (K + 1,) int
        Each loop with its first vertex repeated at the end.
    """
    from solver.io.solid import boundary_edges

    nxt = {int(a): int(b) for a, b in boundary_edges(faces)}
    loops = []
    while nxt:
        start, here = next(iter(nxt.items()))
        del nxt[start]
        loop = [start]
        while here != start and here in nxt:
            loop.append(here)
            here = nxt.pop(here)
        loops.append(np.array(loop + [start]))
    return loops


def overall_dimensions(vertices: np.ndarray) -> dict:
    """The surface's overall size.

    Parameters
    ----------
    vertices : (N, 3) float
        Metres, Y up.

    Returns
    -------
    dict
        `width_mm` (along x), `depth_mm` (along z) and `height_mm` (its top above the floor
        y = 0), millimetres.
    """
    v = np.asarray(vertices, dtype=np.float64) * 1000.0
    lo, hi = v.min(axis=0), v.max(axis=0)
    return {"width_mm": float(hi[0] - lo[0]), "depth_mm": float(hi[2] - lo[2]),
            "height_mm": float(hi[1])}


def silhouette(points: np.ndarray, triangles: np.ndarray) -> list[np.ndarray]:
    """The outline of a mesh seen along its points' third axis: what its triangles cover in
    the plane of the first two, as closed loops.

    The triangles facing the viewer form regions, as do those facing away; each region's
    projection is what its border loops (the region's own faces' direction, reversed for a
    region facing away) enclose with a positive winding number, so the union of all of them
    (manifold3d's polygon clipping, positive fill) is what the mesh covers: from a few
    thousand border edges, not from every triangle (a 300,000-triangle bench takes a fraction
    of a second). Triangles seen edge-on cover nothing and count on either side.

    Parameters
    ----------
    points : (N, 3) float
        The vertices in the drawing's frame: the first two axes the drawing's, the third
        towards the viewer.
    triangles : (F, 3) int, or (F, 4) quads (split along their 0-2 diagonal)

    Returns
    -------
    list of (K + 1, 2) float
        The outer outlines and the holes, each repeating its first point at its end.
    """
    import manifold3d

    t = np.asarray(triangles, dtype=np.int64)
    if t.ndim == 2 and t.shape[1] == 4:
        t = quad_triangles(t)
    p = np.asarray(points, dtype=np.float64)
    corners = p[t][:, :, :2]
    edge1, edge2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    facing = edge1[:, 0] * edge2[:, 1] - edge1[:, 1] * edge2[:, 0] >= 0.0
    loops = []
    for side in (facing, ~facing):
        tris = t[side] if side is facing else t[side][:, ::-1]  # (away: turned round)
        loops += _border_loops(tris, len(p))
    union = manifold3d.CrossSection([p[loop, :2] for loop in loops if len(loop) > 2],
                                    manifold3d.FillRule.Positive)
    return [np.concatenate([loop, loop[:1]]) for loop in union.to_polygons() if len(loop) > 2]


def _border_loops(tris: np.ndarray, n: int) -> list[np.ndarray]:
    """The closed loops of vertex indices that border a set of triangles (F, 3), each edge in
    its triangle's direction: the directed edges used more often than their reverse (as
    often as that), chained end to start (at a vertex where several loops meet, any
    continuation closes a loop)."""
    tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) &
                (tris[:, 2] != tris[:, 0])]  # (one with a corner twice covers nothing)
    if not len(tris):
        return []
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    # each directed edge as often as it is used more than its reverse (an edge three faces
    # share borders the region once, whichever comes first)
    keys, counts = np.unique(edges[:, 0] * n + edges[:, 1], return_counts=True)
    reverse = (keys % n) * n + keys // n
    at = np.minimum(np.searchsorted(keys, reverse), len(keys) - 1)
    against = np.where(keys[at] == reverse, counts[at], 0)
    extra = np.maximum(counts - against, 0)
    border = np.repeat(np.stack([keys // n, keys % n], axis=1), extra, axis=0)
    following: dict[int, list[int]] = {}
    for a, b in border.tolist():
        following.setdefault(a, []).append(b)
    loops = []
    for start in list(following):
        while following.get(start):
            loop, here = [start], following[start].pop()
            while here != start and following.get(here):
                loop.append(here)
                here = following[here].pop()
            loops.append(np.array(loop))
    return loops


def write_overall_dxf(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
                      gap: float = 200.0, what: str = "surface") -> dict:
    """Writes the plan (from above) and side elevation of a surface or solid as DXF,
    millimetres, Z up: its outline seen from above and from the side (`silhouette`) as closed
    polylines, the floor line, dimensions of width, depth and height.

    Parameters
    ----------
    path : the file to write.
    vertices : (N, 3) float, metres, Y up.
    faces : (F, 4) or (F, 3) int.
    gap : millimetres between the plan and the elevation.
    what : what the mesh is, for the drawing's text ("surface", "solid").

    Returns
    -------
    dict, `overall_dimensions` of the mesh.

    Raises
    ------
    DrawingError
        If the surface has no vertices or faces, or a vertex that is not finite.
    """
    v = np.asarray(vertices, dtype=np.float64) * 1000.0
    if v.ndim != 2 or v.shape[1:] != (3,) or not len(v) or not len(faces):
        raise DrawingError(f"Expected a surface of (N, 3) vertices and some faces, got "
                           f"{v.shape} and {np.shape(faces)}")
    if not np.all(np.isfinite(v)):
        raise DrawingError(f"Expected finite surface vertices, got "
                           f"{int(np.sum(~np.isfinite(v).all(axis=1)))} that are not")
    plan = np.stack([v[:, 0], -v[:, 2]], axis=1)  # workshop (X, Y) seen from above
    side = np.stack([-v[:, 2], v[:, 1]], axis=1)  # workshop (Y, Z) seen from +X
    shift = plan[:, 0].max() + gap - side[:, 0].min()
    side[:, 0] += shift
    doc = _new_document()
    msp = doc.modelspace()
    # the views as rotations of the scene (the third axis towards the viewer): from above,
    # (x, -z) with y; from +X, (-z, y) with x
    for view, depth in ((plan, v[:, 1]), (side, v[:, 0])):
        for loop in silhouette(np.column_stack([view, depth]), faces):
            _polyline(msp, loop, "SOLID" if what == "solid" else "SURFACE")
    (x0, y0), (x1, y1) = plan.min(axis=0), plan.max(axis=0)
    (s0, _), (s1, top) = side.min(axis=0), side.max(axis=0)
    _dimension(msp, (x0, y0), (x1, y0), (0, y0 - 60), 0)
    _dimension(msp, (x1, y0), (x1, y1), (x1 + 60, 0), 90)
    msp.add_line((s0 - 50, 0), (s1 + 50, 0), dxfattribs={"layer": "FLOOR"})
    _dimension(msp, (s1, 0), (s1, top), (s1 + 60, 0), 90)
    dims = overall_dimensions(vertices)
    msp.add_text(f"overall {dims['width_mm']:.0f} x {dims['depth_mm']:.0f} x "
                 f"{dims['height_mm']:.0f} mm (the {what}'s width x depth x height above the "
                 f"floor); plan and elevation Z up", height=14,
                 dxfattribs={"layer": "DIMENSIONS"}).set_placement((x0, y0 - 130))
    _save(doc, Path(path))
    return dims


SECTION_WIDTHS = {"SURFACE": 2.0, "BODY": 1.0, "SOLID": 0.8}  # line widths, points
FLOOR_COLOR = (0.3, 0.6, 0.3)


def _data_box(canvas_box, xlim, ylim):
    """The part of a pixel box that shows xlim x ylim at one scale both ways, centred (the
    box shrinks to the data's shape, as a drawing with equal aspect does)."""
    from solver.io.raster import Axes

    left, top, right, bottom = canvas_box
    dx, dy = max(xlim[1] - xlim[0], 1e-9), max(ylim[1] - ylim[0], 1e-9)
    scale = min((right - left) / dx, (bottom - top) / dy)
    cx, cy = (left + right) / 2, (top + bottom) / 2
    return Axes((cx - dx * scale / 2, cy - dy * scale / 2, cx + dx * scale / 2,
                 cy + dy * scale / 2), tuple(xlim), tuple(ylim))


def draw_section(canvas, box, sec: Section, title_size: float = 9) -> None:
    """Draws one section into a box of a canvas (`solver.io.raster.Canvas`; box: left, top,
    right, bottom pixels, the title written above it): millimetres along the section and above
    the floor, the floor as a line, one scale both ways, ticks and labels, titled with the
    surface's length and top.

    Parameters
    ----------
    canvas : solver.io.raster.Canvas
    box : (4,) float, pixels (room for the ticks and labels is kept inside it).
    sec : Section
    """
    from solver.io.raster import draw_frame
    from solver.io.render import SKIN, SURFACE

    colors = {"SURFACE": SURFACE, "BODY": tuple(0.8 * c for c in SKIN),
              "SOLID": (0.4, 0.4, 0.4)}
    lines = [(layer, line * 1000) for layer, group in sec.curves.items() for line in group]
    extent = sec.extent()
    pts = [line for _, line in lines]
    if extent is not None:
        pts.append(np.zeros((1, 2)))  # the floor's line is part of the drawing
    pts = np.concatenate(pts) if pts else np.zeros((1, 2))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    margin = 0.05 * np.maximum(hi - lo, 1.0)  # as a plot's automatic limits leave
    left, top, right, bottom = box
    axes = _data_box((left + 60, top, right - 10, bottom - 34),
                     (lo[0] - margin[0], hi[0] + margin[0]), (lo[1] - margin[1],
                                                             hi[1] + margin[1]))
    for layer, line in lines:
        canvas.line(axes.pixels(line[:, 0], line[:, 1]), colors.get(layer, (0, 0, 0)),
                    SECTION_WIDTHS.get(layer, 1.0))
    label = sec.name
    if extent is not None:
        canvas.line(axes.pixels(np.array(axes.xlim), [0.0, 0.0]), FLOOR_COLOR, 0.8)
        label += (f": {1000 * (extent[1][0] - extent[0][0]):.0f} mm long, top "
                  f"{1000 * extent[1][1]:.0f} mm")
    draw_frame(canvas, axes, "mm along the section", "mm above the floor")
    canvas.text(((left + right) / 2, axes.box[1] - 6), label, title_size, "md")


# square-on views of a surface: direction towards the camera, and what the picture's
# horizontal and vertical extents measure (`overall_dimensions` keys; "height_mm" from the floor)
ELEVATIONS = {
    "front": ((0.0, 0.0, 1.0), "width_mm", "height_mm"),
    "side": ((1.0, 0.0, 0.0), "depth_mm", "height_mm"),
    "top": ((0.0, 1.0, 0.0), "width_mm", "depth_mm"),
}
_ELEVATION_TITLES = {"front": "front (from +z)", "side": "side (from +x)",
                     "top": "top (plan)"}


def draw_elevation(canvas, box, vertices: np.ndarray, faces: np.ndarray, view: str,
                   floor: float = 0.0, title_size: float = 9, loops=None) -> dict:
    """Draws a surface alone, square-on, with its overall dimensions: shaded on both sides
    (its underside darker, so that a fold, an overhang or a curtain shows), its border as a
    line, the floor as a line in the front and side views, and dimension lines in millimetres:
    the width and height (front), the depth and height (side), the width and depth (top). The
    title goes above the drawing; the texts written are the title, then the two dimensions.

    Parameters
    ----------
    canvas : solver.io.raster.Canvas
    box : (left, top, right, bottom) pixels.
    vertices : (N, 3) float
        Metres, Y up.
    faces : (F, 4) or (F, 3) int
    view : str
        "front", "side" or "top" (`ELEVATIONS`).
    floor : float
        The floor's height y, metres (heights are given above it).
    loops : list of (K + 1,) int, optional
        The surface's `boundary_loops`, when the caller draws several views.

    Returns
    -------
    dict
        `overall_dimensions` of the vertices (the numbers written on the drawing), mm.

    Raises
    ------
    DrawingError
        For an unknown view.
    """
    from solver.io.render import SURFACE, MeshView, camera_axes, draw_meshes

    if view not in ELEVATIONS:
        raise DrawingError(f"Expected a view from {sorted(ELEVATIONS)}, got {view!r}")
    direction, across, upward = ELEVATIONS[view]
    mm = np.asarray(vertices, dtype=np.float64) * 1000.0
    right, up, _ = camera_axes(direction)
    flat = np.stack([mm @ right, mm @ up], axis=1)
    dims = overall_dimensions(np.asarray(vertices) - [0.0, floor, 0.0])
    (x0, y0), (x1, y1) = flat.min(axis=0), flat.max(axis=0)
    span = max(x1 - x0, y1 - y0, 1.0)
    gap = 0.08 * span
    low = floor * 1000.0 if upward == "height_mm" else y0
    xlim = (x0 - 1.6 * gap, x1 + 2.6 * gap)
    ylim = (min(y0, low) - 2.4 * gap, y1 + 0.8 * gap)
    frame = _data_box(box, xlim, ylim)
    canvas.text(((box[0] + box[2]) / 2, frame.box[1] - 6),
                f"{_ELEVATION_TITLES[view]}: {across[:-3]} {dims[across]:.0f}, "
                f"{upward[:-3]} {dims[upward]:.0f} mm", title_size, "md")
    proj = draw_meshes(canvas, frame.box, [MeshView(mm, faces, SURFACE,
                                                    back_color=(0.72, 0.62, 0.55))],
                       direction, bounds=((xlim[0], ylim[0]), (xlim[1], ylim[1])))
    for loop in boundary_loops(faces) if loops is None else loops:
        canvas.line(proj.plane(flat[loop]), (0.25, 0.25, 0.25), 0.7)
    if upward == "height_mm":
        canvas.line(proj.plane(np.array([[x0 - gap, low], [x1 + gap, low]])), FLOOR_COLOR, 1.0)
    _png_dimension(canvas, proj.plane(np.array([[x0, y0 - gap], [x1, y0 - gap]])),
                   f"{dims[across]:.0f}", below=True)
    _png_dimension(canvas, proj.plane(np.array([[x1 + gap, low], [x1 + gap, y1]])),
                   f"{dims[upward]:.0f}", below=False)
    return dims


def _png_dimension(canvas, ends: np.ndarray, text: str, below: bool) -> None:
    """A dimension line with arrows at both ends (pixels, (2, 2)) and its text: under a
    horizontal one (`below`), beside a vertical one."""
    canvas.arrow(ends[0], ends[1])
    middle = ends.mean(axis=0)
    if below:
        canvas.text((middle[0], middle[1] + 4), text, 8, "ma")
    else:
        canvas.text((middle[0] + 10, middle[1]), text, 8, rotate=True)


def render_sections(path: str | os.PathLike, sections: list[Section], *, columns: int = 2,
                    title: str | None = None) -> Path:
    """A PNG of sections, millimetres, floor at 0, one panel each (500 x 360 pixels).

    Parameters
    ----------
    path : str or os.PathLike
    sections : list of Section
    columns : int
    title : str, optional

    Returns
    -------
    pathlib.Path
        The picture written (atomically).
    """
    from solver.io.raster import Canvas

    if not sections:
        raise DrawingError("Expected at least one section to draw, got none")
    columns = min(columns, len(sections))
    rows = -(-len(sections) // columns)
    top = 40 if title else 0
    canvas = Canvas.blank(500 * columns, 360 * rows + 40)
    if title:
        canvas.text((250 * columns, 12), title, 12, "ma")
    for k, sec in enumerate(sections):
        x, y = 500 * (k % columns), top + 360 * (k // columns)
        draw_section(canvas, (x + 10, y + 40, x + 490, y + 350), sec)
    return canvas.save(path)
