"""The settle against statics worked out by hand: boxes on foam, on a slope, on two pads."""

import numpy as np
import pytest
import trimesh

from solver.contact.settle import G, Foam, Support, settle
from solver.mesh import SurfaceMesh, triangle_mesh


def _box(size, centre, pitch=0.05):
    """A closed box mesh with edges about `pitch` long: vertices, normals, areas, triangles."""
    mesh = trimesh.creation.box(extents=size)
    v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, pitch)
    m = trimesh.Trimesh(v, f, process=True)
    v = np.asarray(m.vertices) + centre
    t = np.asarray(m.faces)
    areas, normals = triangle_mesh(t, len(v)).measures(v)
    return v, normals, areas, t


def _plane(height=0.0, slope_deg=0.0, half=2.0):
    """A square plane facing up, turned `slope_deg` about z."""
    v = np.array([[-half, 0, -half], [-half, 0, half], [half, 0, half], [half, 0, -half]], float)
    a = np.radians(slope_deg)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return SurfaceMesh.from_quads(v @ rot.T + [0, height, 0], np.array([[0, 1, 2, 3]]))


def _load(settled, name):
    c = next(c for c in settled.contacts if c.name == name)
    return (c.normal_force[:, None] * c.normals + c.tangential_force).sum(axis=0), c


def test_box_on_foam_sinks_by_weight_over_area_and_stiffness():
    """A 0.4 x 0.3 m box of 20 kg on 200 kPa/m foam: pressure m g / A = 1635 Pa everywhere
    under it, so it sinks 8.2 mm, straight down, carried wholly by the foam (within 3 %: the
    bottom edge's vertices share their areas with the sides)."""
    v, n, a, t = _box((0.4, 0.2, 0.3), [0, 0.1, 0], pitch=0.0125)
    foam = Foam(200e3, thickness=0.1)
    s = settle(v, n, a, t, 20.0, [Support("seat", foam, _plane())])
    assert s.stable and s.reason is None
    force, c = _load(s, "seat")
    weight = 20.0 * G
    assert np.linalg.norm(force - [0, weight, 0]) < 0.01 * weight
    assert np.linalg.norm(s.net_force) < 0.01 * weight and np.linalg.norm(s.net_moment) < 1.0
    assert s.translation[1] == pytest.approx(-weight / 0.12 / 200e3, rel=0.03)
    assert np.abs(s.translation[[0, 2]]).max() < 1e-4 and np.abs(s.rotation).max() < 1e-3
    pressure = c.normal_force / a[c.vertices]
    interior = np.all(np.abs(v[c.vertices][:, [0, 2]]) < [0.15, 0.1], axis=1)
    assert pressure[interior] == pytest.approx(weight / 0.12, rel=0.02)


@pytest.mark.parametrize("slope, mu, rests", [(10.0, 0.5, True), (20.0, 0.5, True),
                                              (26.0, 0.5, True), (35.0, 0.5, False),
                                              (20.0, 0.2, False)])
def test_box_on_a_slope_rests_while_friction_holds_it(slope, mu, rests):
    """On a slope the foam carries m g cos(a) and friction m g sin(a), which it can while
    tan(a) <= mu; past that the box slides off and the settle says so."""
    v, n, a, t = _box((0.4, 0.2, 0.3), [0, 0.1, 0])
    rot = np.radians(slope)
    turn = np.array([[np.cos(rot), -np.sin(rot), 0], [np.sin(rot), np.cos(rot), 0], [0, 0, 1]])
    v, n = v @ turn.T, n @ turn.T
    s = settle(v, n, a, t, 20.0, [Support("seat", Foam(200e3, friction=mu), _plane(0.0, slope))])
    assert s.stable is rests, s.reason
    if rests:
        force, c = _load(s, "seat")
        weight = 20.0 * G
        assert np.linalg.norm(force - [0, weight, 0]) < 0.01 * weight
        assert c.normal_force.sum() == pytest.approx(weight * np.cos(rot), rel=0.01)
        assert np.linalg.norm(c.tangential_force.sum(axis=0)) == pytest.approx(
            weight * np.sin(rot), rel=0.01)
    else:
        assert "slide" in s.reason or "no rest" in s.reason or "tips" in s.reason


