"""The flat seat at the same load (solver.contact.evaluate.flat_at_same_load), against statics
worked out by hand and against the settle on a flat plane (a Newton solve of the body's six
balance equations with friction, where the baseline solves one equation for a plane's height)."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from solver.contact.evaluate import flat_at_same_load, flat_surface
from solver.contact.settle import G, Foam, Support, settle
from solver.contact.supported import SupportedBody
from solver.mesh import triangle_mesh


def _box(size, centre, pitch=0.0125):
    mesh = trimesh.creation.box(extents=size)
    v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, pitch)
    m = trimesh.Trimesh(v, f, process=True)
    v, t = np.asarray(m.vertices) + centre, np.asarray(m.faces)
    areas, normals = triangle_mesh(t, len(v)).measures(v)
    return SupportedBody(v, normals, np.ones(len(v)), triangles=t, areas=areas, mass_kg=0.0)


def _rested(body: SupportedBody, mass: float, foam: Foam, height: float = 0.0):
    """The body settled on a flat plane at `height` named as a fitted surface's seat."""
    s = settle(body.vertices, body.normals, body.areas, body.triangles, mass,
               [Support("seat", foam, flat_surface(height, body.vertices.mean(axis=0)))])
    assert s.stable, s.reason
    return s


def test_a_box_held_where_it_rests_on_a_plane_finds_that_plane_and_its_pressure():
    """A 0.4 x 0.3 m box of 20 kg at rest on 200 kPa/m foam: the flat seat carrying what the
    plane carries lies where the plane lies (the box sank 8.2 mm into it), at m g / A = 1635 Pa
    under the box's inside (its bottom edge shares area with the sides, which the plane's
    pressure sees no more than the settle's)."""
    box = _box((0.4, 0.2, 0.3), [0, 0.1, 0])
    foam = Foam(200e3, thickness=0.1)
    s = _rested(box, 20.0, foam)
    flat = flat_at_same_load(box, s, foam)
    weight = 20.0 * G
    assert flat["load_n"] == pytest.approx(weight, rel=0.01)
    assert flat["load_share"] == pytest.approx(1.0, rel=0.01)
    assert flat["height_m"] == pytest.approx(0.0, abs=2e-4)
    assert flat["contact_area_m2"] == pytest.approx(0.12, rel=0.03)
    assert flat["mean_pressure_kpa"] == pytest.approx(weight / 0.12 / 1e3, rel=0.03)
    seat = next(c for c in s.contacts if c.name == "seat")
    settle_peak = (seat.normal_force / seat.areas).max() / 1e3
    assert flat["peak_pressure_kpa"] == pytest.approx(settle_peak, rel=0.02)


def test_past_its_thickness_the_flat_seat_bottoms_out_as_the_settle_does():
    """A 200 kg box on 1 cm of foam: uniform 16.3 kPa under it (the load over the area, whatever
    the foam), the plane 1 cm + (p - k h) / (20 k) above the box's bottom."""
    box = _box((0.4, 0.2, 0.3), [0, 0.1, 0])
    foam = Foam(200e3, thickness=0.01)
    s = _rested(box, 200.0, foam)
    flat = flat_at_same_load(box, s, foam)
    p = 200 * G / 0.12
    assert flat["height_m"] - s.vertices[:, 1].min() == pytest.approx(
        0.01 + (p - 200e3 * 0.01) / (20 * 200e3), rel=0.05)
    assert flat["mean_pressure_kpa"] == pytest.approx(p / 1e3, rel=0.03)


