"""Catmull-Clark subdivision matrices: stencils by hand, properties, and oracles."""

import os
import tempfile

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import cKDTree

from solver.surface.subdivision import MeshError, grid_mesh, subdivide_once, subdivision

CUBE_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                   [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float)
CUBE_F = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6],
                   [3, 0, 4, 7]])


def _row(matrix, i):
    row = matrix.getrow(i)
    return dict(zip(row.indices.tolist(), row.data.tolist()))


def test_regular_interior_stencil():
    verts, quads = grid_mesh(resolution=(4, 4))  # 5 x 5 vertices, index = 5 i + j
    step = subdivide_once(len(verts), quads)
    row = _row(step.matrix, 12)  # the centre vertex
    assert row[12] == pytest.approx(9 / 16)
    for k in (7, 11, 13, 17):
        assert row[k] == pytest.approx(3 / 32)
    for k in (6, 8, 16, 18):
        assert row[k] == pytest.approx(1 / 64)
    assert len(row) == 9


def test_boundary_and_corner_stencils():
    verts, quads = grid_mesh(resolution=(4, 4))
    step = subdivide_once(len(verts), quads)
    assert _row(step.matrix, 2) == pytest.approx({1: 1 / 8, 2: 3 / 4, 3: 1 / 8})  # boundary
    assert _row(step.matrix, 0) == {0: 1.0}  # a corner is kept
    n = len(verts)
    # edge points: the boundary edge (0, 1) is its midpoint; an interior one averages faces
    edges = {tuple(sorted(e)): k for k, e in enumerate(_edges(quads))}
    assert _row(step.matrix, n + edges[(0, 1)]) == pytest.approx({0: 0.5, 1: 0.5})
    interior = _row(step.matrix, n + edges[(6, 7)])
    assert interior[6] == pytest.approx(3 / 8) and interior[7] == pytest.approx(3 / 8)
    assert sum(interior.values()) == pytest.approx(1.0) and len(interior) == 6
    # face points: the mean of the face
    assert _row(step.matrix, step.matrix.shape[0] - len(quads)) == pytest.approx(
        {int(v): 0.25 for v in quads[0]})


def _edges(faces):
    e = np.concatenate([np.stack([f, np.roll(f, -1)], axis=1) for f in np.asarray(faces)])
    return np.unique(np.sort(e, axis=1), axis=0)


