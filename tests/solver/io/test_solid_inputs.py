"""Surfaces the offset cannot be made of, and small ones it can: clear refusals, not crashes
deep in the trimming or the checks."""

import numpy as np
import pytest

from solver.io.solid import SolidError, check_solid, plinth, thicken
from solver.scene.workshop import WorkshopOptions, export_workshop
from solver.surface.subdivision import grid_mesh


def flat_grid(n: int = 4, size: float = 0.4, height: float = 0.45):
    """An n x n grid of quads at `height`, facing up (the bodies)."""
    return grid_mesh((size, size), (n, n), height)


def test_a_surface_with_a_face_without_area_is_refused_by_name():
    """Two corners of a quad at one point leave a triangle without area and a normal of NaN,
    which reached the trimming's tree query: "'x' must be finite" from scipy, no SolidError,
    and `sitrelax fit --solid` ended on it."""
    vertices, quads = flat_grid()
    vertices[6] = vertices[7]
    with pytest.raises(SolidError, match=r"Expected surface faces with area, got 2 triangles "
                                         r"without \(face 5: corners \[6, 7, 12, 11\]"):
        thicken(vertices, quads, 0.01)
    with pytest.raises(SolidError, match="faces with area"):
        plinth(vertices, quads)


def test_the_workshop_reports_a_surface_it_cannot_offset_and_writes_no_solid(tmp_path):
    vertices, quads = flat_grid()
    quads[0] = [0, 0, 6, 5]  # a repeated corner
    files, fabrication = export_workshop(tmp_path, vertices, quads, [],
                                         WorkshopOptions(solid_thickness=0.01))
    assert fabrication["solid"]["ok"] is False
    assert "faces with area" in fabrication["solid"]["problem"]
    assert files == {} and not list(tmp_path.iterdir())


def test_a_solid_thicker_than_its_surface_is_wide_is_a_checked_column():
    """A 2 mm quad thickened by 0.1 m: its underside has no corner over the surface's inside,
    and the check's least distance of nothing failed (numpy's "zero-size array to reduction
    operation minimum")."""
    vertices, quads = flat_grid(1, 0.002)
    solid = thicken(vertices, quads, 0.1)
    check = check_solid(solid)
    assert check.ok and check.thickness_min_m is None and check.clearance_m is None
    assert check.volume_m3 == pytest.approx(0.002 * 0.002 * 0.1, rel=1e-9)
    low, high = solid.vertices.min(axis=0), solid.vertices.max(axis=0)
    assert np.allclose(high - low, [0.002, 0.1, 0.002])
