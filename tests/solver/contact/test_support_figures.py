"""The support figures a relaxation may not make worse: one computation for the report and the
relaxation's gate, the penetration depth checked against libigl's exact winding number and
distance, and which way each figure is better."""

import numpy as np
import pytest
import trimesh

from solver.contact.evaluate import (SUPPORT_FIGURES, SupportGate, evaluate_person,
                                     penetration_depth, support_figures, worse_figures)
from solver.contact.settle import Foam
from solver.contact.supported import SupportedBody
from solver.mesh import SurfaceMesh, triangle_mesh
from solver.surface.subdivision import grid_mesh


def _ball(centre, radius=0.1, subdivisions=3):
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(sphere.vertices) + centre, np.asarray(sphere.faces)


def _plane(height=0.0, size=0.6, cells=48):
    vertices, quads = grid_mesh((size, size), (cells, cells), height)
    return SurfaceMesh.from_quads(vertices, quads)


def _oracle_depth(points, vertices, triangles):
    """Largest exact distance to the skin of the points whose exact winding number (libigl's
    `winding_number`, no tree) is above one half."""
    import igl

    inside = points[igl.winding_number(vertices, triangles, points) > 0.5]
    if not len(inside):
        return 0.0
    return float(np.sqrt(igl.point_mesh_squared_distance(inside, vertices, triangles)[0].max()))


@pytest.mark.parametrize("sunk", [0.0, 0.004, 0.021, 0.06])
def test_penetration_depth_of_a_plane_through_a_ball(sunk):
    plane = _plane()
    vertices, triangles = _ball([0.003, 0.1 - sunk, -0.002])
    got = penetration_depth(plane.vertices, vertices, triangles)
    assert got == pytest.approx(_oracle_depth(plane.vertices, vertices, triangles), abs=1e-12)
    # a plane through a sphere sunk s into it reaches s into it (the facets cost a little)
    assert got == pytest.approx(sunk, abs=1.5e-3)


def test_penetration_depth_where_the_body_overlaps_itself_is_the_distance_to_its_skin():
    # two overlapping balls, one mesh: inside both the winding number is 2; the depth there is
    # still the distance to the skin (a signed distance scaled by 1 - 2 w would triple it)
    a, ta = _ball([0.0, 0.0, 0.0])
    b, tb = _ball([0.06, 0.0, 0.0])
    vertices, triangles = np.concatenate([a, b]), np.concatenate([ta, tb + len(a)])
    points = np.array([[0.03, 0.0, 0.0], [0.03, 0.05, 0.0], [-0.05, 0.0, 0.0]])
    depth = penetration_depth(points, vertices, triangles)
    assert depth == pytest.approx(_oracle_depth(points, vertices, triangles), abs=1e-12)
    assert depth == pytest.approx(0.1 - 0.03, abs=2e-3)  # the centre point, 3 cm off each centre


def test_penetration_depth_on_a_random_cloud_matches_the_oracle():
    rng = np.random.default_rng(7)
    vertices, triangles = _ball([0.0, 0.0, 0.0], radius=0.12, subdivisions=2)
    vertices = vertices * [1.0, 0.6, 0.8] + rng.normal(scale=0.003, size=vertices.shape)
    points = rng.uniform(-0.15, 0.15, size=(2000, 3))
    assert penetration_depth(points, vertices, triangles) == pytest.approx(
        _oracle_depth(points, vertices, triangles), abs=1e-12)
    assert penetration_depth(points[:0], vertices, triangles) == 0.0
    assert penetration_depth(points[np.abs(points).max(axis=1) > 0.14][:0] + 1.0, vertices,
                             triangles) == 0.0


def _sunk_ball(sunk):
    vertices, triangles = _ball([0.0, 0.1 - sunk, 0.0])
    areas, normals = triangle_mesh(triangles, len(vertices)).measures(vertices)
    importance = np.where(vertices[:, 1] < 0.05 - sunk, 1.0, 0.0)
    return SupportedBody(vertices, normals, importance, "ball", triangles, areas, mass_kg=5.0)


def test_the_report_and_the_gate_give_the_same_figures():
    plane, foam = _plane(), Foam(200e3)
    for sunk in (-0.01, 0.002, 0.02, 0.05):
        ball = _sunk_ball(sunk)
        report, _ = evaluate_person(plane, ball, 0.03, foam, floor=None)
        gate = SupportGate(plane, ball.importance, ball.triangles, 0.03, foam)
        figures = gate.figures(ball.vertices)
        assert set(figures) == set(SUPPORT_FIGURES)
        assert figures == {name: report[name] for name in SUPPORT_FIGURES}
    # hovering 1 cm over the plane, sinking 2 cm into it, sinking 5 cm (past the margin)
    hover, sink, deep = (support_figures(plane, b.vertices, b.importance, b.triangles, 0.03,
                                         foam) for b in map(_sunk_ball, (-0.01, 0.02, 0.05)))
    assert hover["contact_coverage"] == 0.0 and hover["max_penetration_m"] == 0.0
    assert sink["contact_coverage"] > 0.5 and sink["max_penetration_m"] == pytest.approx(
        0.02, abs=1.5e-3)
    assert {"mean_support_distance_m", "max_penetration_m"} <= set(worse_figures(sink, deep))
    assert "max_penetration_m" not in worse_figures(deep, sink)