def test_triangles_and_an_extraordinary_vertex_by_hand():
    # a tetrahedron about its centroid: every vertex point is 7/27 of the vertex
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    faces = [[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]
    step = subdivide_once(4, faces)
    np.testing.assert_allclose((step.matrix @ v)[:4], v * 7 / 27, atol=1e-15)
    assert _row(step.matrix, 4 + 6) == pytest.approx({0: 1 / 3, 1: 1 / 3, 2: 1 / 3})


@pytest.mark.parametrize("level", [1, 2, 3])
def test_rows_sum_to_one_and_are_non_negative(level):
    verts, quads = grid_mesh(resolution=(5, 3))
    sub = subdivision(len(verts), quads, level, creases=[(5, 9), (9, 13)])
    np.testing.assert_allclose(np.asarray(sub.matrix.sum(axis=1)).ravel(), 1.0, atol=1e-14)
    assert sub.matrix.data.min() > 0
    assert sub.faces.shape == (15 * 4**level, 4)


def _oracle_gel(vertices, faces, levels):
    from pygel3d import hmesh

    with tempfile.NamedTemporaryFile("w", suffix=".obj", delete=False) as fh:
        for v in vertices:
            fh.write("v %.17g %.17g %.17g\n" % tuple(v))
        for f in faces:
            fh.write("f " + " ".join(str(i + 1) for i in f) + "\n")
    try:
        mesh = hmesh.obj_load(fh.name)
    finally:
        os.unlink(fh.name)
    for _ in range(levels):
        hmesh.cc_subdivide(mesh)
    mesh.cleanup()
    return np.array(mesh.positions())


@pytest.mark.parametrize("level", [1, 2, 3])
def test_closed_cube_matches_pygel3d(level):
    rng = np.random.default_rng(level)
    verts = CUBE_V + rng.normal(scale=0.05, size=CUBE_V.shape)
    ours = subdivision(8, CUBE_F, level).apply(verts)
    theirs = _oracle_gel(verts, CUBE_F, level)
    assert len(ours) == len(theirs)
    d_ours, _ = cKDTree(theirs).query(ours)
    d_theirs, _ = cKDTree(ours).query(theirs)
    assert max(d_ours.max(), d_theirs.max()) < 1e-9


def _bspline_1d(n_ctrl: int) -> sp.csr_matrix:
    """One step of uniform cubic B-spline subdivision of an open polygon with its ends kept:
    vertex points (1/8, 3/4, 1/8), edge points (1/2, 1/2), interleaved in order."""
    rows = []
    for i in range(n_ctrl):
        row = np.zeros(n_ctrl)
        if i in (0, n_ctrl - 1):
            row[i] = 1
        else:
            row[i - 1:i + 2] = (1 / 8, 3 / 4, 1 / 8)
        rows.append(row)
        if i < n_ctrl - 1:
            row = np.zeros(n_ctrl)
            row[i:i + 2] = 0.5
            rows.append(row)
    return sp.csr_matrix(np.array(rows))


@pytest.mark.parametrize("level", [1, 2, 3])
def test_open_grid_matches_the_tensor_product_bspline(level):
    """On a regular grid Catmull-Clark with B-spline boundaries is the tensor product of cubic
    B-spline curve subdivision (pygel3d's cc_subdivide aborts on meshes with a boundary)."""
    nx, nz = 5, 3
    verts, quads = grid_mesh(resolution=(nx, nz))
    verts[:, 1] += np.random.default_rng(7).normal(scale=0.05, size=len(verts))
    ours = subdivision(len(verts), quads, level).apply(verts)
    grid = verts.reshape(nx + 1, nz + 1, 3)
    for _ in range(level):
        ax, az = _bspline_1d(grid.shape[0]), _bspline_1d(grid.shape[1])
        grid = np.einsum("ai,bj,ijk->abk", ax.toarray(), az.toarray(), grid)
    theirs = grid.reshape(-1, 3)
    assert len(ours) == len(theirs)
    d_ours, _ = cKDTree(theirs).query(ours)
    d_theirs, _ = cKDTree(ours).query(theirs)
    assert max(d_ours.max(), d_theirs.max()) < 1e-9


def test_planar_grid_stays_planar_and_inside():
    verts, quads = grid_mesh(size=(1.2, 0.8), resolution=(8, 6), height=0.45)
    sub = subdivision(len(verts), quads, 3)
    fine = sub.apply(verts)
    np.testing.assert_allclose(fine[:, 1], 0.45, atol=1e-14)
    assert fine[:, 0].min() == pytest.approx(-0.6) and fine[:, 2].max() == pytest.approx(0.4)
    normals = sub.normals(fine)
    np.testing.assert_allclose(normals, np.tile([0, 1, 0], (len(fine), 1)), atol=1e-12)


def test_creases_stay_sharp():
    verts, quads = grid_mesh(resolution=(4, 4))
    verts[:, 1] = np.where(np.abs(verts[:, 0]) < 1e-9, 0.2, 0.0)  # a ridge along x = 0
    ridge = [(10, 11), (11, 12), (12, 13), (13, 14)]  # the middle row of vertices (i = 2)
    sharp = subdivision(len(verts), quads, 3, creases=ridge).apply(verts)
    smooth = subdivision(len(verts), quads, 3).apply(verts)
    on_ridge = np.abs(sharp[:, 0]) < 1e-9
    np.testing.assert_allclose(sharp[on_ridge, 1], 0.2, atol=1e-12)  # the crease keeps height
    assert smooth[np.abs(smooth[:, 0]) < 1e-9, 1].max() < 0.15  # smoothing rounds it off


def test_cached_by_topology():
    verts, quads = grid_mesh()
    a = subdivision(len(verts), quads, 3)
    b = subdivision(len(verts), quads.copy(), 3)
    assert a is b
    assert subdivision(len(verts), quads, 2) is not a


@pytest.mark.parametrize("faces, message", [
    ([[0, 1]], "3 or more vertices"),
    ([[0, 1, 9]], "indices in 0..3"),
    ([[0, 1, 1, 2]], "distinct vertices"),
    ([[0, 1, 2], [0, 1, 3], [0, 1, 2]], "manifold"),
])
def test_bad_meshes_are_named(faces, message):
    with pytest.raises(MeshError, match=message):
        subdivision(4, faces, 1)
    verts, quads = grid_mesh(resolution=(2, 2))
    with pytest.raises(MeshError, match="creases along mesh edges"):
        subdivision(len(verts), quads, 1, creases=[(0, 8)])
