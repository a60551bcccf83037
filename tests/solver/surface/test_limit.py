"""Limit positions: hand-computed masks, rows summing to 1, and the independent check that
densely subdivided levels converge to them (regular, boundary, crease, dart, corner and
extraordinary vertices)."""

import numpy as np
import pytest

from solver.surface.limit import limit_matrix, limit_operator, limit_positions
from solver.surface.subdivision import MeshError, grid_mesh, subdivide_once


def _dense(vertices, faces, creases, levels):
    """The vertices after `levels` steps, applied step by step (the first n are the input's
    vertices at every level)."""
    n, f, c = len(vertices), faces, creases
    for _ in range(levels):
        step = subdivide_once(n, f, c)
        vertices, f, c, n = step.matrix @ vertices, step.faces, step.creases, step.matrix.shape[0]
    return vertices


def _fan(valence: int, rng):
    """An open fan of `valence` quads around vertex 0 (valence `valence`), jittered in 3-D."""
    k = np.arange(valence)
    ring = np.stack([np.cos(2 * np.pi * k / valence), np.zeros(valence),
                     np.sin(2 * np.pi * k / valence)], axis=1)
    mid = 0.5 * (ring + np.roll(ring, -1, axis=0)) * 0.9
    v = np.concatenate([[[0.0, 0.2, 0.0]], ring, mid]) + rng.normal(scale=0.05, size=(
        2 * valence + 1, 3))
    r, m = 1 + k, 1 + valence + k
    faces = np.stack([np.zeros(valence, int), np.roll(m, 1), r, m], axis=1)
    return v, faces


def test_regular_mask_is_the_textbook_one():
    v, f = grid_mesh((1, 1), (2, 2), 0.0)  # centre vertex 4, regular
    row = limit_operator(len(v), f).toarray()[4]
    assert row[4] == pytest.approx(16 / 36)
    assert row[[1, 3, 5, 7]] == pytest.approx([4 / 36] * 4)
    assert row[[0, 2, 6, 8]] == pytest.approx([1 / 36] * 4)
    # boundary vertex 1: (a + 4 v + b) / 6 along the boundary; corner 0 stays
    assert limit_operator(len(v), f).toarray()[1, [0, 1, 2]] == pytest.approx([1 / 6, 4 / 6,
                                                                                  1 / 6])
    assert limit_operator(len(v), f).toarray()[0, 0] == 1.0


def test_rows_sum_to_one_with_creases_and_extraordinary_vertices():
    rng = np.random.default_rng(3)
    v, f = _fan(5, rng)
    for creases in (None, [[0, 6]], [[0, 6], [0, 8]], [[0, 6], [0, 8], [0, 9]]):
        lim = limit_matrix(len(v), f, 2, creases)
        assert np.allclose(lim.sum(axis=1), 1.0)


@pytest.mark.parametrize("case", ["regular", "boundary", "crease", "dart", "valence3",
                                  "valence5", "valence6"])
def test_dense_levels_converge_to_the_limit(case):
    rng = np.random.default_rng(7)
    creases = None
    if case.startswith("valence"):
        v, f = _fan(int(case[-1]), rng)
        watch = [0]
    else:
        v, f = grid_mesh((1.0, 1.0), (4, 4), 0.3)
        v = v + rng.normal(scale=0.05, size=v.shape)
        watch = {"regular": [6, 12, 18], "boundary": [1, 2, 10], "crease": [11, 12, 13],
                 "dart": [12]}[case]
        creases = {"crease": [[10, 11], [11, 12], [12, 13], [13, 14]],
                   "dart": [[11, 12]]}.get(case)
    limit = limit_positions(v, f, 0, creases)
    errors = [np.linalg.norm(_dense(v, f, creases, k)[watch] - limit[watch], axis=1).max()
              for k in (4, 5, 6)]
    # a wrong limit would leave the error standing; here every level at least halves it, at
    # the rate of the vertex's subdominant eigenvalue (1/4 regular, 0.32 at valence 5, 0.38
    # at valence 6, 1/6 at valence 3)
    assert errors[1] < 0.5 * errors[0] and errors[2] < 0.5 * errors[1]
    assert errors[2] < 3e-4  # metres, for a control net of about a metre


def test_corner_and_crease_vertices_follow_their_curves():
    v, f = grid_mesh((1.0, 1.0), (3, 3), 0.0)
    v = v + np.random.default_rng(1).normal(scale=0.05, size=v.shape)
    limit = limit_positions(v, f, 0, [[4, 5], [5, 6], [6, 7]])
    assert np.allclose(limit[[0, 3, 12, 15, 4, 7]], v[[0, 3, 12, 15, 4, 7]])  # corners
    assert np.allclose(limit[5], (v[4] + 4 * v[5] + v[6]) / 6)


def test_non_quads_at_level_zero_are_refused():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1.0]])
    with pytest.raises(MeshError, match="Expected quads for the limit masks"):
        limit_positions(v, [[0, 1, 2]], 0)
    assert limit_positions(v, [[0, 1, 2]], 1).shape == (7, 3)
    with pytest.raises(MeshError, match=r"shape \(n, 3\)"):
        limit_positions(v[:, :2], [[0, 1, 2]], 1)
