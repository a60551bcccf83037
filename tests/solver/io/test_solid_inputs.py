"""Surfaces the offset cannot be made of, and small ones it can: clear refusals, not crashes
deep in the trimming or the checks."""

import numpy as np
import pytest

from solver.io.solid import SolidError, check_solid, plinth, thicken
from solver.scene.workshop import WorkshopOptions, export_workshop


def flat_grid(n: int = 4, size: float = 0.4, height: float = 0.45):
    """An n x n grid of quads at `height`, counter-clockwise seen from above (the bodies)."""
    u = np.linspace(-size / 2, size / 2, n + 1)
    x, z = np.meshgrid(u, u, indexing="ij")
    vertices = np.stack([x.ravel(), np.full(x.size, height), z.ravel()], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]],
                     axis=-1).reshape(-1, 4)
    return vertices, quads


def test_the_grid_faces_the_bodies():
    from solver.mesh import quad_triangles, vertex_normals

    vertices, quads = flat_grid()
    assert np.allclose(vertex_normals(vertices, quad_triangles(quads)), [0.0, 1.0, 0.0])


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
