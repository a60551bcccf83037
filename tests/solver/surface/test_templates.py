"""Furniture templates: consistent manifold quad grids facing the bodies, creases on mesh edges,
smooth at level 3 but for the creases, dimensions as their parameters say (checked with trimesh),
clear errors for bad parameters."""

import math

import numpy as np
import pytest
import trimesh

from solver.mesh import quad_triangles
from solver.surface.nurbs import grid_patches
from solver.surface.subdivision import subdivision
from solver.surface.templates import (KINDS, TEMPLATE_PARAMS, TemplateError, make_template,
                                      template_params)

VARIANTS = [("chair", {}), ("chair", {"arms": True}), ("chair", {"back": False}),
            ("bench", {}), ("bench", {"seats": 3, "back": True, "arms": True}),
            ("bench", {"back": True, "arms": True, "seat_profiles": (
                {"seat_height": 0.40, "seat_width": 0.5},
                {"seat_height": 0.34, "rear": 0.03, "back_angle_deg": 8.0})}),
            ("stool", {}), ("stool", {"seat_tilt_deg": -10.0}),
            ("floor_cushion", {}), ("floor_cushion", {"back": True}),
            ("lounger", {}), ("bed", {}), ("bed", {"edge_drop": 0.0})]
IDS = [f"{k}-{'-'.join(f'{a}={b}' for a, b in v.items() if a != 'seat_profiles') or 'defaults'}"
       f"{'-seat_profiles' if 'seat_profiles' in v else ''}" for k, v in VARIANTS]


def _trimesh(vertices, quads) -> trimesh.Trimesh:
    return trimesh.Trimesh(vertices, quad_triangles(quads), process=False)