def test_a_body_lying_on_a_bed_has_the_bed_s_peak_at_the_same_load():
    """The default body lying on its back at rest on a flat bed (the settle: six balance
    equations, friction, the whole skin): the flat seat at the bed's load over the skin the
    supports name (its back: all of it here) comes out at the bed's height and peak."""
    from solver.body.model import make_body
    from solver.scene.validate import validation_poses

    body = make_body()
    v = validation_poses()["lying"]
    v = v - [0.0, v[:, 1].min() - 0.45, 0.0]
    areas, normals = triangle_mesh(body.triangles, len(v)).measures(v)
    person = SupportedBody(v, normals, np.ones(len(v)), triangles=body.triangles, areas=areas,
                           mass_kg=body.mass_kg)
    foam = Foam(200e3)
    s = _rested(person, body.mass_kg, foam, 0.45)
    flat = flat_at_same_load(person, s, foam)
    seat = next(c for c in s.contacts if c.name == "seat")
    assert flat["height_m"] == pytest.approx(0.45, abs=1e-3)
    assert flat["peak_pressure_kpa"] == pytest.approx(
        (seat.normal_force / seat.areas).max() / 1e3, rel=0.03)


def test_the_plane_is_pressed_by_the_supported_skin_that_faces_down_only():
    """Two boxes side by side at rest as a body's supported and unsupported parts: the flat
    seat carries the whole load on the supported one alone (twice the pressure over half the
    area), and a body with no supported skin facing down, or not at rest, has no baseline."""
    left = _box((0.2, 0.2, 0.3), [-0.15, 0.1, 0])
    right = _box((0.2, 0.2, 0.3), [0.15, 0.1, 0])
    n = len(left.vertices)
    both = SupportedBody(np.concatenate([left.vertices, right.vertices]),
                         np.concatenate([left.normals, right.normals]),
                         np.ones(2 * n), triangles=np.concatenate([left.triangles,
                                                                   right.triangles + n]),
                         areas=np.concatenate([left.areas, right.areas]), mass_kg=20.0)
    foam = Foam(200e3, thickness=0.1)
    s = _rested(both, 20.0, foam)
    whole = flat_at_same_load(both, s, foam)
    right_only = flat_at_same_load(replace(both, supported=np.arange(2 * n) >= n), s, foam)
    weight = 20.0 * G
    assert whole["contact_area_m2"] == pytest.approx(0.12, rel=0.03)
    assert whole["mean_pressure_kpa"] == pytest.approx(weight / 0.12 / 1e3, rel=0.03)
    assert right_only["contact_area_m2"] == pytest.approx(0.06, rel=0.03)
    assert right_only["mean_pressure_kpa"] == pytest.approx(weight / 0.06 / 1e3, rel=0.03)
    assert right_only["height_m"] - whole["height_m"] == pytest.approx(
        weight / 0.06 / 200e3 - weight / 0.12 / 200e3, rel=0.05)  # pressed twice as deep
    facing_up = both.normals[:, 1] > 0
    assert flat_at_same_load(replace(both, supported=facing_up), s, foam) is None
    assert flat_at_same_load(both, replace(s, stable=False), foam) is None


def test_the_flat_seat_takes_the_seat_s_load_and_leaves_the_back_its_own():
    """A plank 0.8 m long resting on two pads, one the surface's seat and one its back (by
    name): by the lever rule each carries half its weight, and the flat seat, in the seat's
    place under the whole plank, carries that half, not the weight; it is compared with the
    surface's peak on the skin it presses, the back's pad's included."""
    from solver.mesh import SurfaceMesh

    plank = _box((0.8, 0.1, 0.2), [0.0, 0.05, 0.0])
    foam = Foam(200e3, thickness=0.1)

    def pad(x0: float, x1: float) -> SurfaceMesh:
        v = np.array([[x0, 0, -0.3], [x0, 0, 0.3], [x1, 0, 0.3], [x1, 0, -0.3]], float)
        return SurfaceMesh.from_quads(v, np.array([[0, 1, 2, 3]]))

    s = settle(plank.vertices, plank.normals, plank.areas, plank.triangles, 20.0,
               [Support("seat", foam, pad(0.2, 0.45)), Support("back", foam, pad(-0.45, -0.2))])
    assert s.stable, s.reason
    flat = flat_at_same_load(plank, s, foam)
    half = 20.0 * G / 2
    assert flat["load_n"] == pytest.approx(half, rel=0.02)
    assert flat["mean_pressure_kpa"] == pytest.approx(half / 0.16 / 1e3, rel=0.03)
    # compared with the surface's peak on the skin the flat seat presses (a body without
    # regions: all of it), whichever pad presses it
    peaks = {c.name: (c.normal_force / c.areas).max() / 1e3 for c in s.contacts}
    assert set(peaks) == {"seat", "back"}
    assert flat["fitted_peak_kpa"] == pytest.approx(max(peaks.values()))
    assert flat["regions"] is None