def test_a_plank_on_two_supports_splits_its_weight_by_the_lever_rule():
    """A 1 m plank whose centre of mass sits 0.2 m from one end's pad and 0.6 m from the other
    (pads 0.8 m apart): 3/4 of the weight on the near pad, 1/4 on the far one, whichever is
    the stiffer (a stiff floor pad and a soft seat)."""
    v, n, a, t = _box((1.0, 0.05, 0.2), [0, 0.025, 0])
    pad = lambda x0, x1, h: SurfaceMesh.from_quads(  # noqa: E731
        np.array([[x0, h, -0.2], [x0, h, 0.2], [x1, h, 0.2], [x1, h, -0.2]]),
        np.array([[0, 1, 2, 3]]))
    near = Support("near", Foam(300e3), pad(0.1, 0.3, 0.0))  # pad centred 0.2 m right of the centre
    far = Support("far", Foam(3e6), pad(-0.7, -0.5, 0.0))  # reaches the plank's end at -0.5
    s = settle(v, n, a, t, 10.0, [near, far], centre=np.array([0.0, 0.025, 0.0]))
    assert s.stable, s.reason
    w = 10.0 * G
    f_near, _ = _load(s, "near")
    f_far, _ = _load(s, "far")
    # the far pad touches the plank over x in [-0.5, -0.45] (its last vertex row): the lever
    # arms are about the near pad's and the far contact's centres of pressure
    x_near = (lambda c: (c.normal_force @ c.points[:, 0]) / c.normal_force.sum())(_load(s, "near")[1])
    x_far = (lambda c: (c.normal_force @ c.points[:, 0]) / c.normal_force.sum())(_load(s, "far")[1])
    share_far = (x_near - 0.0) / (x_near - x_far)
    assert f_far[1] == pytest.approx(share_far * w, rel=0.02)
    # by hand, with the near pad's centre (0.2 m) and the plank's end (-0.5 m): 2/7 of it
    assert f_far[1] == pytest.approx(2 / 7 * w, rel=0.1)
    assert f_near[1] + f_far[1] == pytest.approx(w, rel=0.01)


def test_a_tall_box_on_a_pad_off_its_centre_tips_over():
    """A tall box whose centre of mass stands beside the one pad under it has no rest."""
    v, n, a, t = _box((0.2, 1.0, 0.2), [0, 0.5, 0])
    pad = SurfaceMesh.from_quads(np.array([[0.05, 0, -0.2], [0.05, 0, 0.2], [0.3, 0, 0.2],
                                           [0.3, 0, -0.2]]), np.array([[0, 1, 2, 3]]))
    s = settle(v, n, a, t, 30.0, [Support("pad", Foam(200e3), pad)])
    assert not s.stable and s.contacts == []
    assert "tips over" in s.reason or "no rest" in s.reason


def test_nothing_under_the_body_is_reported_not_a_number():
    v, n, a, t = _box((0.4, 0.2, 0.3), [0, 1.0, 0])
    s = settle(v, n, a, t, 20.0, [Support("seat", Foam(200e3), _plane())])
    assert not s.stable and "no support" in s.reason


def test_a_body_lying_on_a_bed_rests_on_it_alone():
    """The default body lying on its back on a flat bed of foam (no floor under it): at rest in
    equilibrium, its whole weight on the bed, sunk by about what its weight over its footprint
    asks of the foam."""
    from solver.body.model import make_body
    from solver.scene.validate import validation_poses

    body = make_body()
    v = validation_poses()["lying"]
    v = v - [0.0, v[:, 1].min() - 0.45, 0.0]  # on a bed 0.45 m high
    areas, normals = triangle_mesh(body.triangles, len(v)).measures(v)
    bed = _plane(0.45)
    s = settle(v, normals, areas, body.triangles, body.mass_kg,
               [Support("bed", Foam(200e3), bed), Support("floor", Foam(30000e3, 0.02))])
    assert s.stable, s.reason
    weight = body.mass_kg * G
    assert [c.name for c in s.contacts] == ["bed"]
    force, c = _load(s, "bed")
    assert np.linalg.norm(force - [0, weight, 0]) < 0.01 * weight
    assert np.linalg.norm(s.net_moment) < 1.0
    assert 0.005 < -s.translation[1] < 0.1