def _quad_edges(quads) -> set[tuple[int, int]]:
    q = np.asarray(quads)
    pairs = np.sort(np.stack([q, np.roll(q, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    return set(map(tuple, pairs.tolist()))


def test_every_kind_is_covered():
    assert {k for k, _ in VARIANTS} == set(KINDS) == set(TEMPLATE_PARAMS)


@pytest.mark.parametrize("kind, values", VARIANTS, ids=IDS)
def test_template_is_a_manifold_consistently_wound_quad_grid(kind, values):
    t = make_template(kind, **values)
    assert t.vertices.shape[1] == 3 and t.quads.shape[1] == 4
    assert np.isfinite(t.vertices).all()
    mesh = _trimesh(t.vertices, t.quads)
    assert mesh.is_winding_consistent
    # edge manifold: no edge of more than two faces, and every vertex used
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    assert counts.max() <= 2
    assert np.array_equal(np.unique(t.quads), np.arange(len(t.vertices)))
    # no degenerate quad: every one has area
    assert (mesh.area_faces > 1e-6).all()
    # the grid exports as NURBS patches (a regular grid, creases along whole lines)
    patches = grid_patches(len(t.vertices), t.quads, t.creases.tolist() or None)
    assert patches is not None
    assert sum(patch.size for patch in patches) >= len(t.vertices)


@pytest.mark.parametrize("kind, values", VARIANTS, ids=IDS)
def test_creases_are_mesh_edges_and_the_level_3_surface_folds_only_there(kind, values):
    t = make_template(kind, **values)
    edges = _quad_edges(t.quads)
    assert all(tuple(sorted(c)) in edges for c in t.creases.tolist())
    sub = subdivision(len(t.vertices), t.quads, 3, t.creases.tolist() or None)
    fine = _trimesh(sub.apply(t.vertices), sub.faces)
    sharp = {tuple(sorted(e)) for e in sub.steps[-1].creases.tolist()}
    angles = np.degrees(fine.face_adjacency_angles)
    off = np.array([tuple(e) not in sharp for e in np.sort(fine.face_adjacency_edges, axis=1)
                    .tolist()])
    assert angles[off].max() < 60.0


def _normals_and_centres(t):
    mesh = _trimesh(t.vertices, t.quads)
    return mesh.face_normals, mesh.triangles_center


@pytest.mark.parametrize("kind, values", VARIANTS, ids=IDS)
def test_faces_point_towards_the_bodies(kind, values):
    """Seats and tops face up, backs forward (+z), arm walls inwards: the body side."""
    t = make_template(kind, **values)
    normals, centres = _normals_and_centres(t)
    area = _trimesh(t.vertices, t.quads).area_faces
    # most of the area faces up or forward, none of it down and back at once
    towards = normals[:, 1] + np.clip(normals[:, 2], 0, None)
    assert area[towards > 0.5].sum() > 0.6 * area.sum()
    walls = np.abs(normals[:, 0]) > 0.9  # arm walls: their normal points to the middle
    assert (np.sign(normals[walls, 0]) == -np.sign(centres[walls, 0])).all()
    if values.get("back", kind == "chair") and kind in ("chair", "bench", "floor_cushion"):
        high = centres[:, 1] > centres[:, 1].max() - 0.1  # the top of the back
        assert (normals[high & ~walls, 2] > 0.5).all()


def _seat_height(t) -> float:
    """The highest point of the up-facing seat (arms left out), measured on the mesh."""
    normals, centres = _normals_and_centres(t)
    half = t.params.seat_width * getattr(t.params, "seats", 1) / 2
    seat = (normals[:, 1] > 0.95) & (np.abs(centres[:, 0]) < half - 0.01)
    mesh = _trimesh(t.vertices, t.quads)
    return float(mesh.vertices[mesh.faces[seat]][..., 1].max())


@pytest.mark.parametrize("kind", ["chair", "bench", "stool"])
def test_seat_height_depth_and_width_are_what_they_say(kind):
    low, high = make_template(kind, seat_height=0.40), make_template(kind, seat_height=0.52)
    assert _seat_height(low) == pytest.approx(0.40, abs=1e-9)
    assert _seat_height(high) == pytest.approx(0.52, abs=1e-9)
    wide = make_template(kind, seat_width=0.61)
    span = np.ptp(wide.vertices[:, 0]) / getattr(wide.params, "seats", 1)
    assert span == pytest.approx(0.61)
    deep = make_template(kind, seat_depth=0.5, **({"back": False} if kind == "chair" else {}))
    assert np.ptp(deep.vertices[:, 2]) == pytest.approx(0.5)


def test_bench_spans_its_seats():
    two, five = make_template("bench", seats=2), make_template("bench", seats=5)
    assert np.ptp(five.vertices[:, 0]) == pytest.approx(2.5 * np.ptp(two.vertices[:, 0]))
    assert len(five.quads) == pytest.approx(2.5 * len(two.quads))


def test_a_bench_with_a_seat_each_is_its_seats_chairs_side_by_side():
    """`seat_profiles`: each seat's columns are the profile of a chair of that seat's own
    parameters (moved to its place), the seam column between two seats the mean of both;
    empty tables give the bench of the common values, the same mesh."""
    common = make_template("bench", back=True, seat_height=0.42)
    same = make_template("bench", back=True, seat_height=0.42, seat_profiles=({}, {}))
    assert same.vertices == pytest.approx(common.vertices, abs=1e-12)
    assert np.array_equal(same.quads, common.quads)
    assert np.array_equal(same.creases, common.creases)
    own = ({"seat_height": 0.44, "seat_depth": 0.42, "seat_width": 0.5, "back_angle_deg": 10.0},
           {"seat_height": 0.36, "seat_width": 0.62, "rear": 0.05})
    bench = make_template("bench", back=True, seat_profiles=own)
    assert np.array_equal(bench.quads, common.quads)  # the same topology as without
    assert np.ptp(bench.vertices[:, 0]) == pytest.approx(0.5 + 0.62)
    columns = bench.vertices[bench.grid]  # (columns across, rows along the profile, 3)
    for k, (x0, entry) in enumerate(zip((-0.56, 0.0), own)):  # each seat's first columns
        chair = make_template("chair", **{**{key: getattr(bench.params, key) for key in (
            "seat_tilt_deg", "front_drop", "back_height", "back_angle_deg", "seat_quads",
            "back_quads")}, **{key: v for key, v in entry.items() if key != "rear"}})
        profile = chair.vertices[chair.grid[0]][:, 1:]  # its (y, z) profile
        column = columns[1 if k == 0 else 9][:, 1:]  # a column inside seat k
        assert column == pytest.approx(profile + [0.0, entry.get("rear", 0.0)], abs=1e-9)
    seam = columns[8][:, 1:]
    assert seam == pytest.approx((columns[7][:, 1:] + columns[9][:, 1:]) / 2, abs=1e-9)


def test_back_angle_and_height_of_a_chair():
    for angle in (0.0, 20.0):
        t = make_template("chair", back_angle_deg=angle, back_height=0.6, seat_tilt_deg=0.0)
        normals, centres = _normals_and_centres(t)
        back = centres[:, 1] > 0.45 + 0.1
        tilt = np.degrees(np.arctan2(normals[back, 1], normals[back, 2]))
        assert tilt == pytest.approx(np.full(back.sum(), angle), abs=1e-6)
        top = t.vertices[:, 1].max() - 0.45
        assert top == pytest.approx(0.6 * math.cos(math.radians(angle)))


def test_arms_stand_their_height_above_the_seat():
    t = make_template("chair", arms=True, arm_height=0.25, seat_tilt_deg=0.0, front_drop=0.0,
                      seams=True)
    normals, centres = _normals_and_centres(t)
    arm_tops = (normals[:, 1] > 0.99) & (np.abs(centres[:, 0]) > t.params.seat_width / 2)
    assert centres[arm_tops, 1] == pytest.approx(np.full(arm_tops.sum(), 0.45 + 0.25))
    assert np.ptp(t.vertices[:, 0]) == pytest.approx(0.5 + 2 * t.params.arm_width)
    assert len(t.creases) > 0


def test_seats_have_no_seams_unless_asked():
    """A sharp seat-back seam lets the fit fold the surface back across it into a slit: the
    chair and the bench are seamless by default, and keep their creases when asked."""
    for kind, extra in (("chair", {"arms": True}), ("bench", {"back": True, "arms": True})):
        assert len(make_template(kind, **extra).creases) == 0
        assert len(make_template(kind, seams=True, **extra).creases) > 0


def test_bed_lounger_and_cushion_dimensions():
    bed = make_template("bed", height=0.5, width=1.4, length=2.1)
    assert bed.vertices[:, 1].max() == pytest.approx(0.5)
    assert np.ptp(bed.vertices[:, [0, 2]], axis=0) == pytest.approx([1.4, 2.1])
    cushion = make_template("floor_cushion", height=0.15, width=0.7)
    assert cushion.vertices[:, 1].max() == pytest.approx(0.15)
    assert np.ptp(cushion.vertices[:, 0]) == pytest.approx(0.7)
    lounger = make_template("lounger", seat_height=0.3, back_angle_deg=60.0, back_length=0.9)
    normals, centres = _normals_and_centres(lounger)
    back = centres[:, 2] < -0.1
    assert np.degrees(np.arctan2(normals[back, 1], normals[back, 2])) == \
        pytest.approx(np.full(back.sum(), 60.0))
    assert lounger.vertices[:, 1].min() == pytest.approx(0.3)


def test_position_and_heading_move_and_turn_the_template():
    base = make_template("chair")
    moved = make_template("chair", position=(1.0, -2.0), heading_deg=90.0)
    # turned a quarter about +y: the front (+z) now faces +x, then moved on the floor
    expected = np.stack([base.vertices[:, 2] + 1.0, base.vertices[:, 1],
                         -base.vertices[:, 0] - 2.0], axis=1)
    assert moved.vertices == pytest.approx(expected)
    assert np.array_equal(moved.quads, base.quads)


@pytest.mark.parametrize("kind, values, message", [
    ("chair", {"seat_height": -0.1}, r"chair\.seat_height: expected a number >= 0\.05, got -0\.1"),
    ("chair", {"arms": "yes"}, r"chair\.arms: expected true or false, got 'yes'"),
    ("chair", {"seat_quads": (8,)}, r"chair\.seat_quads: expected \[across, along\]"),
    ("chair", {"seat_quads": (8, 1)}, r"chair\.seat_quads\[1\]: expected a whole number >= 2"),
    ("chair", {"seat_tilt_deg": 29.0, "seat_depth": 1.4},
     r"chair\.seat_tilt_deg: expected a tilt that keeps the seat above the floor"),
    # a low seat whose front edge drops to the floor: the drop is named, not the tilt
    ("chair", {"seat_height": 0.1, "seat_depth": 0.4, "seat_tilt_deg": 0.0,
               "front_drop": 0.09},
     r"chair\.front_drop: expected a drop that keeps the seat's edge above the floor, at most "
     r"0\.080 here, got 0\.09"),
    ("bench", {"seats": 0}, r"bench\.seats: expected a whole number >= 1, got 0"),
    ("bench", {"seats": 2.5}, r"bench\.seats: expected a whole number, got 2\.5"),
    ("bench", {"seat_profiles": ({},)},
     r"bench\.seat_profiles: expected one table per seat \(2\), got 1"),
    ("bench", {"seat_profiles": ({"seat_heigt": 0.4}, {})},
     r"bench\.seat_profiles\[0\]: unknown parameter 'seat_heigt'"),
    ("bench", {"seat_profiles": ({}, {"seat_height": 0.01})},
     r"bench\.seat_profiles\[1\]\.seat_height: expected a number >= 0\.05, got 0\.01"),
    ("bench", {"seat_profiles": ({}, {"rear": 2.0})},
     r"bench\.seat_profiles\[1\]\.rear: expected a number <= 1, got 2"),
    ("bench", {"seat_each": "yes"}, r"bench\.seat_each: expected true or false, got 'yes'"),
    ("bed", {"width": float("nan")}, r"bed\.width: expected a number, got nan"),
    ("lounger", {"knee_height": 1.0}, r"lounger\.knee_height: expected within thigh_length"),
    ("stool", {"position": (0.0,)}, r"stool\.position: expected \[x, z\]"),
    ("floor_cushion", {"height": 0.7}, r"floor_cushion\.height: expected a number <= 0\.6"),
    ("sofa", {}, r"Expected a template kind of \['chair', .*\], got 'sofa'"),
    ("chair", {"colour": "red"}, r"chair: unknown parameter 'colour'"),
])
def test_bad_parameters_raise_with_a_message(kind, values, message):
    with pytest.raises(TemplateError, match=message):
        make_template(kind, **values)


def test_parameters_are_frozen_and_lists_become_tuples():
    p = template_params("chair", seat_quads=[6, 5], position=[0.2, 0.1])
    assert p.seat_quads == (6, 5) and p.position == (0.2, 0.1)
    with pytest.raises(AttributeError):
        p.seat_height = 0.3
    t = make_template("chair", p)
    assert len(t.quads) == 6 * (5 + p.back_quads)


# above the floor and not folded, at every allowed value ---------------------------------------

@pytest.mark.parametrize("kind, values, message", [
    # rounded along both edges, a corner drops twice: the edge stays up, the corner goes under
    ("bed", {"height": 0.16, "edge_drop": 0.15},
     r"bed\.edge_drop: expected a drop that keeps the corners above the floor, at most 0\.080 "
     r"here \(height 0\.16\), got 0\.15 \(a corner would be at -0\.140 m\)"),
    ("floor_cushion", {"height": 0.1, "edge_drop": 0.1},
     r"floor_cushion\.edge_drop: expected a drop that keeps the corners above the floor, at "
     r"most 0\.050 here \(height 0\.1\), got 0\.1 \(a corner would be at -0\.100 m\)"),
    ("floor_cushion", {"height": 0.1, "edge_drop": 0.1, "back": True},
     r"floor_cushion\.edge_drop: .* at most 0\.050 here"),
    ("stool", {"seat_height": 0.49, "seat_depth": 1.5, "seat_tilt_deg": 15.0, "edge_drop": 0.06},
     r"stool\.edge_drop: expected a drop that keeps the corners 2 cm above the floor, at most "
     r"0\.037 here \(seat_height 0\.49, seat_depth 1\.5, seat_tilt_deg 15\), got 0\.06 "
     r"\(a corner would be at -0\.020 m\)"),
    ("stool", {"seat_height": 0.12, "seat_depth": 0.4, "seat_tilt_deg": -10.0, "edge_drop": 0.08},
     r"stool\.edge_drop: .* at most 0\.050 here"),
    # one limit for a stool whose edge and corners both reach down: the corners' (the edge's
    # own, 0.037 here, would be refused again)
    ("stool", {"seat_height": 0.12, "seat_tilt_deg": 10.0, "edge_drop": 0.036},
     r"stool\.edge_drop: expected a drop that keeps the corners 2 cm above the floor, at most "
     r"0\.020 here"),
    # rounded edges of opposite sides meeting (zero-area quads) or crossing (flipped ones)
    ("bed", {"width": 0.3, "edge_drop": 0.15},
     r"bed\.edge_drop: expected a drop that leaves 2 cm of flat top between the rounded edges "
     r"of width and length, at most 0\.140 here \(width 0\.3 m, length 2 m\), got 0\.15"),
    ("floor_cushion", {"depth": 0.19, "edge_drop": 0.09, "height": 0.6},
     r"floor_cushion\.edge_drop: expected a drop that leaves 2 cm .* at most 0\.085 here"),
    ("stool", {"seat_width": 0.1, "seat_depth": 0.4, "edge_drop": 0.1},
     r"stool\.edge_drop: expected a drop that leaves 2 cm of flat top between the rounded "
     r"edges of seat_width and seat_depth, at most 0\.040 here"),
    # arm bands offset into the seat-back corner: higher than the seat (or back) is long, their
    # tops fold over themselves
    ("chair", {"arms": True, "seat_depth": 0.3, "back_angle_deg": 0.0, "seat_tilt_deg": 0.0,
               "arm_height": 0.35},
     r"chair\.arm_height: expected arms that the seat is long enough to carry, below 0\.300 "
     r"here \(seat_depth 0\.3, seat_tilt_deg 0, back_angle_deg 0, back_height 0\.5\), got 0\.35"),
    ("chair", {"arms": True, "back_height": 0.1, "back_angle_deg": 0.0, "seat_tilt_deg": 0.0,
               "arm_height": 0.3},
     r"chair\.arm_height: expected arms that the back is long enough to carry, below 0\.100"),
    ("bench", {"arms": True, "back": True, "arm_height": 0.4, "seat_profiles": (
        {}, {"seat_depth": 0.3, "seat_tilt_deg": 0.0, "back_angle_deg": 0.0})},
     r"bench\.arm_height: expected arms that the seat \(seat_profiles\[1\]\) is long enough"),
])
def test_parameters_that_put_the_mesh_under_the_floor_or_fold_it_are_refused(kind, values,
                                                                             message):
    with pytest.raises(TemplateError, match=message):
        make_template(kind, **values)


@pytest.mark.parametrize("kind, values, name", [
    ("bed", {"height": 0.16, "edge_drop": 0.08}, "edge_drop"),
    ("floor_cushion", {"height": 0.1, "edge_drop": 0.05}, "edge_drop"),
    ("stool", {"seat_height": 0.49, "seat_depth": 1.5, "seat_tilt_deg": 15.0, "edge_drop": 0.037},
     "edge_drop"),
    # rounded edges up to nearly half a side: 2 cm of flat top left, nothing folds (a stool's
    # too: its drop is no longer held to a quarter of its depth, as a chair's front drop is)
    ("stool", {"seat_depth": 0.12, "seat_width": 0.4, "edge_drop": 0.05}, "edge_drop"),
    ("bed", {"width": 0.3, "edge_drop": 0.14}, "edge_drop"),
    ("floor_cushion", {"width": 0.2, "depth": 0.2, "height": 0.3, "edge_drop": 0.06},
     "edge_drop"),
    ("chair", {"arms": True, "seat_depth": 0.3, "back_angle_deg": 0.0, "seat_tilt_deg": 0.0,
               "arm_height": 0.29}, "arm_height"),
])
def test_up_to_the_limits_the_mesh_stays_above_the_floor_unfolded(kind, values, name):
    t = make_template(kind, **values)
    assert t.vertices[:, 1].min() >= 0.0
    mesh = _trimesh(t.vertices, t.quads)
    assert (mesh.area_faces > 1e-9).all()
    # the middle of the allowed drop or height keeps both splits of every quad facing one way
    half = make_template(kind, **{**values, name: values[name] / 2})
    assert _quad_twist(half).min() > 0.0


def _quad_twist(t) -> np.ndarray:
    """(F,) cosine between the normals of a quad's two triangles, both ways of splitting it:
    -1 for a quad folded flat onto itself."""
    v = t.vertices[t.quads]
    a, b, c, d = v[:, 0], v[:, 1], v[:, 2], v[:, 3]

    def cos(x, y):
        return np.einsum("ij,ij->i", x, y) / np.maximum(
            np.linalg.norm(x, axis=1) * np.linalg.norm(y, axis=1), 1e-300)

    return np.minimum(cos(np.cross(b - a, c - a), np.cross(c - a, d - a)),
                      cos(np.cross(b - a, d - a), np.cross(c - b, d - b)))


_SWEEP = {  # each kind's numeric parameters and their bounds (the templates' own checks)
    "chair": {"seat_height": (0.05, 1.2), "seat_depth": (0.1, 1.5), "seat_width": (0.1, 3.0),
              "seat_tilt_deg": (-30.0, 30.0), "front_drop": (0.0, 0.1),
              "back_angle_deg": (-10.0, 60.0), "back_height": (0.05, 1.5),
              "arm_height": (0.03, 0.6), "arm_width": (0.02, 0.4)},
    "stool": {"seat_height": (0.05, 1.2), "seat_depth": (0.1, 1.5), "seat_width": (0.1, 3.0),
              "seat_tilt_deg": (-30.0, 30.0), "edge_drop": (0.0, 0.1)},
    "floor_cushion": {"height": (0.02, 0.6), "depth": (0.1, 2.0), "width": (0.1, 6.0),
                      "edge_drop": (0.0, 0.1), "back_angle_deg": (-10.0, 80.0),
                      "back_height": (0.05, 1.5)},
    "lounger": {"seat_height": (0.05, 1.2), "width": (0.2, 6.0), "back_angle_deg": (10.0, 85.0),
                "back_length": (0.2, 2.0), "thigh_length": (0.1, 1.0),
                "knee_height": (0.05, 1.5), "leg_length": (0.1, 1.2),
                "foot_height": (0.02, 1.5)},
    "bed": {"height": (0.05, 1.2), "width": (0.3, 6.0), "length": (0.5, 3.5),
            "edge_drop": (0.0, 0.15)},
}
_SWEEP["bench"] = _SWEEP["chair"]
_FLAGS = {"chair": ("back", "arms"), "bench": ("back", "arms"), "floor_cushion": ("back",)}
_COARSE = {"chair": {"seat_quads": (2, 2), "back_quads": 1},
           "bench": {"seat_quads": (2, 2), "back_quads": 1, "seats": 2},
           "stool": {"seat_quads": (2, 2)}, "floor_cushion": {"quads": (2, 2), "back_quads": 1},
           "lounger": {"quads_across": 1, "back_quads": 1, "thigh_quads": 1, "leg_quads": 1},
           "bed": {"quads": (2, 2)}}


@pytest.mark.parametrize("kind", sorted(_SWEEP))
def test_every_allowed_template_stays_above_the_floor_and_unfolded(kind):
    """A seeded sweep of each kind's parameter box, its corners half the time: every template
    the checks let through has its control mesh, so its limit surface (each level a convex
    combination of it), on or above the floor, no quad without area, none folded onto itself."""
    rng = np.random.default_rng(7)
    built = 0
    for k in range(200):
        values = {name: float(rng.choice([lo, hi]) if k % 2 or rng.random() < 0.3
                              else rng.uniform(lo, hi))
                  for name, (lo, hi) in _SWEEP[kind].items()}
        values.update({flag: bool(rng.random() < 0.6) for flag in _FLAGS.get(kind, ())})
        values.update(_COARSE[kind], position=(float(rng.uniform(-2, 2)), 0.5),
                      heading_deg=float(rng.uniform(-360, 360)))
        try:
            t = make_template(kind, **values)
        except TemplateError:
            continue
        built += 1
        assert t.vertices[:, 1].min() >= 0.0, values
        assert (_trimesh(t.vertices, t.quads).area_faces > 1e-12).all(), values
        assert _quad_twist(t).min() > -0.5, values
    assert built > 25
