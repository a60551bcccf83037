"""Evaluating a surface against a posed body, as a designer and a pressure mat would.

* coverage: the share of the body's importance within the margin of the surface, on either
  side; contact coverage: the share in contact, within `CONTACT_GAP` in front of the surface
  or sunk into it (where it cuts into the body) by up to the margin;
* largest penetration: how deep the surface cuts into the body: the largest depth of a surface
  vertex inside the (closed) body mesh, by the winding number and the distance to the skin;
* the settle: the body, with its estimated weight, comes to rest in static equilibrium on the
  surface's foam and the floor (`solver.contact.settle`): force and moment balance, friction
  within its cone. Its contact forces give the pressure on the skin (kPa), the load each support
  carries, and the figures a pressure mat reports (peak, peak pressure index, mean, contact
  area, centre of pressure). A body vertex behind the surface presses the foam only where the
  surface cuts into the body (its closest surface point lies inside the body); otherwise it is
  on the surface's other side (an ankle under a seat's front edge) and not in contact. A body
  that does not come to rest (it tips over, slides off) is reported as such, without pressure
  figures.

The flat-seat baseline evaluates the same body on a horizontal plane at the height of the
fitted surface under the body's most important points; a seated body seldom rests on it (it tips
back), so the peak pressure a shaped seat is judged against is the flat seat's at the same
load (`flat_at_same_load`): the plane in the fitted seat's place, pressed up under the body held
as it rests on the fitted surface, until it carries what that seat carries.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from solver.contact.mat import SupportContact, contact_figures, mat_figures
from solver.contact.ratios import ratio_text
from solver.contact.settle import TOUCHING, UP, Foam, Settled, Support, reach_depth, settle
from solver.contact.skins import body_closest, body_winding, vertex_tree
from solver.contact.supported import SupportedBody
from solver.mesh import SurfaceMesh
from solver.threads import with_limited_threads

FLOOR = Foam(stiffness=30000e3, thickness=0.02)  # a hard floor under shoes and heels
CONTACT_GAP = 0.005  # metres in front of the surface a body point counts as touching it
FACING_REACH = 0.1  # metres: supported skin this near a surface tells which way the surface faces
DEPTH_BATCH = 256  # surface points `penetration_depth` tests for inside at once


@dataclass(frozen=True, eq=False)
class PressureMap:
    """Per body vertex pressure (V,) in kPa, and the settle it comes from."""

    pressure_kpa: np.ndarray
    settled: Settled


LEG_REGIONS = ("thighs", "calves", "feet")
SURFACE_PARTS = ("seat", "back", "leg rest")  # the names `surface_parts` gives contacts
STEEP = np.cos(np.radians(45.0))  # a support steeper than 45 degrees is no seat
MAX_REGION_ROUNDS = 5  # times the flat seat's regions are sought again (`flat_at_same_load`)


def surface_parts(regions: np.ndarray | None):
    """The names of a fitted surface's parts for `Support.parts`: "seat" where its normal is
    within 45 degrees of up, and where steeper "leg rest" under the legs and feet and "back"
    under the rest of the body (all "back" without `regions`)."""
    from solver.body.model import BODY_REGIONS

    legs = np.array([r in LEG_REGIONS for r in BODY_REGIONS])

    def parts(vertices: np.ndarray, normals: np.ndarray) -> np.ndarray:
        names = np.where(normals[:, 1] >= STEEP, "seat", "back").astype(object)
        if regions is not None:
            names[(names == "back") & legs[regions[vertices]]] = "leg rest"
        return names

    return parts


def contact_footprint(settled: Settled, n: int, names=None) -> np.ndarray:
    """(n,) m^2: each body vertex's footprint on the supports it presses (those `names` when
    given; 0 elsewhere)."""
    footprint = np.zeros(n)
    for c in settled.contacts:
        if names is None or c.name in names:
            np.add.at(footprint, c.vertices, c.areas)
    return footprint


def skin_pressure(settled: Settled, n: int, names=None) -> np.ndarray:
    """(n,) kPa on each of the n body vertices: its normal contact force over its footprint
    on the supports (those `names` when given, e.g. the surface's parts without the floor),
    summed over them."""
    force = np.zeros(n)
    for c in settled.contacts:
        if names is None or c.name in names:
            np.add.at(force, c.vertices, c.normal_force)
    footprint = contact_footprint(settled, n, names)
    touched = footprint > 0
    force[touched] /= footprint[touched] * 1e3
    return force


def surface_figures(settled: Settled, names=SURFACE_PARTS) -> dict:
    """The pressure mat's figures over the contacts of the named supports: peak and peak
    pressure index and mean pressure (kPa), contact area (m^2), centre of pressure (m); all
    None when the body does not rest or nothing touches them."""
    none = dict.fromkeys(("peak_pressure_kpa", "peak_pressure_index_kpa", "mean_pressure_kpa",
                          "centre_of_pressure_m"))
    chosen = [c for c in settled.contacts if c.name in names]
    if not settled.stable or not chosen:
        return {**none, "contact_area_m2": 0.0}
    f = contact_figures(chosen, contact_footprint(settled, len(settled.vertices), names),
                        settled.weight_n)
    return {"peak_pressure_kpa": f["peak_kpa"],
            "peak_pressure_index_kpa": f["peak_pressure_index_kpa"],
            "mean_pressure_kpa": f["mean_kpa"], "contact_area_m2": f["contact_area_cm2"] / 1e4,
            "centre_of_pressure_m": f["centre_of_pressure_m"]}


def facing_away_share(surface: SurfaceMesh, person: SupportedBody) -> float | None:
    """The share of `person`'s supported skin (weighted by importance) within FACING_REACH of
    `surface` whose outward normal runs along the normal of the surface's closest face. Skin
    resting on a surface faces against it, so a share over a half means the surface's faces
    point away from the body (their vertex order reversed: flip the mesh); None when no
    supported skin lies that near."""
    ids = np.flatnonzero(person.importance > 0)
    if not len(ids):
        return None
    dist, _, _, face, _ = surface.closest(person.vertices[ids])
    near = dist <= FACING_REACH
    if not near.any():
        return None
    along = np.einsum("ij,ij->i", person.normals[ids[near]],
                      surface.face_normals[face[near]]) > 0
    weight = person.importance[ids[near]]
    return float(weight @ along / weight.sum())


def peak_text(figures: dict) -> str:
    """A person's peak pressure on the surface for people ("7.9 kPa"), why the body does not
    rest, that it rests on something else, or that the figures hold no settle ("not
    measured")."""
    balance = figures.get("equilibrium") or {}
    if balance.get("stable") is False or figures.get("supported") is False:
        return f"no rest: {balance.get('reason') or 'does not come to rest'}"
    if figures.get("peak_pressure_kpa") is None:
        rests = balance.get("stable") or figures.get("supported")
        return "0 kPa (rests elsewhere)" if rests else "not measured"
    return f"{figures['peak_pressure_kpa']:.1f} kPa"


def seated_skin(same_load: dict) -> str:
    """The regions a flat seat carries, as a flat seat's `same_load` names them, in words
    ("pelvis and thighs"; "skin the flat seat presses" for a body without regions)."""
    regions = [r.replace("_", " ") for r in same_load.get("regions") or ()]
    if not regions:
        return "skin the flat seat presses"
    return regions[0] if len(regions) == 1 else ", ".join(regions[:-1]) + " and " + regions[-1]


def flat_text(person: dict) -> str:
    """A person's flat-seat baseline for people: its peak at the same load and the fitted
    surface's peak on the regions it carries (which may be less than the person's peak on the
    whole surface, a back included) as a share of it ("10.4 kPa at the same load; the surface's
    7.7 kPa on the pelvis and thighs is 0.74 of it"), or the flat seat's own settle
    (`peak_text`) where there is no same-load figure."""
    flat = person.get("flat") or {}
    same_load = flat.get("same_load") or {}
    same = same_load.get("peak_pressure_kpa")
    if same is None:
        return peak_text(flat)
    ratio, seat = person.get("peak_of_flat"), same_load.get("fitted_peak_kpa")
    if not ratio or seat is None:
        return f"{same:.1f} kPa at the same load"
    return (f"{same:.1f} kPa at the same load; the surface's {seat:.1f} kPa on the "
            f"{seated_skin(same_load)} is {ratio_text(ratio)} of it")


def equilibrium_figures(settled: Settled) -> dict:
    """report.json's `equilibrium`: whether the body rests (and why not), the weight, the force
    and moment left over (N, N m), the settle's motion (None when it does not rest), and per
    support part its load (N carried against gravity) and share of the weight (they add up to 1
    at rest), the magnitude of its whole force and of its friction."""
    out = {"stable": settled.stable, "reason": settled.reason, "weight_n": settled.weight_n}
    if not settled.stable:
        return {**out, "net_force_n": None, "net_moment_nm": None, "translation_m": None,
                "rotation_deg": None, "supports": {}}
    supports = {}
    up = -settled.gravity
    for c in settled.contacts:
        f = c.force
        supports[c.name] = {"load_n": float(f @ up),
                            "load_share": float(f @ up / settled.weight_n),
                            "force_n": float(np.linalg.norm(f)),
                            "friction_n": float(np.linalg.norm(c.tangential_force.sum(axis=0)))}
    return {**out, "net_force_n": float(np.linalg.norm(settled.net_force)),
            "net_moment_nm": float(np.linalg.norm(settled.net_moment)),
            "translation_m": [float(v) for v in settled.translation],
            "rotation_deg": float(np.degrees(np.linalg.norm(settled.rotation))),
            "supports": supports}


def deepest_cut(surface_points: np.ndarray, body_vertices: np.ndarray,
                body_triangles: np.ndarray, winding=None) -> tuple[float, int]:
    """Largest depth (m) of the given surface points (P, 3) inside a closed body mesh (0 if
    none), and the skin triangle nearest the deepest point (-1 if none): inside where the
    body's fast winding number (`winding`, its `body_winding`, kept per skin when None)
    exceeds one half, the depth the exact distance to the skin.

    A point's distance to its nearest body vertex bounds its depth from above, so the points
    are taken largest bound first, tested for inside in batches of `DEPTH_BATCH` and measured
    in smaller ones (on the skin's kept bounding-box tree), until no bound left exceeds the
    deepest depth found."""
    points = np.asarray(surface_points, dtype=np.float64)
    if not len(points):
        return 0.0, -1
    vertices = np.asarray(body_vertices, dtype=np.float64)
    triangles = np.asarray(body_triangles, dtype=np.int64)
    if winding is None:
        winding = body_winding(vertices, triangles)
    bound, _ = vertex_tree(vertices).query(points)
    order = np.argsort(-bound)
    skin = body_closest(vertices, triangles)
    deepest, face = 0.0, -1
    for start in range(0, len(order), DEPTH_BATCH):
        batch = order[start:start + DEPTH_BATCH]
        batch = batch[bound[batch] > deepest]
        if not batch.size:
            break
        inside = batch[winding.winding_number(points[batch]) > 0.5]
        for first in range(0, len(inside), DEPTH_BATCH // 8):
            measured = inside[first:first + DEPTH_BATCH // 8]
            measured = measured[bound[measured] > deepest]
            if not measured.size:
                break
            squared, faces, _ = skin.squared_distance(vertices, triangles, points[measured])
            k = int(np.argmax(squared))
            if np.sqrt(squared[k]) > deepest:
                deepest, face = float(np.sqrt(squared[k])), int(faces[k])
    return deepest, face


def penetration_depth(surface_points: np.ndarray, body_vertices: np.ndarray,
                      body_triangles: np.ndarray, winding=None) -> float:
    """The depth of `deepest_cut` alone."""
    return deepest_cut(surface_points, body_vertices, body_triangles, winding)[0]


def cut_vertices(vertices: np.ndarray, triangles: np.ndarray, signed: np.ndarray,
                 closest: np.ndarray, foam: Foam, winding=None) -> np.ndarray:
    """(P,) bool: of P body points, those behind a surface (their `signed` distances (P,),
    within its foam's reach) whose `closest` surface points (P, 3) lie inside the closed body
    (`vertices` (V, 3), `triangles` (F, 3); `winding` its `body_winding`, built when None and
    needed): where the surface cuts into the body, so the skin presses its foam (elsewhere
    behind it, the skin is on the surface's far side)."""
    cut = np.zeros(len(signed), dtype=bool)
    behind = np.flatnonzero((signed < 0) & (signed > -reach_depth(foam)))
    if behind.size:
        if winding is None:
            winding = body_winding(vertices, triangles)
        cut[behind] = winding.winding_number(np.asarray(closest[behind],
                                                        dtype=np.float64)) > 0.5
        cut[behind] |= signed[behind] > -TOUCHING  # (on the surface: it touches it)
    return cut


# the figures of how well a surface supports a body, and which way is better: +1 more, -1 less
SUPPORT_FIGURES = {"mean_support_distance_m": -1, "coverage": +1, "contact_coverage": +1,
                   "max_penetration_m": -1}


def support_figures(surface: SurfaceMesh, vertices: np.ndarray, importance: np.ndarray,
                    triangles: np.ndarray, margin: float, foam: Foam, closest=None,
                    winding=None, reference: dict | None = None,
                    regions: np.ndarray | None = None) -> dict:
    """How well a surface supports a posed body: the `SUPPORT_FIGURES` of `evaluate_person`.

    Parameters
    ----------
    surface : SurfaceMesh
        The surface, metres, its face normals towards the side bodies rest on.
    vertices : (V, 3) float
        The body's skin, metres; triangles (F, 3) int close it.
    importance : (V,) float
        Each vertex's importance; the vertices with none do not count.
    margin : float
        Metres of softness the surface may sink into the body.
    foam : Foam
        The surface's foam (how far behind the surface the body can press it).
    closest : tuple, optional
        `surface.closest(vertices)` when already computed (all V vertices).
    winding : optional
        The body's `body_winding` when already built.
    reference : dict, optional
        Figures to judge against: when the distance or the coverage is worse than the
        reference's, the figures stop there, without the costly ones (the contact coverage and
        the penetration, which need the body's winding number).
    regions : (V,) int, optional
        Each vertex's body region: the figures then name the region of the deepest cut
        (``deepest_cut_region``, None where the surface cuts nowhere).

    Returns
    -------
    dict
        ``mean_support_distance_m`` (the importance-weighted mean distance to the surface, None
        without importance), ``coverage`` (share of the importance within `margin` of the
        surface, either side), ``contact_coverage`` (the share within `CONTACT_GAP` in front of
        it or sunk in where it cuts into the body, by up to `margin`), ``max_penetration_m``
        (`penetration_depth` of the surface's vertices near the body). With a `reference` that
        is better by one of the first two, only those two.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    wanted = np.flatnonzero(importance > 0)
    weight = np.asarray(importance, dtype=np.float64)[wanted]
    total = weight.sum()
    figures = {"mean_support_distance_m": None, "coverage": 0.0}
    if wanted.size:
        if closest is None:
            dist, signed, _, _, points = surface.closest(vertices[wanted])
        else:
            dist, signed, points = closest[0][wanted], closest[1][wanted], closest[4][wanted]
        figures = {"mean_support_distance_m": float(np.sum(weight * dist) / total),
                   "coverage": float(weight[dist <= margin + 1e-9].sum() / total)}
        if reference is not None and worse_figures(reference, figures):
            return figures
    if winding is None:
        winding = body_winding(vertices, triangles)
    if wanted.size:
        # (by the distance to the surface, on the side its normal says: skin level with the
        # plane of a face it lies far beside touches nothing)
        front = (signed >= 0) & (dist <= CONTACT_GAP)
        sunk = (signed < 0) & (dist <= margin + 1e-9)
        cut = np.zeros(len(wanted), dtype=bool)
        cut[sunk] = cut_vertices(vertices, triangles, signed[sunk], points[sunk], foam, winding)
        figures["contact_coverage"] = float(weight[front | cut].sum() / total)
    else:
        figures["contact_coverage"] = 0.0
    lo, hi = vertices.min(axis=0) - 0.01, vertices.max(axis=0) + 0.01
    near = np.all((surface.vertices >= lo) & (surface.vertices <= hi), axis=1)
    near[np.setdiff1d(np.arange(len(near)), surface.triangles)] = False  # (a vertex no face
    # uses is no part of the surface: it cuts nothing)
    figures["max_penetration_m"], face = deepest_cut(surface.vertices[near], vertices,
                                                     triangles, winding)
    if regions is not None:
        figures["deepest_cut_region"] = _face_region(regions, triangles, face)
    return figures


def _face_region(regions: np.ndarray, triangles: np.ndarray, face: int) -> str | None:
    """The body region (`BODY_REGIONS`) most of a skin triangle's corners belong to (None for
    no triangle, -1)."""
    from solver.body.model import BODY_REGIONS

    if face < 0:
        return None
    corners = np.asarray(regions)[triangles[face]]
    return str(BODY_REGIONS[int(np.bincount(corners).argmax())])


def worse_figures(before: dict, after: dict) -> list[str]:
    """The `SUPPORT_FIGURES` worse in `after` than in `before` (dicts of them), in their order;
    a figure missing from either is not compared, and one None in both (no importance) is not
    worse."""
    worse = []
    for name, better in SUPPORT_FIGURES.items():
        if name not in before or name not in after:
            continue
        a, b = after[name], before[name]
        if a is None and b is None:
            continue
        if a is None or b is None or (a - b) * better < 0:
            worse.append(name)
    return worse


@dataclass(frozen=True, eq=False)
class SupportGate:
    """Judges a posed body on a surface by the evaluation's own `support_figures`, what a
    relaxation may not make worse (`solver.body.relax.Gate`): the surface, the body's
    importance (V,) and closed skin (F, 3), the softness margin (m) and the surface's foam;
    with a `floor` (its height, m), also how far the skin lies under it (`below_floor_m`),
    which may not grow past `solver.body.relax.FLOOR_TOLERANCE` (a body pulled down onto a
    seat must not push its feet through the floor)."""

    surface: SurfaceMesh
    importance: np.ndarray
    triangles: np.ndarray
    margin: float
    foam: Foam
    floor: float | None = None

    def figures(self, vertices: np.ndarray, reference: dict | None = None) -> dict:
        """`support_figures` of the skin posed at `vertices` (V, 3), metres, cut short when
        worse than `reference`, and `floor_figures`."""
        return {**support_figures(self.surface, vertices, self.importance, self.triangles,
                                  self.margin, self.foam, reference=reference),
                **self.floor_figures(vertices)}

    def floor_figures(self, vertices: np.ndarray) -> dict:
        """`below_floor_m`, how far the skin at `vertices` (V, 3) lies under the floor (0 on
        or above it); nothing without a floor."""
        if self.floor is None:
            return {}
        return {"below_floor_m": max(0.0, self.floor - float(np.min(vertices[:, 1])))}

    def worse(self, before: dict, after: dict) -> list[str]:
        """`worse_figures`: the names of the figures worse in `after` than in `before`, and
        `below_floor_m` when the skin goes deeper under the floor than before and than the
        relaxation's `FLOOR_TOLERANCE`."""
        from solver.body.relax import FLOOR_TOLERANCE

        worse = worse_figures(before, after)
        if "below_floor_m" in before and "below_floor_m" in after and \
                after["below_floor_m"] > max(before["below_floor_m"], FLOOR_TOLERANCE):
            worse.append("below_floor_m")
        return worse


@with_limited_threads  # small products: one BLAS thread (SITRELAX_THREADS), see solver.threads
def evaluate_person(surface: SurfaceMesh, person: SupportedBody, margin: float, foam: Foam,
                    floor: Foam | None = FLOOR, winding=None) -> tuple[dict, PressureMap]:
    """Coverage, penetration and the settle of one body on one surface (and the floor).

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
    foam : Foam
        The surface's foam (stiffness in Pa per metre, thickness, friction).
    floor : Foam or None, default FLOOR
        The floor's (the plane y = 0), or None for no floor.
    winding : optional
        The body's `body_winding`, when the caller evaluates it on several surfaces (built
        here when None).

    Returns
    -------
    figures : dict
        The figures, lengths in metres, pressures in kPa, areas in m^2: ``coverage`` (share of
        the importance within `margin` of the surface, either side, in [0, 1]),
        ``contact_coverage`` (the share within `CONTACT_GAP` in front of it or sunk in where it
        cuts into the body, by up to `margin`), ``max_penetration_m``,
        ``mean_support_distance_m`` (importance-weighted mean distance to the surface, None
        without importance), ``supported`` (bool: the body comes to rest), over the surface's
        contacts ``peak_pressure_kpa``, ``peak_pressure_index_kpa``, ``mean_pressure_kpa``,
        ``contact_area_m2`` and ``centre_of_pressure_m`` ((3,) list; None when the body does
        not rest), ``peak_region`` (`peak_region`), and ``equilibrium``
        (`equilibrium_figures`).
    pressure_map : PressureMap
        The pressure (V,) in kPa on each body vertex, and the settle.

    Raises
    ------
    ValueError
        If the person lacks areas, a closed skin or a mass.
    """
    if person.areas is None or person.triangles is None or person.mass_kg is None:
        raise ValueError(f"{person.label}: an evaluation needs the body's areas, closed skin "
                         "and mass")
    vertices, triangles = person.vertices, person.triangles
    near = surface.closest(vertices)
    winding = body_winding(vertices, triangles) if winding is None else winding
    support = support_figures(surface, vertices, person.importance, triangles, margin, foam,
                              near, winding, regions=person.regions)
    dist, signed, over, face, closest = near
    cut = cut_vertices(vertices, triangles, signed, closest, foam, winding)
    supports = [Support("surface", foam, surface, parts=surface_parts(person.regions))]
    if floor is not None:
        supports.append(Support("floor", floor))
    settled = settle(vertices, person.normals, person.areas, triangles, person.mass_kg,
                     supports, cut=cut, closest={0: near})
    figures = {
        **support,
        "supported": settled.stable,
        **surface_figures(settled),
        "peak_region": peak_region(settled, person.regions),
        "equilibrium": equilibrium_figures(settled),
        "mat": mat_figures(settled.contacts, contact_footprint(settled, len(vertices)),
                           person.mass_kg, person.regions, orientation=person.orientation)
        if settled.stable else None,
    }
    return figures, PressureMap(skin_pressure(settled, len(vertices)), settled)


def peak_region(settled: Settled, regions: np.ndarray | None) -> str | None:
    """The body region (`BODY_REGIONS`) of the highest pressure the surface's parts
    (`SURFACE_PARTS`, not the floor) put on the body: the vertex of `peak_pressure_kpa`. None
    when the body does not rest, nothing touches the surface, or `regions` (V,) is None."""
    from solver.body.model import BODY_REGIONS

    if regions is None or not settled.stable:
        return None
    pressure = skin_pressure(settled, len(regions), SURFACE_PARTS)
    return str(BODY_REGIONS[regions[int(np.argmax(pressure))]]) if pressure.max() > 0 else None


def surface_pressure(pressure: PressureMap) -> np.ndarray:
    """(V,) kPa the surface (not the floor) puts on each body vertex, 0 where it does not touch
    or the body does not rest."""
    n = len(pressure.pressure_kpa)
    if not pressure.settled.stable:
        return np.zeros(n)
    return skin_pressure(pressure.settled, n, SURFACE_PARTS)


def flat_seat_height(surface: SurfaceMesh, person: SupportedBody) -> float:
    """Height of the fitted surface under the body's most important tenth."""
    vertices, importance = person.vertices, person.importance
    top = importance >= np.quantile(importance[importance > 0], 0.9) if (importance > 0).any() \
        else np.ones(len(importance), dtype=bool)
    closest = surface.closest(vertices[top])[4]  # on the surface's own tree (kept)
    return float(np.median(closest[:, 1]))


def flat_at_same_load(person: SupportedBody, settled: Settled, foam: Foam) -> dict | None:
    """The flat-seat baseline of a body at rest on a fitted surface: a horizontal plane of the
    same foam in place of the surface's seat (its part within 45 degrees of level,
    `surface_parts`), pressed up under the body, held as it rests on the fitted surface (no
    turn, no slide: a seated body tips back off a flat seat, which a person prevents with their
    muscles), until it carries the vertical load the seat carries, and the vertical load the
    surface's steeper parts put on the body regions of the skin that presses the plane (a seat's
    front or sides rising against the thighs). Only the supported skin that faces down presses
    it (the plane ends where the supported parts do: calves hanging or tucked under a seat do
    not reach it). Pressure is the settle's law: stiffness times depth, `bottom_factor` times
    stiffer past the foam's thickness, over each vertex's Voronoi area projected on the plane.
    A back or a leg rest keeps its load on other regions (the lower back, the calves): the
    flat seat takes the place of the surface where it presses the regions the plane stands in
    for. What it is compared with (`fitted_peak_kpa`) is the fitted surface's peak on the body
    regions the flat seat presses (pelvis and thighs on a seat), whichever of its parts presses
    them: a seat's front or sides rising steeper than 45 degrees against the thighs count, a
    back or an arm rest pressing other regions does not. (Until 2026-12-07 the plane carried
    the seat part's load alone while the peak counted the steeper parts': it was compared at a
    lighter load than the regions carried.)

    Parameters
    ----------
    person : SupportedBody
        The posed body, with its areas (and `supported`; all its skin when None).
    settled : Settled
        The body's settle on the fitted surface (and the floor).
    foam : Foam
        The fitted surface's foam, which the plane gets too.

    Returns
    -------
    dict or None
        ``height_m`` (the plane), ``load_n`` and ``load_share`` (of m g) it carries,
        ``peak_pressure_kpa``, ``peak_pressure_index_kpa``, ``mean_pressure_kpa``,
        ``contact_area_m2`` as `surface_figures` gives them, ``fitted_peak_kpa``, the fitted
        surface's peak on the regions the flat seat presses (None where it presses none of
        them), and ``regions``, their names (None for a body without regions); None when the
        body does not rest on the fitted surface, its seat carries no vertical load or no
        supported skin faces down.
    """
    if not settled.stable:
        return None
    seat = [c for c in settled.contacts if c.name == "seat"]
    load = float(sum(c.force[1] for c in seat))
    normals = person.normals @ Rotation.from_rotvec(settled.rotation).as_matrix().T
    footprint = person.areas * np.maximum(-normals[:, 1], 0.0)
    pressing = footprint > 0  # (facing down, with an area)
    if person.supported is not None:
        pressing &= person.supported
    index = np.flatnonzero(pressing)
    if load <= 0 or not index.size:
        return None
    y, footprint = settled.vertices[index, 1], footprint[index]
    extra = (foam.bottom_factor - 1.0) * foam.stiffness

    def pressure(height: float) -> np.ndarray:  # Pa
        depth = np.maximum(height - y, 0.0)
        return foam.stiffness * depth + extra * np.maximum(depth - foam.thickness, 0.0)

    def plane(load: float) -> float:  # the height at which the plane carries `load`
        from scipy.optimize import brentq

        def short(height: float) -> float:  # N the plane at `height` carries less than load
            return load - float(footprint @ pressure(height))

        low, high = float(y.min()), float(y.min()) + 0.01
        while short(high) > 0:  # (the load grows without bound as the plane rises)
            high += high - low
        return brentq(short, low, high, xtol=1e-9)

    seat_load = load
    height = plane(load)
    if person.regions is not None:
        # the surface's steeper parts (a seat's sides or front edge rising against the thighs)
        # give the load they put on the regions the plane presses to the plane as well: the
        # fitted peak it is compared with is taken on those regions whichever part presses
        # them. Those regions depend on how high the plane carries its load: sought until they
        # stay the same (a back's or an arm rest's load on regions the plane does not reach,
        # the lower back, the forearms, stays theirs)
        steep = [(c.vertices, c.normal_force * c.normals[:, 1] + c.tangential_force[:, 1])
                 for c in settled.contacts if c.name != "seat" and c.name in SURFACE_PARTS]
        seen: list = []
        for _ in range(MAX_REGION_ROUNDS):
            held = np.unique(person.regions[index[pressure(height) > 0]])
            if any(np.array_equal(held, before) for before in seen):
                break  # (the same regions again: a cycle ends on the last)
            seen.append(held)
            within = np.isin(person.regions, held)
            load = seat_load + sum(max(float(up[within[v]].sum()), 0.0) for v, up in steep)
            height = plane(load)
    p = pressure(height)
    on = p > 0
    k = int(on.sum())
    points = settled.vertices[index[on]].copy()
    points[:, 1] = height  # on the plane, as the settle's contact points lie on the support
    contact = SupportContact("flat seat", index[on], p[on] * footprint[on], np.zeros((k, 3)),
                             np.tile(UP, (k, 1)), points, np.full(k, -1), footprint[on])
    areas = np.zeros(len(settled.vertices))
    areas[index[on]] = footprint[on]
    f = contact_figures([contact], areas, settled.weight_n)
    fitted, regions = _peak_on_regions_pressed(settled, person, index[on])
    return {"height_m": height, "load_n": load, "load_share": load / settled.weight_n,
            "peak_pressure_kpa": f["peak_kpa"],
            "peak_pressure_index_kpa": f["peak_pressure_index_kpa"],
            "mean_pressure_kpa": f["mean_kpa"], "contact_area_m2": f["contact_area_cm2"] / 1e4,
            "fitted_peak_kpa": fitted, "regions": regions}


def _peak_on_regions_pressed(settled: Settled, person: SupportedBody, pressed: np.ndarray
                             ) -> tuple[float | None, list[str] | None]:
    """The fitted surface's peak (kPa; None for none) on the body regions the flat seat
    presses (its vertices `pressed`), whichever part of the surface presses them: the seat,
    or a seat's edge or side rising steeper than 45 degrees beside the thighs (a "leg rest"),
    which a designer judges as the seat; and those regions' names (None without regions: then
    the whole surface's peak)."""
    from solver.body.model import BODY_REGIONS

    skin = skin_pressure(settled, len(settled.vertices), SURFACE_PARTS)
    names = None
    if person.regions is not None:
        held = np.unique(person.regions[pressed])
        skin = np.where(np.isin(person.regions, held), skin, 0.0)
        names = [BODY_REGIONS[r] for r in held]
    peak = float(skin.max(initial=0.0))
    return (peak if peak > 0 else None), names


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
