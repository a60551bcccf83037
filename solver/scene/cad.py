"""A fitted surface for the workshop: its exact limit surface, as a mesh and as NURBS.

The fit and its evaluation work on the level-s mesh (`FitResult.surface`); what goes to CAD is
the Catmull-Clark limit surface of the fitted control mesh: the level-s quads with each vertex
moved to its limit point, and, where the whole control net is a regular quad grid without
creases, the exact uniform bicubic B-spline (`solver.surface.nurbs`); a grid cut by creases
along whole grid lines, one B-spline per patch between them. Other control nets (extraordinary
vertices, triangles, partial creases) get the dense limit mesh only: one NURBS per maximal
regular region of a general mesh is not done.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solver.io.rhino import write_3dm
from solver.mesh import quad_triangles
from solver.surface.fit import FitResult
from solver.surface.nurbs import (BSplineSurface, bspline_of_grid, grid_layout, grid_patches,
                                  subdivided_grid)


@dataclass(frozen=True, eq=False)
class CadSurface:
    """The limit surface of a fit.

    vertices : (n_s, 3) float, the level-s vertices moved to their limit points, metres.
    faces : (F_s, 4) int, the level-s quads.
    nurbs : the exact B-splines of a grid control net's patches (empty when there is none).
    figures : dict of measured distances in millimetres: `level_to_limit_max_mm` and
        `level_to_limit_median_mm` (each level-s vertex to its limit point),
        `limit_to_level_mesh_max_mm` (the limit points' distance to the level-s mesh), and with
        NURBS `nurbs_to_limit_max_mm` (the B-spline at the vertices' parameters to their limit
        points); `level` and `kind` ("nurbs" or "limit mesh").
    """

    vertices: np.ndarray
    faces: np.ndarray
    nurbs: tuple[BSplineSurface, ...]
    figures: dict


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
        return CadSurface(limit, np.asarray(result.surface_faces), (), figures)
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


def write_scene_3dm(path: Path, result: FitResult, cad: CadSurface, bodies, names,
                    unit: str = "mm", up: str = "z") -> Path:
    """The fit as a Rhino document: the control net, the surface (the NURBS, or the limit mesh
    where there is none) and each body on its layer."""
    surface = list(cad.nurbs) if cad.nurbs else (cad.vertices, cad.faces)
    kind = "exact limit surface, NURBS" if cad.nurbs else \
        f"limit points of the level-{cad.figures['level']} vertices"
    return write_3dm(path, result.control, result.faces, surface, bodies, body_names=names,
                     unit=unit, up=up, notes=f"sitrelax fit; surface: {kind}")