@pytest.mark.parametrize("mu", [0.05, 0.5])  # most contacts slipping, and sticking
def test_the_balance_jacobian_is_the_finite_difference(mu):
    """The Newton step's Jacobian of the net force and moment against central differences, on
    a tilted box pressed into foam on a slope, moved and turned off its placement."""
    from solver.contact import settle as s

    v, n, a, t = _box((0.4, 0.2, 0.3), [0, 0.1, 0])
    rot = np.radians(15.0)
    turn = np.array([[np.cos(rot), -np.sin(rot), 0], [np.sin(rot), np.cos(rot), 0], [0, 0, 1]])
    v, n = v @ turn.T - [0.0, 0.01, 0.0], n @ turn.T
    support = Support("seat", Foam(200e3, friction=mu), _plane(0.0, 10.0))
    subset, _, _ = s._prepare(support, v, n, None, lambda p: np.zeros(len(p), bool), 0)
    centre = s.volume_centroid(v, t)
    moved = v + [0.002, -0.001, 0.001]
    cand = s._candidates(support, 0, moved, subset)
    groups = [s._group(support, moved, v, centre, a, n, cand)]
    weight = np.array([0.0, -20 * G, 0.0])
    q = np.array([0.001, -0.002, 0.0005, 0.01, -0.02, 0.015])
    _, jac = s._balance(q, groups, weight)
    numeric = np.zeros((6, 6))
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = 1e-8
        numeric[:, i] = (s._balance(q + dq, groups, weight)[0]
                         - s._balance(q - dq, groups, weight)[0]) / 2e-8
    assert np.abs(jac - numeric).max() <= 1e-5 * np.abs(numeric).max()


@pytest.mark.parametrize("tilt", [3.0, 5.0, 10.0])
def test_a_box_landing_on_its_edge_comes_down_flat(tilt):
    """Tilted a few degrees with its low edge on the foam (or just above), the box turns down
    onto its face, as a box does, rather than balancing on the edge."""
    v, n, a, t = _box((0.4, 0.2, 0.3), [0, 0.1, 0])
    r = np.radians(tilt)
    turn = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    v, n = v @ turn.T, n @ turn.T
    v = v - [0.0, v[:, 1].min() - 0.002, 0.0]
    s = settle(v, n, a, t, 20.0, [Support("seat", Foam(200e3), _plane())])
    assert s.stable, s.reason
    assert np.degrees(s.rotation[2]) == pytest.approx(-tilt, abs=0.5)


def test_a_box_placed_deep_in_the_foam_is_pushed_back_up():
    """Placed 7 cm into 10 cm of foam (ten times what its weight needs), the box rises to where
    the foam carries it: 8.2 mm in (within 5 %: the bottom edge's vertices share their areas
    with the sides)."""
    v, n, a, t = _box((0.4, 0.2, 0.3), [0, 0.1 - 0.07, 0], pitch=0.0125)
    s = settle(v, n, a, t, 20.0, [Support("seat", Foam(200e3, thickness=0.1), _plane())])
    assert s.stable, s.reason
    assert s.vertices[:, 1].min() == pytest.approx(-20 * G / 0.12 / 200e3, rel=0.05)


