"""Cutter reach: a trough of known radius, a 6 mm and a 20 mm ball-nose."""

import numpy as np
import pytest

from solver.io.reach import ReachError, bending_towards_normal, cutter_reach, render_reach

RADIUS = 0.012


def test_bend_towards_the_bodies_is_positive_in_a_trough(trough, fine_ridge):
    middle = np.abs(trough[0][:, 0]) < 0.5 * trough[2]
    assert np.allclose(bending_towards_normal(*trough[:2])[middle, 0], 1 / RADIUS, rtol=0.05)
    assert np.allclose(bending_towards_normal(*fine_ridge[:2])[middle, 1], -1 / RADIUS, rtol=0.05)


def test_a_6_mm_ball_reaches_all_of_a_12_mm_trough(trough):
    reach = cutter_reach(trough[0], trough[1], 0.006)
    assert reach.unreachable.sum() == 0 and reach.unreachable_area_m2 == 0.0
    assert reach.min_concave_radius_m == pytest.approx(RADIUS, rel=0.05)


def test_a_20_mm_ball_misses_the_trough_and_only_the_trough(trough):
    vertices, quads, half = trough
    reach = cutter_reach(vertices, quads, 0.020)
    x = np.abs(vertices[:, 0])
    assert reach.unreachable[x < 0.9 * half].all()  # the whole hollow
    assert not reach.unreachable[x > half + 0.002].any()  # the flanks are flat
    # the hollow's area: arc length (2 r theta0) times the trough's length
    arc = 2 * RADIUS * np.pi / 3 * 0.04
    assert reach.unreachable_area_m2 == pytest.approx(arc, rel=0.15)


def test_a_ridge_is_no_hollow(fine_ridge):
    reach = cutter_reach(fine_ridge[0], fine_ridge[1], 0.020)
    assert reach.unreachable.sum() == 0 and reach.min_concave_radius_m > 1.0
    assert reach.min_convex_radius_m == pytest.approx(RADIUS, rel=0.05)
    assert reach.summary()["unreachable_vertices"] == 0


def test_reach_picture_is_a_png(tmp_path, trough):
    reach = cutter_reach(trough[0], trough[1], 0.020)
    path = render_reach(tmp_path / "reach.png", trough[0], trough[1], reach)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("radius", [0.0, -1.0, float("inf"), float("nan"), 1e308, 0.2])
def test_bad_tool_radius_is_named(trough, radius):
    with pytest.raises(ReachError, match=r"tool radius in \(0, 0.1\] m"):
        cutter_reach(trough[0], trough[1], radius)
