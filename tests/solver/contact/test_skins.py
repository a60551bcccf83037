"""A closed skin's search structures are built once per skin and kept: the same tree for the same
vertices and triangles (also when given as another array), a new one when the skin moves, and
the same winding numbers as libigl's one-call `fast_winding_number`."""

import igl
import numpy as np
import trimesh

from solver.contact import skins
from solver.contact.skins import KEPT_SKINS, body_winding, vertex_tree


def _ball(centre=(0.0, 0.0, 0.0), radius=0.1):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return np.asarray(sphere.vertices) + centre, np.asarray(sphere.faces)


def test_a_skin_keeps_its_trees_whatever_array_holds_it():
    vertices, triangles = _ball()
    winding = body_winding(vertices, triangles)
    assert body_winding(vertices.copy(), triangles.astype(np.int32)) is winding
    assert vertex_tree(vertices.copy()) is vertex_tree(vertices)
    moved = vertices + [0.0, 0.01, 0.0]
    assert body_winding(moved, triangles) is not winding
    assert vertex_tree(moved) is not vertex_tree(vertices)


def test_kept_winding_numbers_are_libigls():
    vertices, triangles = _ball((0.3, 0.2, -0.1))
    points = np.random.default_rng(3).uniform(0.1, 0.5, (500, 3)) - [0.0, 0.0, 0.3]
    got = body_winding(vertices, triangles).winding_number(points)
    assert np.array_equal(got, igl.fast_winding_number(vertices, triangles, points))
    assert 0 < (got > 0.5).sum() < len(points)


def test_the_skins_asked_for_least_recently_go_first(monkeypatch):
    monkeypatch.setattr(skins, "_SKINS", skins.KeptByContent(KEPT_SKINS))
    first, second = _ball(), _ball((0.5, 0.0, 0.0))
    winding, other = body_winding(*first), body_winding(*second)
    for k in range(1, KEPT_SKINS):
        body_winding(first[0] + [0.0, 0.01 * k, 0.0], first[1])
        assert body_winding(*first) is winding  # asked for again: kept
    assert len(skins._SKINS) == KEPT_SKINS
    assert body_winding(*second) is not other  # the one not asked for since went
