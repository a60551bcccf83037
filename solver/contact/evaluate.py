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

from solver.contact.supported import SupportedBody
from solver.mesh import SurfaceMesh

G = 9.81
FOAM_DEPTH = 0.05  # metres: a body vertex deeper than this behind the surface is not in contact
MAX_SINK = 0.2  # metres: a body that needs to sink deeper than this is reported unsupported


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


def evaluate_person(surface: SurfaceMesh, person: SupportedBody, margin: float,
                    stiffness_kpa_per_m: float) -> tuple[dict, PressureMap]:
    """Coverage, penetration and the pressure map of one body on one surface.

    Parameters
    ----------
    surface : SurfaceMesh
        The surface, metres, its face normals towards the side bodies rest on.
    person : SupportedBody
        The posed body (V vertices, metres) with its importance, areas, closed skin (for the
        penetration depth), supported parts and mass; areas, triangles and mass_kg are
        required.
    margin : float
        Metres of softness the surface may sink into the body (coverage counts the importance
        within it).
    stiffness_kpa_per_m : float
        The foam's kPa per metre pressed in.

    Returns
    -------
    figures : dict
        The figures, lengths in metres, pressures in kPa, areas in m^2: ``coverage`` (share of
        the importance within `margin` of the surface, in [0, 1]), ``max_penetration_m``,
        ``contact_area_m2``, ``peak_pressure_kpa``, ``mean_pressure_kpa``,
        ``centre_of_pressure_m`` ((3,) list of metres, or None when unsupported), ``sink_m``
        (the sinking depth, metres, at which the reactions carry the weight; `MAX_SINK` when
        unsupported),
        ``supported`` (bool: the foam carries the body's weight within `MAX_SINK`) and
        ``mean_support_distance_m`` (importance-weighted mean distance to the surface, None
        without importance).
    pressure_map : PressureMap
        The simulated pressure mat: per body vertex pressure (V,) in kPa and the same figures.

    Raises
    ------
    ValueError
        If the person lacks areas, a closed skin or a mass.
    """
    import igl

    if person.areas is None or person.triangles is None or person.mass_kg is None:
        raise ValueError(f"{person.label}: an evaluation needs the body's areas, closed skin "
                         "and mass")
    vertices, importance, triangles = person.vertices, person.importance, person.triangles
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
    pm = pressure_map(vertices, person.normals, person.areas, person.mass_kg, signed,
                      surface.face_normals[face], over, stiffness_kpa_per_m, person.supported,
                      cut)
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


def flat_seat_height(surface: SurfaceMesh, person: SupportedBody) -> float:
    """Height of the fitted surface under the body's most important tenth."""
    vertices, importance = person.vertices, person.importance
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
