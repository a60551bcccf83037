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


def _least_peak_in_the_cone(v, n, a, t, s, mu):
    """The same least peak with the exact Coulomb cone |t_k| <= mu p_k, a second-order cone
    programme solved by Clarabel (coded here from the statement, not from `least_peak`)."""
    import clarabel
    import scipy.sparse as sp

    up = np.array([0.0, 1.0, 0.0])
    skin = np.flatnonzero(s & (n @ up <= 0.17) & (a > 0))
    k = len(skin)
    corners = v[t]  # the box's centroid, from its closed triangles
    vol = np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2]))
    centre = (corners.sum(axis=1) * vol[:, None]).sum(axis=0) / (4 * vol.sum())
    nk, ak, arm = n[skin], a[skin], v[skin] - centre
    e1 = np.cross(nk, up)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(nk, e1)
    unit = WEIGHT / ak.sum()  # unknowns in units of the mean pressure: p, t1, t2 per vertex, peak
    directions = [-nk, e1, e2]
    balance = np.zeros((6, 3 * k + 1))
    for j, d in enumerate(directions):
        force = d * (ak * unit)[:, None]
        balance[:3, j * k:(j + 1) * k] = force.T
        balance[3:, j * k:(j + 1) * k] = np.cross(arm, force).T
    peak = np.zeros((k, 3 * k + 1))
    peak[:, :k] = np.eye(k)
    peak[:, -1] = -1.0
    cone = np.zeros((3 * k, 3 * k + 1))
    for i in range(k):
        cone[3 * i, i] = -mu
        cone[3 * i + 1, k + i] = -1.0
        cone[3 * i + 2, 2 * k + i] = -1.0
    a_all = sp.csc_matrix(np.vstack([balance, peak, -np.eye(3 * k + 1)[:k], cone]))
    b_all = np.concatenate([[0.0, WEIGHT, 0.0, 0.0, 0.0, 0.0], np.zeros(2 * k + 3 * k)])
    cones = [clarabel.ZeroConeT(6), clarabel.NonnegativeConeT(2 * k)] + \
        [clarabel.SecondOrderConeT(3)] * k
    q = np.zeros(3 * k + 1)
    q[-1] = 1.0
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solution = clarabel.DefaultSolver(sp.csc_matrix((3 * k + 1, 3 * k + 1)), q, a_all, b_all,
                                      cones, settings).solve()
    assert str(solution.status) == "Solved"
    return solution.x[-1] * unit / 1e3


def test_with_friction_the_least_peak_is_a_bound_below_the_exact_cones():
    """Skin of mixed slopes (the plate's normals tilted every way, some steeply): the
    programme's least peak never exceeds the exact Coulomb cone's (Clarabel, a different
    solver), and lies within the polygon's 1 / cos(pi / 16) of friction of it."""
    from solver.contact.bound import CONE_SIDES as sides
    v, n, a, t, s, _ = _box_and_plate(offset=0.06, n=9)
    rng = np.random.default_rng(3)
    tilt = rng.normal(size=(len(v) - 8, 3)) * [1.0, 0.0, 1.0]
    n = n.copy()
    n[8:] = [0.0, -1.0, 0.0] + 1.5 * tilt
    n[8:] /= np.linalg.norm(n[8:], axis=1, keepdims=True)
    bound = least_peak(v, n, a, t, s, MASS, mu=0.5)
    exact = _least_peak_in_the_cone(v, n, a, t, s, 0.5)
    wider = _least_peak_in_the_cone(v, n, a, t, s, 0.5 / np.cos(np.pi / sides))
    assert wider * (1 - 1e-6) <= bound.peak_kpa <= exact * (1 + 1e-6)
    # and without friction the two solvers agree
    assert least_peak(v, n, a, t, s, MASS).peak_kpa == pytest.approx(
        _least_peak_in_the_cone(v, n, a, t, s, 0.0), rel=1e-5)