@pytest.mark.parametrize("steep, counted", [("leg rest", True), ("back", False)])
def test_the_flat_seat_takes_the_load_steeper_parts_put_on_the_regions_it_stands_in_for(
        steep, counted):
    """The same plank on a seat pad and a second pad, its skin the thighs over the seat and the
    lower back over the second, only the thighs supported: a steeper part of the surface (a
    seat's rising front or sides, `leg rest`) under the thighs gives its half of the weight to
    the flat seat too, since the peak compared counts it; a back under the lower back, which
    the flat seat does not stand in for, keeps its half."""
    from solver.body.model import BODY_REGIONS
    from solver.mesh import SurfaceMesh

    plank = _box((0.8, 0.1, 0.2), [0.0, 0.05, 0.0])
    right = plank.vertices[:, 0] > 0
    regions = np.where(right | (steep == "leg rest"), BODY_REGIONS.index("thighs"),
                       BODY_REGIONS.index("lower_back"))
    plank = replace(plank, regions=regions, supported=regions == BODY_REGIONS.index("thighs"))
    foam = Foam(200e3, thickness=0.1)

    def pad(x0: float, x1: float) -> SurfaceMesh:
        v = np.array([[x0, 0, -0.3], [x0, 0, 0.3], [x1, 0, 0.3], [x1, 0, -0.3]], float)
        return SurfaceMesh.from_quads(v, np.array([[0, 1, 2, 3]]))

    s = settle(plank.vertices, plank.normals, plank.areas, plank.triangles, 20.0,
               [Support("seat", foam, pad(0.2, 0.45)), Support(steep, foam, pad(-0.45, -0.2))])
    assert s.stable, s.reason
    flat = flat_at_same_load(plank, s, foam)
    weight = 20.0 * G
    assert flat["load_n"] == pytest.approx(weight if counted else weight / 2, rel=0.02)
    assert flat["regions"] == ["thighs"]


def test_the_skin_that_presses_is_the_skin_that_faces_down_as_the_body_rests():
    """A box turned a quarter about z by its settle (made here): the face whose normal was +x
    now faces down and alone presses the flat seat, uniformly, at the load over its area."""
    from solver.contact.mat import SupportContact
    from solver.contact.settle import Settled

    box = _box((0.2, 0.4, 0.3), [0.0, 0.0, 0.0])
    turn = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # +x -> -y
    rested = box.vertices @ turn.T + [0.0, 0.1, 0.0]
    load = 150.0
    bottom = np.flatnonzero(np.isclose(rested[:, 1], 0.0))
    contact = SupportContact("seat", bottom, np.full(len(bottom), load / len(bottom)),
                             np.zeros((len(bottom), 3)), np.tile([0.0, 1.0, 0.0],
                                                                 (len(bottom), 1)),
                             rested[bottom], np.zeros(len(bottom), dtype=int),
                             np.full(len(bottom), 0.12 / len(bottom)))
    s = Settled(True, None, rested, np.array([0.0, 0.1, 0.0]), np.array([0.0, 0.0, -np.pi / 2]),
                np.zeros(3), [contact], np.zeros(3), np.zeros(3), 200.0)
    flat = flat_at_same_load(box, s, Foam(200e3))
    assert flat["load_n"] == pytest.approx(load)
    assert flat["contact_area_m2"] == pytest.approx(0.4 * 0.3, rel=0.03)
    assert flat["mean_pressure_kpa"] == pytest.approx(load / 0.12 / 1e3, rel=0.03)
    assert flat["peak_pressure_kpa"] == pytest.approx(load / 0.12 / 1e3, rel=0.05)
