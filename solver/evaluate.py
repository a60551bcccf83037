"""Evaluating a surface against a posed body, as a designer and a pressure mat would.

* coverage: the share of the body's importance within the margin of the surface;
* largest penetration: how deep the surface cuts into the body: the largest depth of a surface
  vertex inside the (closed) body mesh, by the winding number and the distance to the skin;
* a simulated pressure map: the body, with its estimated weight, settles straight down onto the
  surface as onto foam of a given stiffness (pressure = stiffness x how far the foam is pressed
  in, along the surface normal). The sinking depth is found so the vertical reactions carry the
  weight; the map gives peak and mean pressure (kPa), contact area and centre of pressure, the
  figures a pressure mat reports. Only the body parts the designer asked the surface to support
  take part. A vertex already behind the surface is pressed into the foam only where the surface
  cuts into the body (its closest surface point lies inside the body); otherwise it is on the
  surface's other side (an ankle under a seat's front edge) and not in contact. Muscles and the
  feet on the floor are what a mat cannot see, so the body does not tip: the model is a straight
  sinking.

The flat-seat baseline evaluates the same body on a horizontal plane at the height of the
fitted surface under the body's most important points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .subdivision import quad_triangles

G = 9.81
FOAM_DEPTH = 0.05  # metres: a body vertex deeper than this behind the surface is not in contact
MAX_SINK = 0.2  # metres: a body that needs to sink deeper than this is reported unsupported


@dataclass(frozen=True, eq=False)
class SurfaceMesh:
    """A triangle surface for distance queries: vertices (N, 3), triangles (F, 3), unit face
    normals (F, 3) pointing to the side bodies rest on."""

    vertices: np.ndarray
    triangles: np.ndarray
    face_normals: np.ndarray

    @classmethod
    def from_quads(cls, vertices: np.ndarray, quads: np.ndarray) -> "SurfaceMesh":
        tris = quad_triangles(quads)
        return cls.from_triangles(vertices, tris)

    @classmethod
    def from_triangles(cls, vertices: np.ndarray, triangles: np.ndarray) -> "SurfaceMesh":
        v = np.asarray(vertices, dtype=np.float64)
        t = np.asarray(triangles, dtype=np.int64)
        n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return cls(v, t, n)

    def closest(self, points: np.ndarray):
        """Unsigned distance (P,), signed distance along the closest face's normal (P,), whether
        the closest point lies inside its face (not on the surface's border) (P,), the closest
        face (P,) and the closest point (P, 3)."""
        import igl

        points = np.asarray(points, dtype=np.float64)
        sq, face, closest = igl.point_mesh_squared_distance(points, self.vertices, self.triangles)
        dist = np.sqrt(sq)
        offset = points - closest
        signed = np.einsum("ij,ij->i", offset, self.face_normals[face])
        # over the surface: the offset runs along the normal (not sideways off an edge)
        over = np.abs(signed) >= 0.95 * dist - 1e-9
        return dist, signed, over, face, closest


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


@dataclass(frozen=True, eq=False)
class PressureMap:
    """Per body vertex pressure (kPa) and the figures of a pressure mat."""

    pressure_kpa: np.ndarray
    peak_kpa: float
    mean_kpa: float
    contact_area_m2: float
    centre_of_pressure: list[float] | None
    sink_m: float
    supported: bool


def pressure_map(vertices: np.ndarray, normals: np.ndarray, areas: np.ndarray, mass_kg: float,
                 signed: np.ndarray, surface_normals: np.ndarray, over: np.ndarray,
                 stiffness_kpa_per_m: float, mask: np.ndarray | None = None,
                 cut_into_body: np.ndarray | None = None) -> PressureMap:
    """The body sinking straight down into foam until the vertical reactions carry its weight.

    signed : (V,) signed distance of each body vertex from the surface (positive: in front);
    surface_normals : (V, 3) the surface normal at each vertex's closest point;
    mask : (V,) bool, the vertices of the supported parts (all when None);
    cut_into_body : (V,) bool, whether each vertex's closest surface point lies inside the body
        (a vertex behind the surface counts only then).
    """
    k = stiffness_kpa_per_m * 1e3  # Pa per metre
    up = surface_normals[:, 1]
    facing = np.einsum("ij,ij->i", normals, surface_normals) < 0
    candidate = facing & over & (up > 1e-3) & (signed > -FOAM_DEPTH) & (signed < 0.5)
    if mask is not None:
        candidate &= mask
    if cut_into_body is not None:
        candidate &= (signed >= 0) | cut_into_body
    d, a, u = signed[candidate], areas[candidate], up[candidate]
    weight = mass_kg * G

    def lift(t: float) -> float:
        return float(np.sum(k * np.maximum(0.0, t * u - d) * a * u))

    zeros = np.zeros(len(vertices))
    if not candidate.any() or lift(MAX_SINK) < weight:
        return PressureMap(zeros, 0.0, 0.0, 0.0, None, MAX_SINK, False)
    lo, hi = -MAX_SINK, MAX_SINK
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if lift(mid) < weight:
            lo = mid
        else:
            hi = mid
    t = 0.5 * (lo + hi)
    p = np.zeros(len(vertices))
    p[candidate] = k * np.maximum(0.0, t * u - d)
    touching = p > 0
    force = p * areas
    cop = (force[:, None] * vertices).sum(axis=0) / force.sum()
    return PressureMap(
        p / 1e3, float(p.max() / 1e3),
        float(np.sum(p[touching] * areas[touching]) / np.sum(areas[touching]) / 1e3),
        float(areas[touching].sum()), [float(x) for x in cop], t, True,
    )


def penetration_depth(surface_points: np.ndarray, body_vertices: np.ndarray,
                      body_triangles: np.ndarray) -> float:
    """Largest depth (m) of the given surface points inside a closed body mesh (0 if none); the
    distance is exact, the inside test the fast winding number."""
    import igl

    signed = igl.signed_distance(np.asarray(surface_points, dtype=np.float64),
                                       np.asarray(body_vertices, dtype=np.float64),
                                       np.asarray(body_triangles, dtype=np.int64),
                                       igl.SIGNED_DISTANCE_TYPE_FAST_WINDING_NUMBER)[0]
    return float(max(0.0, -signed.min()))


def evaluate_person(surface: SurfaceMesh, vertices: np.ndarray, normals: np.ndarray,
                    areas: np.ndarray, importance: np.ndarray, mass_kg: float, margin: float,
                    stiffness_kpa_per_m: float, triangles: np.ndarray,
                    supported: np.ndarray | None = None) -> tuple[dict, PressureMap]:
    """Coverage, penetration and the pressure map of one body on one surface.

    vertices, normals, areas, importance : the posed body's per-vertex data; triangles : its
    closed skin, for the penetration depth; supported : (V,) bool, its supported parts.
    """
    import igl

    dist, signed, over, face, closest = surface.closest(vertices)
    total = importance.sum()
    coverage = float(importance[dist <= margin + 1e-9].sum() / total) if total > 0 else 0.0
    lo, hi = vertices.min(axis=0) - 0.01, vertices.max(axis=0) + 0.01
    near = np.all((surface.vertices >= lo) & (surface.vertices <= hi), axis=1)
    penetration = penetration_depth(surface.vertices[near], vertices, triangles) \
        if near.any() else 0.0
    cut = np.zeros(len(vertices), dtype=bool)
    behind = np.flatnonzero(signed < 0)
    if behind.size:
        wn = igl.fast_winding_number(np.asarray(vertices, dtype=np.float64),
                                     np.asarray(triangles, dtype=np.int64), closest[behind])
        cut[behind] = wn > 0.5
    pm = pressure_map(vertices, normals, areas, mass_kg, signed, surface.face_normals[face],
                      over, stiffness_kpa_per_m, supported, cut)
    figures = {
        "coverage": coverage,
        "max_penetration_m": penetration,
        "contact_area_m2": pm.contact_area_m2,
        "peak_pressure_kpa": pm.peak_kpa,
        "mean_pressure_kpa": pm.mean_kpa,
        "centre_of_pressure_m": pm.centre_of_pressure,
        "sink_m": pm.sink_m,
        "supported": pm.supported,
        "mean_support_distance_m": float(np.sum(importance * dist) / total) if total else None,
    }
    return figures, pm


def flat_seat_height(surface: SurfaceMesh, vertices: np.ndarray, importance: np.ndarray
                     ) -> float:
    """Height of the fitted surface under the body's most important tenth."""
    top = importance >= np.quantile(importance[importance > 0], 0.9) if (importance > 0).any() \
        else np.ones(len(importance), dtype=bool)
    import igl

    _, _, closest = igl.point_mesh_squared_distance(vertices[top], surface.vertices,
                                                    surface.triangles)
    return float(np.median(closest[:, 1]))


def flat_surface(height: float, centre: np.ndarray, half: float = 5.0) -> SurfaceMesh:
    """A horizontal square plane (two triangles) at `height`, facing up."""
    cx, cz = float(centre[0]), float(centre[2])
    v = np.array([[cx - half, height, cz - half], [cx - half, height, cz + half],
                  [cx + half, height, cz + half], [cx + half, height, cz - half]])
    return SurfaceMesh.from_quads(v, np.array([[0, 1, 2, 3]]))


def support_inside(vertices: np.ndarray, importance: np.ndarray,
                   others: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Share of a body's importance that lies inside other bodies (each given as vertices and
    its closed skin's triangles): support no surface can give, since a surface there would cut
    into the other person. Inside is a winding number above one half."""
    import igl

    total = float(importance.sum())
    wanted = np.flatnonzero(importance > 0)
    if total <= 0 or not wanted.size:
        return 0.0
    points = np.asarray(vertices[wanted], dtype=np.float64)
    lo, hi = points.min(axis=0), points.max(axis=0)
    inside = np.zeros(len(wanted), dtype=bool)
    for other, triangles in others:
        if np.any(other.max(axis=0) < lo) or np.any(other.min(axis=0) > hi):
            continue  # the boxes do not meet
        inside |= igl.fast_winding_number(np.asarray(other, dtype=np.float64),
                                          np.asarray(triangles, dtype=np.int64), points) > 0.5
    return float(importance[wanted][inside].sum() / total)
