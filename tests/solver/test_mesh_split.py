"""Splitting one control quad into four (`solver.mesh.split_quad`): the mesh stays all quads,
closed meshes stay closed (checked by trimesh), the net keeps its shape and creases halve."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from solver.mesh import MeshSplitError, quad_triangles, split_quad
from solver.surface.subdivision import grid_mesh, subdivision

CUBE_V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
CUBE_Q = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4],
                   [1, 5, 7, 3]])


def _trimesh(v, q) -> trimesh.Trimesh:
    return trimesh.Trimesh(v, quad_triangles(q), process=False)


def test_a_cube_face_splits_into_four_and_the_cube_stays_closed():
    before = _trimesh(CUBE_V, CUBE_Q)
    assert before.is_watertight and before.is_winding_consistent
    v, q, _ = split_quad(CUBE_V, CUBE_Q, 0)
    # two loop cuts around the cube: 8 edge middles, the split face and its opposite quartered
    assert (len(v), len(q)) == (8 + 8 + 2, 2 * 4 + 4 * 2)
    after = _trimesh(v, q)
    assert after.is_watertight and after.is_winding_consistent
    assert after.euler_number == before.euler_number == 2
    assert after.volume == pytest.approx(before.volume)
    assert np.array_equal(v[:8], CUBE_V)  # old vertices keep their indices
    subdivision(len(v), q, 2)  # Catmull-Clark takes it


def test_a_grid_quad_splits_its_row_and_column():
    v0, q0 = grid_mesh((1.2, 0.8), (8, 6), 0.45)
    v, q, creases = split_quad(v0, q0, 20, creases=[tuple(q0[20, :2]), (0, 1)])
    assert (len(v), len(q)) == (10 * 8, 9 * 7)  # one more grid line either way
    before, after = _trimesh(v0, q0), _trimesh(v, q)
    assert after.area == pytest.approx(before.area)
    assert after.euler_number == before.euler_number == 1
    assert np.allclose(v[:, 1], 0.45)
    # the face's normals still point the same way
    assert np.allclose(after.face_normals.mean(axis=0), before.face_normals.mean(axis=0))
    a, b = q0[20, :2]
    (m,) = [j for i, j in creases if i == a]  # the split crease's middle
    assert (m, b) in creases and m >= len(v0)
    assert np.allclose(v[m], (v0[a] + v0[b]) / 2)
    assert (0, 1) in creases and len(creases) == 3


def test_splitting_is_checked():
    v0, q0 = grid_mesh((1.0, 1.0), (2, 2), 0.4)
    with pytest.raises(MeshSplitError, match="face in 0..3, got 4"):
        split_quad(v0, q0, 4)
    fin = np.concatenate([q0, [[q0[0, 0], q0[0, 1], 0, 0]]])
    with pytest.raises(MeshSplitError):
        split_quad(v0, fin[:, :3], 0)


def test_a_surface_mesh_with_nothing_to_search_is_refused_before_libigl_sees_it():
    """libigl's search tree on an empty or ill-indexed mesh ends the process: refused first."""
    from solver.mesh import SurfaceMesh, SurfaceMeshError

    with pytest.raises(SurfaceMeshError, match="0 vertices and 0 faces"):
        SurfaceMesh.from_triangles(np.zeros((0, 3)), np.zeros((0, 3), int))
    square = np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]])
    with pytest.raises(SurfaceMeshError, match=r"indices in 0..3, got 0..7"):
        SurfaceMesh.from_quads(square, np.array([[0, 1, 2, 7]]))
    bad = square.copy()
    bad[1, 1] = np.inf
    with pytest.raises(SurfaceMeshError, match="finite surface vertices, got 1"):
        SurfaceMesh.from_quads(bad, np.array([[0, 1, 2, 3]]))
    mesh = SurfaceMesh.from_quads(square, np.array([[0, 3, 2, 1]]))
    assert mesh.closest(np.array([[0.5, 0.1, 0.5]]))[0][0] == pytest.approx(0.1)