def test_skin_level_with_a_face_far_beside_it_is_not_in_contact():
    """A ball whose upper half is important, 1 m beside a 20 cm plate whose plane runs
    through its middle: none of it is within the margin of the plate, so none of it is in
    contact either (measured along the plate's normal alone, the skin up to 5 mm over the
    plate's height read as touching it). Checked with trimesh's own closest points."""
    plate, foam = _plane(height=0.1, size=0.2, cells=4), Foam(200e3)
    vertices, triangles = _ball([1.1, 0.1, 0.0])
    importance = np.where(vertices[:, 1] >= 0.1, 1.0, 0.0)
    assert np.any((vertices[:, 1] >= 0.1) & (vertices[:, 1] <= 0.105))  # (the case at issue)
    figures = support_figures(plate, vertices, importance, triangles, 0.03, foam)
    mesh = trimesh.Trimesh(plate.vertices, plate.triangles, process=False)
    _, gap, _ = trimesh.proximity.closest_point(mesh, vertices[importance > 0])
    assert gap.min() > 0.8  # (the oracle: nothing within reach)
    assert figures["coverage"] == 0.0 and figures["contact_coverage"] == 0.0


def test_a_vertex_no_face_uses_cuts_nothing():
    """A plate 1 cm under a ball, and one more vertex, used by no face, 2 cm inside the
    ball: the surface does not cut into the ball (the stray vertex read as a 2 cm cut)."""
    plate, foam = _plane(), Foam(200e3)
    ball = _sunk_ball(-0.01)
    stray = SurfaceMesh.from_triangles(
        np.concatenate([plate.vertices, [[0.0, 0.03, 0.0]]]), plate.triangles)
    figures = support_figures(stray, ball.vertices, ball.importance, ball.triangles, 0.03,
                              foam)
    assert figures["max_penetration_m"] == 0.0
    assert figures == support_figures(plate, ball.vertices, ball.importance, ball.triangles,
                                      0.03, foam)


def test_figures_stop_short_once_the_cheap_ones_are_worse_than_the_reference():
    plane, foam = _plane(), Foam(200e3)
    near, far = _sunk_ball(0.002), _sunk_ball(-0.02)
    reference = support_figures(plane, near.vertices, near.importance, near.triangles, 0.03,
                                foam)
    short = support_figures(plane, far.vertices, far.importance, far.triangles, 0.03, foam,
                            reference=reference)
    assert set(short) == {"mean_support_distance_m", "coverage"}
    assert worse_figures(reference, short) == ["mean_support_distance_m", "coverage"]
    # not worse by those: all of them
    full = support_figures(plane, near.vertices, near.importance, near.triangles, 0.03, foam,
                           reference=short)
    assert full == reference


def test_worse_figures_knows_which_way_is_better():
    before = {"mean_support_distance_m": 0.01, "coverage": 0.8, "contact_coverage": 0.5,
              "max_penetration_m": 0.02}
    assert worse_figures(before, dict(before)) == []
    assert worse_figures(before, {**before, "mean_support_distance_m": 0.009,
                                  "coverage": 0.9, "contact_coverage": 0.6,
                                  "max_penetration_m": 0.01}) == []
    assert worse_figures(before, {**before, "coverage": 0.79999,
                                  "max_penetration_m": 0.02001}) == ["coverage",
                                                                     "max_penetration_m"]
    none = {**before, "mean_support_distance_m": None}
    assert worse_figures(none, none) == []
    assert worse_figures(before, none) == ["mean_support_distance_m"]
    assert worse_figures(before, {"coverage": 0.9}) == []  # only what both have is compared


def test_the_deepest_cut_names_its_skin_triangle_and_region():
    """Two balls of two regions, a plane sunk 21 mm into the right one and 4 mm into the left:
    the deepest cut is the right ball's (one of its triangles), and the
    figures name its region."""
    from solver.body.model import BODY_REGIONS
    from solver.contact.evaluate import deepest_cut

    left, tl = _ball([-0.15, 0.1 - 0.004, 0.0])
    right, tr = _ball([0.15, 0.1 - 0.021, 0.0])
    vertices, triangles = np.concatenate([left, right]), np.concatenate([tl, tr + len(left)])
    regions = np.concatenate([np.full(len(left), BODY_REGIONS.index("pelvis")),
                              np.full(len(right), BODY_REGIONS.index("calves"))])
    plane = _plane(size=0.8, cells=64)
    depth, face = deepest_cut(plane.vertices, vertices, triangles)
    assert depth == pytest.approx(_oracle_depth(plane.vertices, vertices, triangles), abs=1e-12)
    assert face >= len(tl)  # one of the right ball's triangles
    figures = support_figures(plane, vertices, np.ones(len(vertices)), triangles, 0.03,
                              Foam(200e3), regions=regions)
    assert figures["deepest_cut_region"] == "calves"
    assert figures["max_penetration_m"] == pytest.approx(depth)
    high, high_t = _ball([0.0, 0.5, 0.0])  # a body above the plane: no cut, no region
    none = support_figures(plane, high, np.ones(len(high)), high_t, 0.03, Foam(200e3),
                           regions=np.zeros(len(high), dtype=int))
    assert none["max_penetration_m"] == 0.0 and none["deepest_cut_region"] is None
