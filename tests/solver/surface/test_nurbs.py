"""The B-spline of a regular grid: its layout, its phantom points, and that it is the limit
surface (against our limit masks, and independently against densely subdivided levels)."""

import numpy as np
import pytest

from solver.surface.limit import limit_positions
from solver.surface.nurbs import bspline_of_grid, grid_layout
from solver.surface.subdivision import MeshError, grid_mesh, subdivide_once, subdivision


def _bumpy_grid(resolution=(5, 3), seed=2):
    v, f = grid_mesh((1.0, 0.8), resolution, 0.4)
    v = v + np.random.default_rng(seed).normal(scale=0.03, size=v.shape)
    return v, f


def test_grid_layout_of_grid_mesh_runs_along_z_then_x():
    v, f = grid_mesh((1.0, 0.8), (5, 3), 0.4)
    grid = grid_layout(len(v), f)
    assert grid.shape == (4, 6)  # u along z (4 points), v along x (6 points): normal +Y
    assert np.array_equal(grid, np.arange(24).reshape(6, 4).T)


def test_grid_layout_refuses_what_is_no_grid():
    v, f = grid_mesh((1.0, 0.8), (3, 3), 0.4)
    assert grid_layout(len(v), f, [[5, 6]]) is None  # a crease
    assert grid_layout(len(v), f[1:]) is None  # a quad missing
    tri = [list(q) for q in f[:-1]] + [[10, 11, 15], [10, 15, 14]]
    assert grid_layout(len(v), tri) is None
    # a cube's six quads: closed, no corner
    cube = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    assert grid_layout(8, cube) is None


def test_phantom_points_mirror_the_boundary():
    v, f = _bumpy_grid()
    srf = bspline_of_grid(v, grid_layout(len(v), f))
    p = srf.points
    assert p.shape == (6, 8, 3) and len(srf.knots_u) == 8 and len(srf.knots_v) == 10
    assert np.allclose(p[0, 1:-1], 2 * p[1, 1:-1] - p[2, 1:-1])
    assert np.allclose(p[0, 0], 4 * p[1, 1] - 2 * p[2, 1] - 2 * p[1, 2] + p[2, 2])
    assert srf.domain == ((0.0, 3.0), (0.0, 5.0))
    assert np.allclose(srf.evaluate(0.0, 0.0), v[0])  # corners interpolated


@pytest.mark.parametrize("level", [0, 2, 3])
def test_bspline_is_our_limit_surface_at_every_level_vertex(level):
    v, f = _bumpy_grid()
    srf = bspline_of_grid(v, grid_layout(len(v), f))
    sub = subdivision(len(v), f, level)
    fine = grid_layout(sub.matrix.shape[0], sub.faces)
    u, w = np.meshgrid(*(np.arange(k) / 2**level for k in fine.shape), indexing="ij")
    limit = limit_positions(v, f, level)
    assert np.abs(srf.evaluate(u, w) - limit[fine]).max() < 1e-12


def test_bspline_matches_densely_subdivided_levels():
    """Independent of the limit masks: levels 5 to 7 of the control net, at the level-2
    vertices (which keep their indices at every finer level), come ever closer to the
    B-spline, level 7 within 0.05 mm."""
    v, f = _bumpy_grid((3, 2))
    srf = bspline_of_grid(v, grid_layout(len(v), f))
    level2 = subdivision(len(v), f, 2)
    picked = grid_layout(level2.matrix.shape[0], level2.faces)
    u, w = np.meshgrid(*(np.arange(k) / 4 for k in picked.shape), indexing="ij")
    expected = srf.evaluate(u, w)
    n, faces, points, gaps = len(v), f, v, []
    for level in range(1, 8):
        step = subdivide_once(n, faces)
        points, faces, n = step.matrix @ points, step.faces, step.matrix.shape[0]
        if level >= 5:
            gaps.append(np.linalg.norm(expected - points[picked], axis=-1).max())
    assert gaps[0] > gaps[1] > gaps[2]
    assert gaps[2] < 5e-5  # metres