def test_past_its_thickness_the_foam_bottoms_out():
    """A 1 cm foam under a 200 kg box: 16 kPa would press it 8 cm at 200 kPa/m; past 1 cm it is
    20 times stiffer, so the box sinks 1 cm + (p - k h) / (20 k)."""
    v, n, a, t = _box((0.4, 0.2, 0.3), [0, 0.1, 0], pitch=0.0125)
    s = settle(v, n, a, t, 200.0, [Support("seat", Foam(200e3, thickness=0.01), _plane())])
    assert s.stable, s.reason
    p = 200 * G / 0.12
    assert -s.vertices[:, 1].min() == pytest.approx(0.01 + (p - 200e3 * 0.01) / (20 * 200e3),
                                                    rel=0.05)


def test_a_plank_tipping_off_a_soft_pad_comes_to_rest_on_the_floor_not_through_it():
    """A plank on a soft pad under its right part sinks and tips left until its left end,
    6.5 cm above the floor at first (beyond the first look for contacts), reaches the floor;
    it must rest on the floor, not pass through it."""
    v, n, a, t = _box((1.2, 0.05, 0.2), [0, 0.025, 0], pitch=0.025)
    pad = SurfaceMesh.from_quads(np.array([[-0.1, 0, -0.3], [-0.1, 0, 0.3], [0.6, 0, 0.3],
                                           [0.6, 0, -0.3]]), np.array([[0, 1, 2, 3]]))
    s = settle(v, n, a, t, 10.0, [Support("pad", Foam(50e3), pad),
                                  Support("floor", Foam(30000e3, 0.02), height=-0.065)],
               centre=np.array([0.0, 0.025, 0.0]))
    assert s.stable, s.reason
    assert {c.name for c in s.contacts} == {"pad", "floor"}
    assert s.vertices[:, 1].min() > -0.065 - 0.002


def test_skin_beside_a_border_below_the_surface_is_not_in_its_foam():
    """The foam lies behind the surface only: skin 3 cm beside a pad's border and 5 cm below
    its plane (its closest point on the border, the offset running off it sideways) presses
    nothing, while skin 5 cm below the pad's middle presses 5 cm in; skin just beyond the
    border but nearly straight below it (within 18 degrees of the normal) still counts."""
    from solver.contact import settle as s

    pad = SurfaceMesh.from_quads(np.array([[-0.2, 0, -0.2], [-0.2, 0, 0.2], [0.2, 0, 0.2],
                                           [0.2, 0, -0.2]]), np.array([[0, 1, 2, 3]]))
    support = Support("pad", Foam(200e3), pad)
    x = np.array([[0.23, -0.05, 0.0], [0.0, -0.05, 0.0], [0.21, -0.05, 0.0]])
    c = s._candidates(support, 0, x, np.arange(3))
    assert list(c.index) == [1, 2]
    np.testing.assert_allclose(c.depth[0], 0.05)
    # the same skin moved there from over the pad (the settle's later looks): the sideways
    # skin drops out
    before = x - [0.2, 0.0, 0.0]
    prev = s._candidates(support, 0, before, np.arange(3))
    assert list(prev.index) == [0, 1, 2]
    again = s._candidates(support, 0, x, prev.index, prev, before[prev.index])
    assert list(again.index) == [1, 2]
    np.testing.assert_allclose(again.depth, 0.05)


def test_steps_that_overshoot_are_followed_by_shorter_ones(monkeypatch):
    """A settle whose every step overshoots its balance twice over (Newton's step
    made twice as long: the body rocks across its rest, as on contacts that come and go)
    still comes to the rest of the box on foam above (within 0.3 mm): after a step that did not
    shrink the imbalance the next goes half as far. Without that it rocks until its steps run
    out."""
    from solver.contact import settle as S

    v, n, a, t = _box((0.4, 0.2, 0.3), [0, 0.1, 0], pitch=0.025)
    foam = Foam(200e3, thickness=0.1)
    plain = settle(v, n, a, t, 20.0, [Support("seat", foam, _plane())])
    newton = S._newton
    monkeypatch.setattr(S, "_newton", lambda *args: 2.0 * newton(*args))
    rocked = settle(v, n, a, t, 20.0, [Support("seat", foam, _plane())])
    assert plain.stable and rocked.stable, rocked.reason
    np.testing.assert_allclose(rocked.translation, plain.translation, atol=3e-4)
