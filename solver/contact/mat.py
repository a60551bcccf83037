"""The figures a pressure mat reports, per support and per body region, and the 2-D map a mat
draped on each support would show.

A settled body touches each support (the fitted surface's seat and back, the floor, ...) at some
of its vertices; `SupportContact` records, per support, the force each of those vertices carries.
From those records and the body's Voronoi areas (pressure at a vertex = its normal force / its
area):

* `mat_figures`: per support and in total, the load (N and share of the body's weight m g), the
  peak pressure, the peak pressure index, the mean pressure, the contact area, the centre of
  pressure, a seat pressure distribution (contact area and load per pressure band, load on the
  two halves of the contact area each way) and the same figures per body region;
* `pressure_grid`: the contact's pressure binned into a mat's sensor cells (about `MAP_CELL_M`)
  over the support: on a fitted surface whose quads form a regular grid the cells follow that
  grid, measured by arc length (the mat is draped); on the floor, or a surface that is no
  grid, they are a regular grid on the support's plane. A cell's pressure is the normal force
  landing in it over its area, so the cells carry the contact's whole normal force;
* `write_pressure_csv` / `read_pressure_csv`: the maps as CSV grids in kPa, with comment headers.

Units: newtons, kPa, cm^2 in the figures (m^2 in arrays), metres; the frame is Y up (a map is
seen from the side the body rests on, its rows running along column axis x support normal).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from capture.files import write_atomic
from solver.body.model import BODY_REGIONS
from solver.kept import KeptByContent

# seat pressure distribution bands, kPa: [0, 2), [2, 4), ... [10, inf)
PRESSURE_BANDS_KPA = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0)
# published seated values (as the issue quotes them), for reports to compare with
SEATED_REFERENCE = {"seat_mean_kpa": 2.4, "seat_peak_kpa": 6.7,
                    "seat_contact_area_cm2": (308.0, 394.0),
                    "noticeable_change_kpa": (2.0, 3.5), "noticeable_at_kpa": (13.0, 26.0)}
MAP_CELL_M = 0.02  # metres: the largest side of a mat cell (mat sensors are 1-2 cm)
MAP_MARGIN_M = 0.03  # metres of unloaded mat shown around the loaded cells


G = 9.81
PEAK_AREA = 10e-4  # m^2: the peak pressure index averages over 10 cm^2, as seating studies do


def peak_pressure_index(vertices: np.ndarray, areas: np.ndarray, pressure: np.ndarray) -> float:
    """The highest area-weighted mean pressure over a disc of PEAK_AREA around a loaded vertex
    (the "peak pressure index" of seating research: a mat's 3 x 3 sensor cells)."""
    from scipy.spatial import cKDTree

    loaded = np.flatnonzero(pressure > 0)
    if not loaded.size:
        return 0.0
    radius = np.sqrt(PEAK_AREA / np.pi)
    tree = cKDTree(vertices[loaded])
    order = loaded[np.argsort(pressure[loaded])[::-1][:64]]  # the peak lies near a high vertex
    best = 0.0
    for i in order:
        near = loaded[tree.query_ball_point(vertices[i], radius)]
        best = max(best, float(np.sum(pressure[near] * areas[near]) / np.sum(areas[near])))
    return best


class MatError(ValueError):
    """Contact records or inputs the mat figures cannot take."""


@dataclass(frozen=True, eq=False)
class SupportContact:
    """The contact of one body with one support after the settle.

    name : str
        The support part it is reported as ("seat", "back", "floor", ...).
    vertices : (K,) int
        Body vertex indices in contact.
    normal_force : (K,) float
        Newtons, >= 0, along the support normal.
    tangential_force : (K, 3) float
        Newtons (friction), perpendicular to the normal.
    normals : (K, 3) float
        Unit support normals at the contact points, towards the body.
    points : (K, 3) float
        Metres, the contact points on the support.
    faces : (K,) int
        The support triangle each contact lies on (-1: the floor plane).
    areas : (K,) float, optional
        m^2, the skin's footprint on the support at each contact (its Voronoi area projected
        along the support normal), over which the settle spread the normal force.
    """

    name: str
    vertices: np.ndarray
    normal_force: np.ndarray
    tangential_force: np.ndarray
    normals: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    areas: np.ndarray | None = None

    def __post_init__(self) -> None:
        k = len(np.atleast_1d(self.vertices))
        shapes = {"vertices": (k,), "normal_force": (k,), "tangential_force": (k, 3),
                  "normals": (k, 3), "points": (k, 3), "faces": (k,)}
        if self.areas is not None:
            shapes["areas"] = (k,)
        for name, shape in shapes.items():
            kind = np.int64 if name in ("vertices", "faces") else np.float64
            value = np.asarray(getattr(self, name))
            if name in ("vertices", "faces") and value.size and \
                    not np.issubdtype(value.dtype, np.integer):
                raise MatError(f"{self.name}: expected integer {name}, got {value.dtype}")
            value = value.astype(kind).reshape(shape) if value.size == 0 else value.astype(kind)
            if value.shape != shape:
                raise MatError(f"{self.name}: expected {name} of shape {shape}, got "
                               f"{value.shape}")
            if kind is np.float64 and not np.isfinite(value).all():
                raise MatError(f"{self.name}: expected finite {name}, got NaN or inf")
            object.__setattr__(self, name, value)
        if k and self.normal_force.min() < 0:
            raise MatError(f"{self.name}: expected normal forces >= 0 N, got "
                           f"{self.normal_force.min()}")

    @property
    def force(self) -> np.ndarray:
        """(3,) newtons: the support's total force on the body (normal and friction)."""
        return (self.normal_force[:, None] * self.normals + self.tangential_force).sum(axis=0)


def _vertex_loads(contacts: Sequence[SupportContact], areas: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per body vertex in contact: the vertex (L,), its normal force (L,) N summed over the
    contacts, its contact point (L, 3) (normal-force weighted) and its area (L,) m^2."""
    verts = np.concatenate([c.vertices for c in contacts]) if contacts else np.zeros(0, int)
    force = np.concatenate([c.normal_force for c in contacts]) if contacts else np.zeros(0)
    points = np.concatenate([c.points for c in contacts]) if contacts else np.zeros((0, 3))
    if verts.size and (verts.min() < 0 or verts.max() >= len(areas)):
        raise MatError(f"Expected contact vertices in 0..{len(areas) - 1}, got "
                       f"{verts.min()}..{verts.max()}")
    unique, inv = np.unique(verts, return_inverse=True)
    total = np.bincount(inv, weights=force, minlength=len(unique))
    weight = np.where(total[inv] > 0, force / np.where(total[inv] > 0, total[inv], 1.0),
                      1.0 / np.bincount(inv)[inv])  # unloaded: the mean point
    point = np.stack([np.bincount(inv, weights=weight * points[:, k], minlength=len(unique))
                      for k in range(3)], axis=1)
    return unique, total, point, areas[unique]


def contact_figures(contacts: Sequence[SupportContact], areas: np.ndarray,
                    weight_n: float) -> dict:
    """The mat figures (as `mat_figures` gives them per support, without regions and
    distribution) of the given contacts together, a vertex on two of them counted once, over
    the body vertices' areas (V,) m^2."""
    _, force, points, area = _vertex_loads(contacts, areas)
    vector = np.sum([c.force for c in contacts], axis=0) if contacts else np.zeros(3)
    return _figures(force, points, area, vector, weight_n)


def _figures(force: np.ndarray, points: np.ndarray, area: np.ndarray, vector: np.ndarray,
             weight_n: float) -> dict:
    """The mat figures of vertices carrying normal forces (L,) N at points (L, 3) over areas
    (L,) m^2, whose total force vector is `vector` (3,) N."""
    loaded = force > 0
    pressure = force / area / 1e3
    area_m2 = float(area[loaded].sum())
    normal = float(force.sum())
    load = float(np.linalg.norm(vector))
    return {
        "load_n": load,
        "normal_load_n": normal,
        "vertical_load_n": float(vector[1]),
        "load_share": float(vector[1]) / weight_n,
        "peak_kpa": float(pressure.max()) if loaded.any() else 0.0,
        "peak_pressure_index_kpa": peak_pressure_index(points, area, pressure),
        "mean_kpa": normal / area_m2 / 1e3 if area_m2 > 0 else None,
        "contact_area_cm2": area_m2 * 1e4,
        "centre_of_pressure_m": [float(x) for x in force @ points / normal] if normal > 0
        else None,
    }


def _plane_axes(normal: np.ndarray, orientation: np.ndarray) -> list[tuple[np.ndarray, str, str]]:
    """Two orthonormal axes in the plane of `normal`: the first two of the body's forward, up
    and left (columns 2, 1, 0 of `orientation`) that still point clearly along the plane."""
    picked = []
    for column, names in ((2, ("front", "back")), (1, ("upper", "lower")),
                          (0, ("left", "right"))):
        axis = orientation[:, column] - (orientation[:, column] @ normal) * normal
        for other, _, _ in picked:
            axis = axis - (axis @ other) * other
        if np.linalg.norm(axis) >= 0.5:
            picked.append((axis / np.linalg.norm(axis), *names))
        if len(picked) == 2:
            break
    return picked


def _distribution(contact: SupportContact, force: np.ndarray, points: np.ndarray,
                  area: np.ndarray, orientation: np.ndarray) -> dict:
    """The seat pressure distribution of one support (see `mat_figures`)."""
    loaded = force > 0
    pressure = force[loaded] / area[loaded] / 1e3
    band = np.searchsorted(PRESSURE_BANDS_KPA, pressure, side="right") - 1
    nb = len(PRESSURE_BANDS_KPA)
    total = float(force.sum())
    band_area = np.bincount(band, weights=area[loaded], minlength=nb) * 1e4
    band_load = np.bincount(band, weights=force[loaded], minlength=nb)
    out = {
        "bands_kpa": [[lo, hi] for lo, hi in zip(PRESSURE_BANDS_KPA,
                                                 PRESSURE_BANDS_KPA[1:] + (None,))],
        "band_area_cm2": [float(a) for a in band_area],
        "band_load_share": [float(x / total) if total > 0 else 0.0 for x in band_load],
        "halves_about_m": None,
        "halves": {},
    }
    if total <= 0:
        return out
    normal = contact.normal_force @ contact.normals
    normal = normal / np.linalg.norm(normal)
    centre = area[loaded] @ points[loaded] / area[loaded].sum()
    out["halves_about_m"] = [float(x) for x in centre]
    for axis, plus, minus in _plane_axes(normal, orientation):
        side = (points[loaded] - centre) @ axis
        on_line = 0.5 * force[loaded][np.abs(side) < 1e-9].sum()
        out["halves"][plus] = float((force[loaded][side >= 1e-9].sum() + on_line) / total)
        out["halves"][minus] = float((force[loaded][side <= -1e-9].sum() + on_line) / total)
    return out


def _region_figures(contacts: Sequence[SupportContact], areas: np.ndarray, regions: np.ndarray,
                    names: Sequence[str], weight_n: float) -> dict:
    """Per region touching the contacts: its `_figures`."""
    out = {}
    present = np.unique(np.concatenate([regions[c.vertices] for c in contacts]))
    for r in present:
        parts = [SupportContact(c.name, c.vertices[keep], c.normal_force[keep],
                                c.tangential_force[keep], c.normals[keep], c.points[keep],
                                c.faces[keep])
                 for c in contacts for keep in [regions[c.vertices] == r] if keep.any()]
        _, force, points, area = _vertex_loads(parts, areas)
        out[str(names[r])] = _figures(force, points, area, sum(c.force for c in parts),
                                      weight_n)
    return out


def _support_figures(c: SupportContact, areas: np.ndarray, regions: np.ndarray | None,
                     region_names, weight_n: float, orientation: np.ndarray) -> dict:
    _, force, points, area = _vertex_loads([c], areas)
    if (area <= 0).any():
        raise MatError(f"{c.name}: expected contact vertices of area > 0 m^2")
    figures = _figures(force, points, area, c.force, weight_n)
    figures["distribution"] = _distribution(c, force, points, area, orientation)
    figures["regions"] = {} if regions is None or not len(c.vertices) else \
        _region_figures([c], areas, regions, region_names, weight_n)
    return figures


def _checked_regions(regions, names, areas: np.ndarray) -> tuple[np.ndarray, tuple]:
    regions = np.asarray(regions)
    if regions.shape != areas.shape:
        raise MatError(f"Expected regions of shape {areas.shape}, got {regions.shape}")
    names = BODY_REGIONS if names is None else tuple(names)
    if regions.size and (regions.min() < 0 or regions.max() >= len(names)):
        raise MatError(f"Expected region indices in 0..{len(names) - 1}, got "
                       f"{regions.min()}..{regions.max()}")
    return regions, names


def mat_figures(contacts: Sequence[SupportContact], areas: np.ndarray, mass_kg: float,
                regions: np.ndarray | None = None, region_names: Sequence[str] | None = None,
                *, orientation: np.ndarray | None = None) -> dict:
    """The figures a pressure mat reports, per support, per body region and in total.

    Parameters
    ----------
    contacts : sequence of SupportContact
        One record per support, each with its own name.
    areas : (V,) float
        The body's Voronoi areas, m^2 (pressure at a vertex = its normal force / its area).
    mass_kg : float
        The body's mass; load shares are of its weight m g (g = 9.81 m/s^2).
    regions : (V,) int, optional
        A body region index per vertex (`Body.regions`); no region figures without it.
    region_names : sequence of str, optional
        The regions' names (default `BODY_REGIONS`).
    orientation : (3, 3) float, optional
        The body's left, up and forward directions (its rest +X, +Y, +Z) in the world, as
        columns: the placement's rotation matrix (default identity). It names the halves of
        the pressure distribution.

    Returns
    -------
    dict
        JSON-ready (floats, lists, None where a figure is undefined, never NaN):
        ``body_weight_n``; ``supports``: per support name, ``load_n`` (magnitude of the
        support's total force, normal and friction, N), ``normal_load_n`` (N),
        ``vertical_load_n`` (its upward part, against gravity along -Y), ``load_share``
        (vertical_load_n / m g: the shares of the supports add up to 1 at rest),
        ``peak_kpa`` (largest vertex pressure),
        ``peak_pressure_index_kpa`` (the highest mean over about 10 cm^2 around a loaded
        vertex), ``mean_kpa`` (area-weighted over the loaded area: normal load / contact area;
        None without contact), ``contact_area_cm2`` (area of the vertices carrying load),
        ``centre_of_pressure_m`` ((3,) normal-force weighted contact point, or None),
        ``distribution`` and ``regions``; ``total``: the same figures over all supports (a
        vertex touching two supports carries both forces; its load_n is the magnitude of the
        supports' summed force, about m g once the body is in equilibrium) with its
        ``regions``. ``distribution`` holds ``bands_kpa`` (the PRESSURE_BANDS_KPA bands as
        [low, high] pairs, the last high None), ``band_area_cm2`` and ``band_load_share`` (the
        contact area and share of the support's normal load in each band), ``halves_about_m``
        (the loaded area's centroid, or None) and ``halves``: the share of the normal load on
        each side of that centroid along the body's forward ("front"/"back"), up
        ("upper"/"lower") or left ("left"/"right") direction, the first two of those that lie
        along the support (a seat and the floor: front/back and left/right; a backrest:
        upper/lower and left/right); a vertex on the line counts half to each side.
        ``regions`` maps each region name the contacts touch to ``load_n``, ``normal_load_n``,
        ``load_share``, ``peak_kpa``, ``peak_pressure_index_kpa``, ``mean_kpa``,
        ``contact_area_cm2`` and ``centre_of_pressure_m``, as above; it is empty without
        `regions`.

    Raises
    ------
    MatError
        If two contacts share a name, the mass is not positive, a contact vertex has no area
        (or none > 0), or the regions do not match the areas.
    """
    areas = np.asarray(areas, dtype=np.float64)
    names = [c.name for c in contacts]
    if len(set(names)) != len(names):
        raise MatError(f"Expected one contact per support, got names {names}")
    if not mass_kg > 0:
        raise MatError(f"Expected a body mass > 0 kg, got {mass_kg}")
    if regions is not None:
        regions, region_names = _checked_regions(regions, region_names, areas)
    orientation = np.eye(3) if orientation is None else np.asarray(orientation, dtype=float)
    weight_n = mass_kg * G
    supports = {c.name: _support_figures(c, areas, regions, region_names, weight_n,
                                         orientation) for c in contacts}
    _, force, points, area = _vertex_loads(list(contacts), areas)
    total = _figures(force, points, area, sum((c.force for c in contacts), np.zeros(3)),
                     weight_n)
    touched = [c for c in contacts if len(c.vertices)]
    total["regions"] = {} if regions is None or not touched else \
        _region_figures(touched, areas, regions, region_names, weight_n)
    return {"body_weight_n": weight_n, "supports": supports, "total": total}


KEPT_GRIDS = 8
_GRIDS = KeptByContent(KEPT_GRIDS)  # by the quads' content


def surface_grid(quads: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """`_surface_grid` of the quads, kept by their content (each support and each person of a
    fit asks for the same surface's; the grid is found in Python, face by face). The arrays
    are shared: not to be written to."""
    q = np.asarray(quads)
    kept = _GRIDS.entry(q)
    if "grid" not in kept:
        grid = _surface_grid(q)
        if grid is not None:
            for a in grid:
                a.setflags(write=False)
        kept["grid"] = grid
    return kept["grid"]


def _surface_grid(quads: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The (i, j) grid a quad mesh's faces form, if they form one.

    A Catmull-Clark surface of a regular R x C control grid is a regular grid of quads again
    (each step splits each quad in four), but its faces are listed corner by corner, not row
    by row; this recovers the rows and columns from the topology alone.

    Parameters
    ----------
    quads : (F, 4) int
        The faces.

    Returns
    -------
    (vertex_grid, face_grid) or None
        vertex_grid (R + 1, C + 1) int: the vertex at each grid node; face_grid (R, C) int: the
        face of each cell, whose corners are the nodes (i, j), (i + 1, j), (i, j + 1) and
        (i + 1, j + 1). None when the faces are not one topological rectangle of quads (a
        hole, an irregular vertex, a non-manifold edge). The first row and column start at an
        arbitrary corner.
    """
    q = np.asarray(quads)
    if q.ndim != 2 or q.shape[1] != 4 or not len(q) or q.min() < 0:
        return None
    edge_faces: dict[tuple[int, int], list[int]] = {}
    for f, quad in enumerate(q.tolist()):
        for k in range(4):
            a, b = quad[k], quad[k - 3]
            edge_faces.setdefault((a, b) if a < b else (b, a), []).append(f)
    if max(len(fs) for fs in edge_faces.values()) > 2:
        return None
    counts = np.bincount(q.ravel())
    corners = np.flatnonzero(counts == 1)
    if len(corners) != 4:
        return None
    rows = q.tolist()

    def beside(face: int, x: int, y: int) -> int:
        """The corner of `face` next to x that is not y."""
        quad = rows[face]
        k = quad.index(x)
        return quad[k - 3] if quad[k - 1] == y else quad[k - 1]

    def across(face: int, x: int, y: int) -> int | None:
        others = [g for g in edge_faces.get((x, y) if x < y else (y, x), ()) if g != face]
        return others[0] if others else None

    first = int(np.flatnonzero((q == corners[0]).any(axis=1))[0])
    quad = rows[first]
    k = quad.index(int(corners[0]))
    top, bottom, cells = [quad[k], quad[k - 3]], [quad[k - 1], quad[k - 2]], [first]
    while (nxt := across(cells[-1], top[-1], bottom[-1])) is not None:
        if len(cells) >= len(q):
            return None  # a strip that closes on itself
        top.append(beside(nxt, top[-1], bottom[-1]))
        bottom.append(beside(nxt, bottom[-1], top[-2]))
        cells.append(nxt)
    vertex_rows, face_rows = [top, bottom], [cells]
    while True:
        upper, below = vertex_rows[-1], face_rows[-1]
        nxt = [across(f, upper[j], upper[j + 1]) for j, f in enumerate(below)]
        if all(f is None for f in nxt):
            break
        if any(f is None for f in nxt) or len(face_rows) * len(below) >= len(q):
            return None
        new = [beside(f, upper[j], upper[j + 1]) for j, f in enumerate(nxt)]
        new.append(beside(nxt[-1], upper[-1], upper[-2]))
        vertex_rows.append(new)
        face_rows.append(nxt)
    vertex_grid, face_grid = np.array(vertex_rows), np.array(face_rows)
    if face_grid.size != len(q) or len(np.unique(face_grid)) != len(q):
        return None
    corners_ok = np.sort(q[face_grid], axis=-1) == np.sort(np.stack(
        [vertex_grid[:-1, :-1], vertex_grid[1:, :-1], vertex_grid[:-1, 1:],
         vertex_grid[1:, 1:]], axis=-1), axis=-1)
    return (vertex_grid, face_grid) if corners_ok.all() else None


@dataclass(frozen=True, eq=False)
class PressureGrid:
    """A pressure mat's reading of one support: R rows x C columns of cells.

    name : str
        The support.
    pressure_kpa : (R, C) float
        kPa: the normal force landing in each cell over its area, 0 where nothing presses.
    cell_area_m2 : (R, C) float
        Each cell's area on the support as the body presses it, m^2: its area on the surface,
        or where a hollow gathers more of the body's skin onto the cell than that (sunk skin's
        closest points crowd towards the middle of a hollow), the area of the skin pressing on
        it (`pressure_grid` with areas): a mat lying on the pressed foam takes the skin's
        shape, and its cell reads the skin's mean pressure there.
    row_edges_m, column_edges_m : (R + 1,) and (C + 1,) float
        The cells' edges, metres: along the mat from its first row / column (arc length) when
        draped; coordinates along `row_axis` / `column_axis` from the world origin on a plane.
    centres_m : (R, C, 3) float
        World positions of the cells' centres, metres.
    row_axis, column_axis : (3,) float
        Unit world directions of increasing row and column (on a draped mat, their mean over
        the map). Seen from the body's side, columns run left to right and rows top to bottom.
    draped : bool
        Whether the cells follow the surface's own grid (else they lie on a plane).
    """

    name: str
    pressure_kpa: np.ndarray
    cell_area_m2: np.ndarray
    row_edges_m: np.ndarray
    column_edges_m: np.ndarray
    centres_m: np.ndarray
    row_axis: np.ndarray
    column_axis: np.ndarray
    draped: bool

    @property
    def normal_load_n(self) -> float:
        """The normal force the cells carry, N."""
        return float(np.sum(self.pressure_kpa * 1e3 * self.cell_area_m2))

    @property
    def cell_size_m(self) -> tuple[float, float]:
        """The cells' median (height along the rows, width along the columns), metres."""
        if not self.pressure_kpa.size:
            return (0.0, 0.0)
        return (float(np.median(np.diff(self.row_edges_m))),
                float(np.median(np.diff(self.column_edges_m))))


def _barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(K, 3) barycentric coordinates of points (K, 3) in triangles (K, 3, 3)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2, d = b - a, c - a, points - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    p1, p2 = (d * e1).sum(1), (d * e2).sum(1)
    det = np.maximum(d11 * d22 - d12 * d12, 1e-300)
    v = (d22 * p1 - d12 * p2) / det
    w = (d11 * p2 - d12 * p1) / det
    return np.stack([1 - v - w, v, w], axis=1)


def _bilinear_nodes(corners: np.ndarray, kr: int, kc: int) -> np.ndarray:
    """(R kr + 1, C kc + 1, 3) nodes splitting each cell of a node grid (R + 1, C + 1, 3) into
    kr x kc, bilinearly."""
    s = (np.arange(kr + 1) / kr)[:, None, None]
    u = (np.arange(kc + 1) / kc)[None, :, None]
    p = (corners[:-1, :-1, None, None] * (1 - s) * (1 - u) + corners[1:, :-1, None, None] * s
         * (1 - u) + corners[:-1, 1:, None, None] * (1 - s) * u
         + corners[1:, 1:, None, None] * s * u)  # (R, C, kr + 1, kc + 1, 3)
    r, c = p.shape[:2]
    nodes = np.empty((r * kr + 1, c * kc + 1, 3))
    nodes[:-1, :-1] = p[:, :, :kr, :kc].transpose(0, 2, 1, 3, 4).reshape(r * kr, c * kc, 3)
    nodes[-1, :-1] = p[-1, :, kr, :kc].reshape(c * kc, 3)
    nodes[:-1, -1] = p[:, -1, :kr, kc].reshape(r * kr, 3)
    nodes[-1, -1] = p[-1, -1, kr, kc]
    return nodes


def _below_diagonal(x0, x1, y0, y1):
    """Area of {(x, y) in [x0, x1] x [y0, y1] : y < x} (arrays broadcast)."""
    h = y1 - y0

    def integral(t):  # of clip(s, 0, h) ds from -inf to t
        return np.where(t <= 0, 0.0, np.where(t <= h, t * t / 2, h * h / 2 + h * (t - h)))

    return integral(x1 - y0) - integral(x0 - y0)


def _draped_cells(contact: SupportContact, vertices: np.ndarray, quads: np.ndarray,
                  grid: tuple[np.ndarray, np.ndarray], cell_m: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contact points' places (K, 2) in cell units (row, column), the cells' areas (m^2)
    and nodes of the surface's quad grid with each quad split kr x kc (the least that makes
    cells at most `cell_m` each way). A point's place follows from where it lies in its
    triangle, mapped onto the quad's unit square piecewise linearly (the two triangles onto
    its two halves); a cell's area is its share of the two triangles' areas under that map."""
    from solver.mesh import face_cross

    vertex_grid, face_grid = grid
    n_faces, (rows, cols) = len(quads), face_grid.shape
    if contact.faces.min() < 0 or contact.faces.max() >= 2 * n_faces:
        raise MatError(f"{contact.name}: expected surface triangles in 0..{2 * n_faces - 1}, "
                       f"got {contact.faces.min()}..{contact.faces.max()}")
    fi, fj = np.empty(n_faces, int), np.empty(n_faces, int)
    fi[face_grid], fj[face_grid] = np.indices(face_grid.shape)
    vi, vj = np.zeros(len(vertices), int), np.zeros(len(vertices), int)
    vi[vertex_grid], vj[vertex_grid] = np.indices(vertex_grid.shape)
    local = np.stack([vi[quads] - fi[:, None], vj[quads] - fj[:, None]], axis=-1)  # (F, 4, 2)
    nodes = vertices[vertex_grid]
    kr, kc = (max(1, int(np.ceil(np.median(np.linalg.norm(np.diff(nodes, axis=a), axis=-1))
                                 / cell_m - 1e-9))) for a in (0, 1))
    quad, second = contact.faces % n_faces, contact.faces >= n_faces
    pick = np.where(second[:, None], [0, 2, 3], [0, 1, 2])
    bary = _barycentric(contact.points, vertices[quads[quad[:, None], pick]])
    at = np.einsum("kc,kcd->kd", bary, local[quad[:, None], pick])
    place = np.stack([(fi[quad] + at[:, 0]) * kr, (fj[quad] + at[:, 1]) * kc], axis=1)
    # each cell's part of the quad's half that triangle (0, 1, 2) maps onto
    a, b = np.indices((kr, kc))
    x0, x1, y0, y1 = a / kr, (a + 1) / kr, b / kc, (b + 1) / kc
    l0, l1 = local[:, 0], local[:, 1]
    main = (l0[:, 0] == l0[:, 1])[:, None, None]
    below = np.where(main, _below_diagonal(x0, x1, y0, y1),
                     _below_diagonal(1 - x1, 1 - x0, y0, y1))  # y < x, or y < 1 - x
    first_below = np.where(main[:, 0, 0], l1[:, 1] < l1[:, 0], l1[:, 1] < 1 - l1[:, 0])
    cell_param = 1.0 / (kr * kc)
    part = np.where(first_below[:, None, None], below, cell_param - below)
    tri_area = 0.5 * np.linalg.norm(face_cross(vertices, np.concatenate(
        [quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])), axis=1)
    cell = 2 * (tri_area[:n_faces, None, None] * part
                + tri_area[n_faces:, None, None] * (cell_param - part))
    area = np.zeros((rows * kr, cols * kc))
    area[fi[:, None, None] * kr + a, fj[:, None, None] * kc + b] = cell
    return place, area, _bilinear_nodes(nodes, kr, kc)


def _plane_cells(contact: SupportContact, normal: np.ndarray, across: np.ndarray,
                 cell_m: float, margin_m: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contact points' places (K, 2) in cell units (row, column), the cells' areas (m^2)
    and nodes of a square grid of `cell_m` cells on the plane through the contact along
    `normal`, aligned with `across`, over the loaded points and `margin_m` around them (cell
    edges at whole multiples of `cell_m`)."""
    u = across - (across @ normal) * normal
    if np.linalg.norm(u) < 0.5:
        u = np.eye(3)[np.argmin(np.abs(normal))] - normal * normal[np.argmin(np.abs(normal))]
    u /= np.linalg.norm(u)
    w = np.cross(u, normal)
    loaded = contact.normal_force > 0
    cu, cw = contact.points @ u, contact.points @ w
    lo = np.floor((np.array([cw[loaded].min(), cu[loaded].min()]) - margin_m) / cell_m) * cell_m
    hi = np.ceil((np.array([cw[loaded].max(), cu[loaded].max()]) + margin_m) / cell_m) * cell_m
    rows, cols = np.maximum(1, np.round((hi - lo) / cell_m).astype(int))
    place = np.stack([(cw - lo[0]) / cell_m, (cu - lo[1]) / cell_m], axis=1)
    force = contact.normal_force[loaded]
    height = float(force @ (contact.points[loaded] @ normal) / force.sum())
    ii, jj = np.indices((rows + 1, cols + 1))
    nodes = (height * normal + (lo[0] + ii[..., None] * cell_m) * w
             + (lo[1] + jj[..., None] * cell_m) * u)
    return place, np.full((rows, cols), cell_m**2), nodes


def _splat(place: np.ndarray, force: np.ndarray, half: np.ndarray | None,
           shape: tuple[int, int]) -> np.ndarray:
    """(R, C) force per cell: each point's force spread evenly over a box of half-widths
    `half` (K, 2) cells about its place (K, 2) (a point load without `half`), each cell
    taking the box's overlap with it; a box reaching past the grid's edge is renormalised to
    the cells it covers, so the cells carry the whole force. With `half`, `force` (K, m)
    spreads m quantities over the same boxes at once: (R, C, m)."""
    rows, cols = shape
    place = np.clip(place, 0, np.array([rows, cols]) - 1e-9)
    if half is None:
        cell = place.astype(int)
        return np.bincount(cell[:, 0] * cols + cell[:, 1], weights=force,
                           minlength=rows * cols).reshape(shape)
    values = force[:, None] if force.ndim == 1 else force
    half = np.maximum(half, 1e-6)
    reach = int(min(6, np.ceil(half.max()) + 1))
    offsets = np.arange(-reach, reach + 1)
    weights, indices = [], []
    for axis, n in ((0, rows), (1, cols)):
        idx = np.floor(place[:, axis])[:, None].astype(int) + offsets  # (K, O)
        lo, hi = place[:, axis, None] - half[:, axis, None], place[:, axis, None] + \
            half[:, axis, None]
        overlap = np.clip(np.minimum(idx + 1, hi) - np.maximum(idx, lo), 0, None)
        overlap[(idx < 0) | (idx >= n)] = 0.0
        weights.append(overlap)
        indices.append(np.clip(idx, 0, n - 1))
    w = weights[0][:, :, None] * weights[1][:, None, :]
    w = (w / w.sum(axis=(1, 2), keepdims=True)).ravel()
    cell = (indices[0][:, :, None] * cols + indices[1][:, None, :]).ravel()
    per = w.size // len(values)  # (each point's box cells)
    spread = np.stack([np.bincount(cell, weights=w * np.repeat(v, per), minlength=rows * cols)
                       for v in values.T], axis=-1).reshape(rows, cols, -1)
    return spread[..., 0] if force.ndim == 1 else spread


def _orient(force: np.ndarray, area: np.ndarray, nodes: np.ndarray, normal: np.ndarray,
            across: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cells transposed and flipped so that columns run along `across` and rows along
    column axis x normal (seen from the body's side, left to right and top to bottom)."""
    def steps(n):
        return (np.diff(n, axis=0).reshape(-1, 3).mean(axis=0),
                np.diff(n, axis=1).reshape(-1, 3).mean(axis=0))

    row_step, col_step = steps(nodes)
    if abs(row_step @ across) > abs(col_step @ across):
        force, area, nodes = force.T, area.T, nodes.transpose(1, 0, 2)
        row_step, col_step = col_step, row_step
    if col_step @ across < 0:
        force, area, nodes = force[:, ::-1], area[:, ::-1], nodes[:, ::-1]
        col_step = -col_step
    if row_step @ np.cross(col_step, normal) < 0:
        force, area, nodes = force[::-1], area[::-1], nodes[::-1]
    return force, area, nodes


def _crop(force: np.ndarray, area: np.ndarray, nodes: np.ndarray, margin_m: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cells over the loaded ones and about `margin_m` around them."""
    spans = []
    for axis in (0, 1):
        loaded = np.flatnonzero(force.any(axis=1 - axis))
        size = np.median(np.linalg.norm(np.diff(nodes, axis=axis), axis=-1))
        extra = int(np.ceil(margin_m / max(size, 1e-9) - 1e-9))
        spans.append(slice(max(0, loaded[0] - extra),
                           min(force.shape[axis], loaded[-1] + 1 + extra)))
    rows, cols = spans
    return force[rows, cols], area[rows, cols], \
        nodes[rows.start:rows.stop + 1, cols.start:cols.stop + 1]


def pressure_grid(contact: SupportContact, surface_vertices: np.ndarray | None = None,
                  surface_faces: np.ndarray | None = None, areas: np.ndarray | None = None,
                  *, cell_m: float = MAP_CELL_M,
                  margin_m: float = MAP_MARGIN_M,
                  across: Sequence[float] = (1.0, 0.0, 0.0)) -> PressureGrid:
    """The contact's pressure as a pressure mat draped on its support would read it.

    Parameters
    ----------
    contact : SupportContact
        One support's contact (its `faces` index the triangles of `surface_faces` split along
        each quad's 0-2 diagonal, `solver.mesh.quad_triangles`; all -1 on the floor).
    surface_vertices : (N, 3) float, optional
        The support surface, metres (not needed on the floor).
    surface_faces : (F, 4) int, optional
        Its quads.
    areas : (V,) float, optional
        The body's Voronoi areas, m^2. With them each contact's force is spread evenly over a
        square of its vertex's area about its point, as the skin presses on a mat (each cell
        takes the square's overlap with it); without them each force lands in the cell of its
        point (a point load: a sparse, speckled map).
    cell_m : float, default MAP_CELL_M
        The largest side of a cell, metres. A draped mat's cells are the surface's quads, each
        split into k x k (k the least that keeps the cells at most `cell_m`); a plane mat's
        cells are `cell_m` squares.
    margin_m : float, default MAP_MARGIN_M
        Metres of unloaded cells kept around the loaded ones (the map is cropped to them).
    across : (3,) float, default +X
        The world direction the columns follow (as near as the grid allows).

    Returns
    -------
    PressureGrid
        The cells (R, C), in kPa. Draped when the contact lies on a surface whose quads form a
        regular grid (`surface_grid`); otherwise the cells are squares on the plane through the
        contact along its mean normal (normal-force weighted), and a cell's area is its
        projected one: on the floor that is the (x, z) plane, rows along +Z and columns along
        +X. Without load the grid has no cells.

    Raises
    ------
    MatError
        If the contact lies on surface triangles but no surface is given, or its triangles
        are not the surface's, or `cell_m` is not positive.
    """
    if not cell_m > 0:
        raise MatError(f"Expected a cell size > 0 m, got {cell_m}")
    across = np.asarray(across, dtype=float)
    across = across / np.linalg.norm(across)
    loaded = contact.normal_force > 0
    if not loaded.any():
        empty = np.zeros((0, 0))
        return PressureGrid(contact.name, empty, empty, np.zeros(1), np.zeros(1),
                            np.zeros((0, 0, 3)), np.zeros(3), np.zeros(3), False)
    normal = contact.normal_force @ contact.normals
    normal = normal / np.linalg.norm(normal)
    on_floor = bool((contact.faces < 0).all())
    if not on_floor and (surface_vertices is None or surface_faces is None):
        raise MatError(f"{contact.name}: the contact lies on surface triangles; expected the "
                       "surface's vertices and faces")
    grid = None if on_floor else surface_grid(surface_faces)
    if grid is not None:
        place, area, nodes = _draped_cells(contact, np.asarray(surface_vertices, dtype=float),
                                           np.asarray(surface_faces), grid, cell_m)
    else:
        place, area, nodes = _plane_cells(contact, normal, across, cell_m, margin_m)
    half = None
    if areas is not None:
        areas = np.asarray(areas, dtype=float)
        if contact.vertices.max() >= len(areas):
            raise MatError(f"{contact.name}: expected areas for vertices up to "
                           f"{contact.vertices.max()}, got {len(areas)}")
        size = [np.median(np.linalg.norm(np.diff(nodes, axis=a), axis=-1)) for a in (0, 1)]
        footprint = areas[contact.vertices[loaded]]
        half = 0.5 * np.sqrt(footprint)[:, None] / np.array(size)
        # the force and the skin's area pressing on each cell, spread over the same boxes:
        # where a concave surface gathers sunk skin onto a cell (a closest point moves towards
        # the middle of the hollow) more skin than the cell's own area presses it, and the
        # cell, as pressed, takes the skin's area (a mat lying on the pressed foam reads the
        # skin's mean pressure there)
        both = _splat(place[loaded], np.stack([contact.normal_force[loaded], footprint], 1),
                      half, area.shape)
        force, area = both[..., 0], np.maximum(area, both[..., 1])
    else:
        force = _splat(place[loaded], contact.normal_force[loaded], None, area.shape)
    force, area, nodes = _orient(force, area, nodes, normal, across)
    return _grid(contact.name, *_crop(force, area, nodes, margin_m), grid is not None)


def _grid(name: str, force: np.ndarray, area: np.ndarray, nodes: np.ndarray, draped: bool
          ) -> PressureGrid:
    """The PressureGrid of cells carrying force (R, C) N over areas (as pressed) (R, C) m^2
    with nodes (R + 1, C + 1, 3)."""
    centres = 0.25 * (nodes[:-1, :-1] + nodes[1:, :-1] + nodes[:-1, 1:] + nodes[1:, 1:])
    row_axis = np.diff(nodes, axis=0).reshape(-1, 3).mean(axis=0)
    col_axis = np.diff(nodes, axis=1).reshape(-1, 3).mean(axis=0)
    row_axis, col_axis = row_axis / np.linalg.norm(row_axis), col_axis / np.linalg.norm(col_axis)
    if draped:  # arc length along the mat, the mean over its rows or columns
        row_edges = np.concatenate([[0.0], np.cumsum(np.linalg.norm(
            np.diff(nodes, axis=0), axis=-1).mean(axis=1))])
        col_edges = np.concatenate([[0.0], np.cumsum(np.linalg.norm(
            np.diff(nodes, axis=1), axis=-1).mean(axis=0))])
    else:
        row_edges, col_edges = nodes[:, 0] @ row_axis, nodes[0] @ col_axis
    pressure = np.divide(force, area, out=np.zeros_like(force), where=area > 0) / 1e3
    return PressureGrid(name, pressure, area, row_edges, col_edges, centres, row_axis, col_axis,
                        draped)


def _csv_block(grid: PressureGrid) -> str:
    rows, cols = grid.pressure_kpa.shape
    height, width = grid.cell_size_m
    kind = "draped on the surface, edges by arc length along the mat" if grid.draped else \
        "on a plane, edges as coordinates along the row and column axes"
    vec = ", ".join
    lines = [
        f"# pressure map: {grid.name}",
        f"# units: kPa per cell; {rows} rows x {cols} columns; cells about "
        f"{height * 100:.2f} x {width * 100:.2f} cm ({kind})",
        f"# rows run along ({vec(f'{x:.3f}' for x in grid.row_axis)}), columns along "
        f"({vec(f'{x:.3f}' for x in grid.column_axis)}) (world, Y up)",
        f"# row edges (m): {' '.join(f'{x:.4f}' for x in grid.row_edges_m)}",
        f"# column edges (m): {' '.join(f'{x:.4f}' for x in grid.column_edges_m)}",
        f"# normal force {grid.normal_load_n:.2f} N, peak cell "
        f"{float(grid.pressure_kpa.max()) if grid.pressure_kpa.size else 0.0:.3f} kPa",
    ]
    buf = io.StringIO()
    if grid.pressure_kpa.size:
        np.savetxt(buf, grid.pressure_kpa, fmt="%.4f", delimiter=",")
    return "\n".join(lines) + "\n" + buf.getvalue()


def write_pressure_csv(path: str | os.PathLike, grids: PressureGrid | Sequence[PressureGrid]
                       ) -> None:
    """Writes pressure maps as CSV grids (kPa), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    grids : PressureGrid or sequence of PressureGrid
        One map (the file then reads back with ``numpy.loadtxt(path, delimiter=",")``), or
        several, one block each after its own ``# pressure map: NAME`` header, blocks
        separated by a blank line (`read_pressure_csv` reads them all).

    Returns
    -------
    None
        Each block: comment lines (``#``) naming the support, the units (kPa), the number and
        size of the cells, the row and column directions, the cell edges (m) and the normal
        force (N), then one line per row of comma-separated pressures, kPa.
    """
    grids = [grids] if isinstance(grids, PressureGrid) else list(grids)
    write_atomic(path, "\n".join(_csv_block(g) for g in grids).encode())


def read_pressure_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The maps of a `write_pressure_csv` file.

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.

    Returns
    -------
    dict
        Support name -> (R, C) float pressure grid, kPa, in the file's order.
    """
    maps: dict[str, list[list[float]]] = {}
    name = None
    for line in open(path, encoding="utf-8").read().splitlines():
        if line.startswith("# pressure map: "):
            name = line[len("# pressure map: "):]
            maps[name] = []
        elif line.strip() and not line.startswith("#"):
            if name is None:
                raise MatError(f"{path}: expected a '# pressure map: NAME' line before the "
                               "values")
            maps[name].append([float(x) for x in line.split(",")])
    return {k: np.array(v, dtype=float).reshape(len(v), -1) for k, v in maps.items()}