def test_bad_grids_are_refused():
    v, f = _bumpy_grid()
    with pytest.raises(MeshError, match="at least 2 x 2"):
        bspline_of_grid(v, np.array([[0, 1, 2]]))
    with pytest.raises(MeshError, match="covering the grid's indices"):
        bspline_of_grid(v[:5], grid_layout(len(v), f))


def test_grid_patches_cut_at_whole_crease_lines():
    from solver.surface.nurbs import grid_patches

    v, f = grid_mesh((1.0, 0.8), (4, 4), 0.4)  # vertex i * 5 + k
    assert [p.shape for p in grid_patches(len(v), f)] == [(5, 5)]
    line_x0 = [[10, 11], [11, 12], [12, 13], [13, 14]]
    line_z0 = [[2, 7], [7, 12], [12, 17], [17, 22]]
    assert [p.shape for p in grid_patches(len(v), f, line_x0)] == [(5, 3), (5, 3)]
    assert [p.shape for p in grid_patches(len(v), f, line_x0 + line_z0)] == [(3, 3)] * 4
    assert grid_patches(len(v), f, line_x0[:3]) is None  # stops inside: a dart
    assert [p.shape for p in grid_patches(len(v), f, [[0, 1]])] == [(5, 5)]  # on the boundary
    with pytest.raises(MeshError, match="creases along mesh edges"):
        grid_patches(len(v), f, [[0, 6]])


@pytest.mark.parametrize("level", [0, 1, 3])
def test_subdivided_grid_is_the_fine_mesh_layout(level):
    from solver.surface.nurbs import subdivided_grid

    v, f = grid_mesh((1.0, 0.8), (5, 3), 0.4)
    sub = subdivision(len(v), f, level)
    walked = grid_layout(sub.matrix.shape[0], sub.faces)
    assert np.array_equal(subdivided_grid(grid_layout(len(v), f), sub, f), walked)


def test_the_uniform_cubic_basis_is_scipys_design_matrix():
    """On Rhino's unit-spaced knots (scipy's with one more knot each end), anywhere in the
    domain, its ends included."""
    from scipy.interpolate import BSpline

    from solver.surface.nurbs import uniform_cubic_basis

    knots = np.arange(-2.0, 9.0)  # 9 control points
    t = np.concatenate([[0.0, 6.0, 3.0], np.random.default_rng(1).uniform(0, 6, 200)])
    full = np.concatenate([[knots[0] - 1], knots, [knots[-1] + 1]])
    expected = BSpline.design_matrix(t, full, 3).toarray()
    np.testing.assert_allclose(uniform_cubic_basis(t, knots), expected, atol=1e-14)


def test_regular_face_patches_of_a_grid_are_its_bspline_spans():
    """On a grid every inner face (no corner on the border) is regular, and its patch is the
    grid's B-spline over that face's span, at any parameters."""
    from solver.surface.nurbs import bspline_of_ring, regular_face_patches

    v, f = grid_mesh((0.5, 0.6), (6, 5), 0.42)
    v[:, 1] += 0.05 * np.sin(4 * v[:, 0]) * np.cos(5 * v[:, 2])
    grid = grid_layout(len(v), f)
    whole = bspline_of_grid(v, grid)
    found, rings = regular_face_patches(len(v), f)
    assert len(found) == 4 * 3  # the 6 x 5 quads less the border's
    rng = np.random.default_rng(0)
    for face, ring in zip(found, rings):
        assert set(ring[1:3, 1:3].ravel()) == set(f[face])
        i, j = (int(k[0]) for k in np.nonzero(grid == ring[1, 1]))
        u, w = rng.uniform(0, 1, (2, 20))
        np.testing.assert_allclose(bspline_of_ring(v, ring).evaluate(u, w),
                                   whole.evaluate(i + u, j + w), atol=1e-12)
    # a crease at a corner makes its faces irregular
    found_creased, _ = regular_face_patches(len(v), f, [tuple(f[found[0]][:2])])
    assert found[0] not in found_creased and len(found_creased) < len(found)
