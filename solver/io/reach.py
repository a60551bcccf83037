"""Can a ball-nose cutter reach every hollow of a surface? Principal curvatures against the
tool's radius.

The cutter works from the bodies' side (the side the surface's normals point to). A hollow
seen from there, a place where the surface bends towards the bodies with a radius smaller than
the ball's, cannot be cut: the ball touches the sides before the bottom. The same curvatures
bound the constant thickness a solid may have: where the surface bends away from the bodies
with radius r, an offset by more than r away from the bodies folds over (see `solver.io.solid`).

Curvatures are libigl's (`principal_curvature`, a quadric fitted to each vertex's
neighbourhood), in 1/m; vertices are metres, Y up.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solver.mesh import quad_triangles, voronoi_areas

MAX_TOOL_RADIUS = 0.1  # metres: no ball-nose cutter is larger (routers use up to about 25 mm)


class ReachError(ValueError):
    """A surface or a tool that the reach check cannot take."""


@dataclass(frozen=True, eq=False)
class CutterReach:
    """Where a ball-nose cutter of `tool_radius_m` cannot reach.

    unreachable : (N,) bool, per surface vertex.
    unreachable_area_m2 : the Voronoi area of those vertices.
    min_concave_radius_m : the smallest radius of the surface's bends towards the bodies
        (inf if it bends nowhere towards them).
    min_convex_radius_m : the smallest radius of its bends away from them (the largest
        constant thickness an offset away from the bodies can have without folding).
    """

    tool_radius_m: float
    unreachable: np.ndarray
    unreachable_area_m2: float
    min_concave_radius_m: float
    min_convex_radius_m: float

    def summary(self) -> dict:
        """The figures as plain numbers for a report (m, m^2; None for an infinite radius)."""
        def finite(r):
            return float(r) if np.isfinite(r) else None

        return {"tool_radius_m": self.tool_radius_m,
                "unreachable_vertices": int(self.unreachable.sum()),
                "unreachable_area_m2": self.unreachable_area_m2,
                "min_concave_radius_m": finite(self.min_concave_radius_m),
                "min_convex_radius_m": finite(self.min_convex_radius_m)}


def _triangles(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise ReachError(f"Expected finite surface vertices (N, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] not in (3, 4) or len(f) == 0 or f.min() < 0 or \
            f.max() >= len(v):
        raise ReachError(f"Expected faces (F, 3) or (F, 4) indexing {len(v)} vertices, got "
                         f"{f.shape}")
    f = f.astype(np.int64)
    return v, f if f.shape[1] == 3 else quad_triangles(f)


def bending_towards_normal(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 2) principal curvatures (1/m), positive where the surface bends towards its normal
    (a hollow seen from the bodies), negative where it bends away; largest first.

    Parameters
    ----------
    vertices : (N, 3) float
        Metres.
    faces : (F, 4) or (F, 3) int
        Counter-clockwise seen from the side the normals point to.
    """
    import igl

    v, tris = _triangles(vertices, faces)
    _, _, k_max, k_min, _ = igl.principal_curvature(v, tris)
    # libigl counts a bend towards the face normal as negative curvature
    return np.stack([-k_min, -k_max], axis=1)


def cutter_reach(vertices: np.ndarray, faces: np.ndarray, tool_radius: float) -> CutterReach:
    """Where a ball-nose cutter of radius `tool_radius` (m), working from the bodies' side,
    cannot reach: vertices whose sharpest bend towards the bodies has a radius under the
    tool's.

    Parameters
    ----------
    vertices : (N, 3) float
        The surface, metres.
    faces : (F, 4) or (F, 3) int
        Its faces, counter-clockwise seen from the bodies.
    tool_radius : float
        The ball's radius, metres, > 0.

    Returns
    -------
    CutterReach
    """
    if not (np.isfinite(tool_radius) and 0 < tool_radius <= MAX_TOOL_RADIUS):
        raise ReachError(f"Expected a tool radius in (0, {MAX_TOOL_RADIUS:g}] m, got "
                         f"{tool_radius}")
    v, tris = _triangles(vertices, faces)
    bend = bending_towards_normal(v, tris)
    towards, away = bend[:, 0], -bend[:, 1]
    unreachable = towards * tool_radius > 1.0
    area = float(voronoi_areas(v, tris)[unreachable].sum())
    concave = 1.0 / towards.max() if towards.max() > 0 else np.inf
    convex = 1.0 / away.max() if away.max() > 0 else np.inf
    return CutterReach(float(tool_radius), unreachable, area, float(concave), float(convex))


def render_reach(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
                 reach: CutterReach, bodies: list | None = None) -> Path:
    """A PNG of the surface seen from above and from three-quarter, red where the cutter
    cannot reach.

    Parameters
    ----------
    path : str or os.PathLike
    vertices : (N, 3) float; faces : (F, 4) or (F, 3) int
        The surface the reach was computed on.
    reach : CutterReach
    bodies : list of `solver.io.render.MeshView`, optional
        Drawn in the second panel.

    Returns
    -------
    pathlib.Path
        The picture written.
    """
    from solver.io.render import SURFACE, MeshView, Panel, render_panels

    faces = np.asarray(faces)
    colors = np.tile(np.asarray(SURFACE), (len(faces), 1))  # per face: a lone vertex shows
    colors[reach.unreachable[faces].any(axis=1)] = (0.85, 0.15, 0.1)
    surface = MeshView(np.asarray(vertices), faces, colors)
    radius = reach.min_concave_radius_m
    title = (f"ball-nose radius {reach.tool_radius_m * 1000:.0f} mm: "
             f"{int(reach.unreachable.sum())} vertices, "
             f"{reach.unreachable_area_m2 * 1e4:.1f} cm^2 out of reach (red)\nsmallest "
             f"hollow radius " + (f"{radius * 1000:.1f} mm" if np.isfinite(radius) else
                                  "none"))
    return render_panels(path, [Panel([surface], "top", "from above"),
                                Panel([surface] + list(bodies or []), "three-quarter",
                                      "three-quarter")], columns=2, title=title,
                         panel_size=(520, 520))
