"""The least-peak bound against cases worked by hand: a plate under the centre of mass (uniform
pressure), under it off-centre (uniform over the part whose centroid lies under it), walls that
carry a body only by friction, and the floor sharing the load."""

import numpy as np
import pytest

from solver.contact.bound import BoundError, least_peak

MASS = 50.0
WEIGHT = MASS * 9.81


def _box_and_plate(offset: float = 0.0, n: int = 41, side: float = 0.4):
    """A closed box (its centroid at x = offset, z = 0) and, below it and not part of its
    triangles, a plate of n x n skin vertices facing down, each with its share of the area."""
    c = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (0.1, 0.5) for z in (-0.1, 0.1)])
    c[:, 0] += offset
    tris = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    u = np.linspace(-side / 2, side / 2, n)
    plate = np.array([[a, 0.1, b] for a in u for b in u])
    vertices = np.concatenate([c, plate])
    normals = np.zeros_like(vertices)
    normals[:8] = [0.0, 1.0, 0.0]
    normals[8:] = [0.0, -1.0, 0.0]
    areas = np.zeros(len(vertices))
    areas[8:] = side * side / len(plate)
    supported = np.zeros(len(vertices), dtype=bool)
    supported[8:] = True
    return vertices, normals, areas, tris, supported, side * side


def test_a_plate_under_the_centre_of_mass_carries_it_evenly():
    v, n, a, t, s, area = _box_and_plate()
    bound = least_peak(v, n, a, t, s, MASS)
    assert bound.peak_kpa == pytest.approx(WEIGHT / area / 1e3, rel=1e-6)
    assert bound.support_n == pytest.approx(WEIGHT, rel=1e-6) and bound.floor_n == 0.0


def test_off_centre_the_plate_carries_it_evenly_where_its_centroid_lies_under_the_mass():
    """The centre of mass a quarter of the plate's side off its middle: the least peak presses
    the half of the plate whose centroid lies under the mass evenly, twice the mean (on the
    grid, within a column's width)."""
    v, n, a, t, s, area = _box_and_plate(offset=0.1)
    bound = least_peak(v, n, a, t, s, MASS)
    assert bound.peak_kpa == pytest.approx(2 * WEIGHT / area / 1e3, rel=0.05)
    assert np.all(v[bound.vertices, 0] > -0.01)  # only the half under the mass


def test_walls_carry_a_body_only_by_friction():
    """Two facing walls of skin (normals along +-x): without friction nothing lifts the body;
    with mu they carry it by shear, at W / (mu x their area) at the least."""
    v, n, a, t, s, _ = _box_and_plate(n=20)  # (two halves of equal area)
    walls = v.copy()
    left = v[8:, 0] < 0
    walls[8:, 1] = 0.3 + v[8:, 2]  # the plate stood up, in two halves facing each other
    walls[8:, 2] = 0.0
    n = n.copy()
    n[8:] = np.where(left[:, None], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    with pytest.raises(BoundError, match="No forces of that kind"):
        least_peak(walls, n, a, t, s, MASS)
    bound = least_peak(walls, n, a, t, s, MASS, mu=0.5)
    assert bound.peak_kpa == pytest.approx(WEIGHT / (0.5 * a.sum()) / 1e3, rel=1e-3)


def test_the_floor_takes_what_the_support_is_not_given():
    """A support held to half the weight under a centred body: the feet (here the plate's two
    outer columns, on the floor) take the rest, and the support's peak halves."""
    v, n, a, t, s, area = _box_and_plate()
    free = least_peak(v, n, a, t, s, MASS)
    feet = np.zeros(len(v), dtype=bool)
    feet[8:] = np.abs(v[8:, 0]) > 0.19
    seat = s & ~feet
    half = least_peak(v, n, a, t, seat, MASS, feet=feet, support_load_n=WEIGHT / 2)
    assert half.support_n == pytest.approx(WEIGHT / 2, rel=1e-6)
    assert half.floor_n == pytest.approx(WEIGHT / 2, rel=1e-6)
    assert half.peak_kpa == pytest.approx(WEIGHT / 2 / a[seat].sum() / 1e3, rel=1e-6)
    assert half.peak_kpa < free.peak_kpa


def test_skin_facing_up_cannot_carry_anything():
    v, n, a, t, s, _ = _box_and_plate()
    with pytest.raises(BoundError, match="No supported skin faces down or sideways"):
        least_peak(v, -n, a, t, s, MASS)
