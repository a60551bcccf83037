"""A fitted surface for the workshop: its exact limit surface, as a mesh and as NURBS.

The fit and its evaluation work on the level-s mesh (`FitResult.surface`); what goes to CAD is
the Catmull-Clark limit surface of the fitted control mesh: the level-s quads with each vertex
moved to its limit point, and, where the whole control net is a regular quad grid without
creases, the exact uniform bicubic B-spline (`solver.surface.nurbs`); a grid cut by creases
along whole grid lines, one B-spline per patch between them. In any other control net
(extraordinary vertices, triangles, partial creases) each regular face (four regular inner
corners, no crease at them) is its own exact bicubic patch, and the rest of the surface, near
the irregular vertices, creases and the border, is the dense limit mesh. Merging neighbouring
regular faces into larger NURBS is not done.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solver.mesh import quad_triangles
from solver.surface.fit import FitResult
from solver.surface.nurbs import (BSplineSurface, bspline_of_grid, bspline_of_ring, grid_layout,
                                  grid_patches, regular_face_patches, subdivided_grid)


@dataclass(frozen=True, eq=False)
class CadSurface:
    """The limit surface of a fit.

    vertices : (n_s, 3) float, the level-s vertices moved to their limit points, metres.
    faces : (F_s, 4) int, the level-s quads.
    nurbs : the exact B-splines of a grid control net's patches, or of a general net's regular
        faces (empty when there is none).
    figures : dict of measured distances in millimetres: `level_to_limit_max_mm` and
        `level_to_limit_median_mm` (each level-s vertex to its limit point),
        `limit_to_level_mesh_max_mm` (the limit points' distance to the level-s mesh), and with
        NURBS `nurbs_to_limit_max_mm` (the B-spline at the vertices' parameters to their limit
        points); `level` and `kind` ("nurbs", "nurbs and limit mesh" or "limit mesh"), with
        the second also `patches` and `mesh_faces` (level-s quads not under a patch).
    rest : (R,) int, the level-s faces no NURBS covers (all of them without NURBS, none for a
        grid).
    """

    vertices: np.ndarray
    faces: np.ndarray
    nurbs: tuple[BSplineSurface, ...]
    figures: dict
    rest: np.ndarray | None = None

    @property
    def rest_faces(self) -> np.ndarray:
        """The level-s quads no NURBS covers."""
        if self.rest is None:
            return np.zeros((0, 4), dtype=np.int64) if self.nurbs else np.asarray(self.faces)
        return np.asarray(self.faces)[self.rest]


def cad_surface(result: FitResult, creases=()) -> CadSurface:
    """The limit surface of a fit (see `CadSurface`); `creases` are the control creases."""
    import igl

    sub = result.subdivision
    if sub is None:
        raise ValueError("Expected a FitResult that carries its subdivision, got none")
    limit = result.limit_surface(creases)
    moved = np.linalg.norm(limit - result.surface, axis=1)
    dist2, _, _ = igl.point_mesh_squared_distance(limit, result.surface,
                                                  quad_triangles(result.surface_faces))
    figures = {"level": int(sub.level), "kind": "limit mesh",
               "level_to_limit_max_mm": float(moved.max() * 1e3),
               "level_to_limit_median_mm": float(np.median(moved) * 1e3),
               "limit_to_level_mesh_max_mm": float(np.sqrt(dist2.max()) * 1e3)}
    patches = grid_patches(len(result.control), result.faces, list(creases) or None)
    if not patches:
        return _regular_faces(result, creases, limit, figures)
    grid, scale = grid_layout(len(result.control), result.faces), 2**sub.level
    fine = subdivided_grid(grid, sub, result.faces)
    if fine.shape != tuple((np.array(grid.shape) - 1) * scale + 1) or \
            not np.array_equal(fine[::scale, ::scale], grid):
        raise AssertionError("a grid's subdivision is no grid of the expected size")
    nurbs, gap = [], 0.0
    for patch in patches:
        nurbs.append(bspline_of_grid(result.control, patch))
        # the patch's place in the grid, and its level-s vertices
        i, j = (int(k[0]) for k in np.nonzero(grid == patch[0, 0]))
        part = fine[i * scale:i * scale + (patch.shape[0] - 1) * scale + 1,
                    j * scale:j * scale + (patch.shape[1] - 1) * scale + 1]
        u, v = np.meshgrid(*(np.arange(k) / scale for k in part.shape), indexing="ij")
        gap = max(gap, float(np.linalg.norm(nurbs[-1].evaluate(u, v) - limit[part],
                                            axis=-1).max()))
    figures.update(kind="nurbs", patches=len(nurbs), nurbs_to_limit_max_mm=gap * 1e3)
    return CadSurface(limit, np.asarray(result.surface_faces), tuple(nurbs), figures)


def _regular_faces(result: FitResult, creases, limit: np.ndarray, figures: dict) -> CadSurface:
    """A general control net's limit surface: a patch per regular face, the limit mesh of the
    rest. The patches are measured at each face's level-1 points (corners, edge middles,
    centre) against the limit masks there."""
    from solver.surface.limit import limit_positions

    control, faces = result.control, result.faces
    found, rings = regular_face_patches(len(control), faces, list(creases) or None)
    everything = np.asarray(result.surface_faces)
    if len(found) == 0 or result.subdivision.level == 0:
        return CadSurface(limit, everything, (), figures)
    nurbs = tuple(bspline_of_ring(control, ring) for ring in rings)
    owner = control_face_of(result.subdivision, len(faces))
    rest = np.flatnonzero(~np.isin(owner, found))
    # level-1 points: a step makes face f's quad at corner c as (c, the edge point of c and
    # the next corner, f's face point, ...)
    step = result.subdivision.steps[0]
    first_face_point = step.matrix.shape[0] - len(faces)
    made = np.asarray(step.faces)
    parent = made[:, 2] - first_face_point
    n = len(control)
    edge_after = dict(zip((parent * n + made[:, 0]).tolist(), made[:, 1].tolist()))
    level1 = limit_positions(control, faces, 1, list(creases) or None)
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0],
                   [0.5, 0.0], [1.0, 0.5], [0.5, 1.0], [0.0, 0.5], [0.5, 0.5]])
    gap = 0.0
    for f, patch in zip(found.tolist(), nurbs):
        corners = [int(c) for c in faces[f][:4]]
        index = corners + [edge_after[f * n + c] for c in corners] + [first_face_point + f]
        points = patch.evaluate(uv[:, 0], uv[:, 1])
        gap = max(gap, float(np.linalg.norm(points - level1[index], axis=1).max()))
    figures.update(kind="nurbs and limit mesh", patches=len(nurbs), mesh_faces=int(len(rest)),
                   nurbs_to_limit_max_mm=gap * 1e3)
    return CadSurface(limit, everything, nurbs, figures, rest)


def control_face_of(sub, n_faces: int) -> np.ndarray:
    """(F_s,) the control face each level-s face of a subdivision lies in (a step makes face
    f's sub-quads around its face point, the step's last points, one per face)."""
    owner = np.arange(n_faces)
    for step in sub.steps:
        first_face_point = step.matrix.shape[0] - len(owner)
        owner = owner[np.asarray(step.faces)[:, 2] - first_face_point]
    return owner


def write_scene_3dm(path: Path, result: FitResult, cad: CadSurface, bodies, names,
                    unit: str = "mm", up: str = "z") -> Path:
    """The fit as a Rhino document: the control net, the surface (the NURBS, and the limit
    mesh where there are none) and each body on its layer."""
    from solver.io.rhino import write_3dm  # loaded for a .3dm only

    rest = cad.rest_faces
    surface = list(cad.nurbs) + ([(cad.vertices, rest)] if len(rest) else [])
    kind = "exact limit surface, NURBS" if not len(rest) else \
        f"limit points of the level-{cad.figures['level']} vertices" if not cad.nurbs else \
        f"exact limit surface, NURBS over the regular faces; limit points of the " \
        f"level-{cad.figures['level']} vertices elsewhere"
    return write_3dm(path, result.control, result.faces, surface, bodies, body_names=names,
                     unit=unit, up=up, notes=f"sitrelax fit; surface: {kind}")
