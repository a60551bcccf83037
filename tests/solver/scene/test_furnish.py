"""A template scenario: read with its topology, built around the placed people (dimensions
measured on them, explicit ones kept), and fitted through `sitrelax fit`'s path."""

import numpy as np
import pytest

from solver.body.model import BODY_REGIONS
from solver.scene.placement import place_scene
from solver.scene.scenario import ScenarioError, parse_scenario

SITTER = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


def _scenario(template: dict, persons=(SITTER,), **surface):
    return parse_scenario({"surface": {"template": template, **surface},
                           "person": [{"pose": p, "support": ["torso", "thighs"],
                                       "position": [0.7 * k, 0.0, 0.0]}
                                      for k, p in enumerate(persons)]}, "test.toml")


def test_a_template_is_read_with_its_faces_and_creases_but_no_vertices_yet():
    s = _scenario({"kind": "chair", "seat_height": 0.44, "seams": True}, creases=[[0, 1]])
    assert s.surface.vertices is None and s.surface.faces.shape == (8 * 11, 4)
    assert s.surface.template.kind == "chair" and s.surface.template.given == {
        "seat_height": 0.44, "seams": True}
    assert len(s.surface.params.creases) == 9  # the seat-back seam (8 edges) and the one given


@pytest.mark.parametrize("template, message", [
    ({"kind": "chair", "seat_height": 2.0}, r"test\.toml: surface\.template\.seat_height: "
                                            r"expected a number <= 1\.2, got 2"),
    ({"kind": "sofa"}, r"surface\.template: expected a table with kind one of"),
    ({"kind": "bed", "lenght": 2.0}, r"surface\.template\.lenght: unknown field \(did you "
                                     r"mean length\?"),
    ({"kind": "bench", "seat_profiles": [{"seat_heigt": 0.4}, {}]},
     r"surface\.template\.seat_profiles\[0\]\.seat_heigt: unknown field \(did you mean "
     r"seat_height\?"),
    ({"kind": "bench", "seat_profiles": [{"seat_height": 0.4}, {}]},  # (one sitter)
     r"surface\.template\.seat_profiles: expected one table per seat \(1\), got 2"),
])
def test_bad_template_parameters_name_the_field(template, message):
    with pytest.raises(ScenarioError, match=message):
        _scenario(template)


def test_fixed_indices_are_checked_against_the_template():
    with pytest.raises(ScenarioError, match=r"surface\.fixed\[0\]: expected a whole number "
                                            r"in 0\.\.107, got 500"):
        _scenario({"kind": "chair"}, fixed=[500])


def test_the_chair_is_built_under_the_sitter_and_explicit_values_win():
    measured, people = place_scene(_scenario({"kind": "chair"}))
    skin = people[0].vertices
    t = measured.surface.template.built
    v = measured.surface.vertices
    assert v.shape == (108, 3) and np.isfinite(v).all()
    # the seat starts under the buttocks (not inside them), within a few centimetres
    buttocks = skin[people[0].body.regions == BODY_REGIONS.index("pelvis")]
    assert 0.005 <= buttocks[:, 1].min() - t.seat_height <= 0.05
    assert t.seat_width > np.ptp(skin[people[0].body.regions == BODY_REGIONS.index("thighs"), 0])
    given, _ = place_scene(_scenario({"kind": "chair", "seat_height": 0.3, "arms": False}))
    assert given.surface.template.built.seat_height == 0.3
    assert given.surface.template.built.seat_depth == pytest.approx(t.seat_depth, abs=0.02)


def test_a_bench_spans_its_sitters():
    s, people = place_scene(_scenario({"kind": "bench"}, persons=(SITTER, SITTER)))
    assert s.surface.template.built.seats == 2
    xs = s.surface.vertices[:, 0]
    hips = [p.vertices[p.body.regions == BODY_REGIONS.index("thighs"), 0] for p in people]
    assert xs.min() < min(h.min() for h in hips) and xs.max() > max(h.max() for h in hips)


def test_a_bench_with_a_seat_each_measures_each_seat_as_its_sitters_chair():
    """`seat_each`: the seats side by side, each as the chair measured on its sitter alone
    (height, depth, tilt, back), from -x to +x whatever the order of the people, the seams
    halfway between neighbouring chairs' edges; a scenario given the tables keeps them."""
    medium = "bvh:bundled:cmu_75_17_medium_sit.bvh#frame=200"
    pair = parse_scenario({"surface": {"template": {"kind": "bench", "back": True,
                                                    "seat_each": True}},
                           "person": [{"pose": medium, "position": [0.35, 0.0, 0.0]},
                                      {"pose": SITTER, "position": [-0.35, 0.0, 0.0]}]},
                          "test.toml")
    s, people = place_scene(pair)
    built = s.surface.template.built
    assert built.seat_each and len(built.seat_profiles) == 2
    for k, (pose, x) in enumerate(((SITTER, -0.35), (medium, 0.35))):  # left to right
        alone = parse_scenario({"surface": {"template": {"kind": "chair", "back": True}},
                                "person": [{"pose": pose, "position": [x, 0.0, 0.0]}]},
                               "test.toml")
        chair = place_scene(alone)[0].surface.template.built
        for key in ("seat_height", "seat_depth", "seat_tilt_deg", "back_angle_deg"):
            assert built.seat_profiles[k][key] == pytest.approx(getattr(chair, key), abs=1e-9)
    assert built.seat_profiles[0]["seat_height"] > built.seat_profiles[1]["seat_height"] + 0.05
    assert min(p["rear"] for p in built.seat_profiles) == 0.0
    # the seats span the people's thighs, and the seam lies between them
    xs = s.surface.vertices[:, 0]
    thighs = [p.vertices[p.body.regions == BODY_REGIONS.index("thighs"), 0] for p in people]
    assert xs.min() < min(t.min() for t in thighs) and xs.max() > max(t.max() for t in thighs)
    width = built.seat_profiles[0]["seat_width"]
    seam = xs.min() + width
    assert thighs[1].max() < seam < thighs[0].min()  # (people[0] is the one on the right)
    # given the tables, a scenario keeps them as they are
    given = {"kind": "bench", "back": True, "seat_each": True,
             "seat_profiles": [dict(p) for p in built.seat_profiles]}
    again, _ = place_scene(parse_scenario({**_pair_data(pair), "surface": {"template": given}},
                                          "test.toml"))
    assert again.surface.vertices == pytest.approx(s.surface.vertices, abs=1e-9)


def test_a_backless_bench_with_a_seat_each_has_backless_seats():
    """Each seat is measured as a backless chair then: its rear line where the buttocks end,
    not moved for a back (and the mesh has no back rows)."""
    s, _ = place_scene(_scenario({"kind": "bench", "seat_each": True}, persons=(SITTER, SITTER)))
    built = s.surface.template.built
    assert not built.back and len(built.seat_profiles) == 2
    alone, _ = place_scene(_scenario({"kind": "chair", "back": False}))
    chair = alone.surface.template.built
    for seat in built.seat_profiles:
        assert seat["seat_depth"] == pytest.approx(chair.seat_depth, abs=1e-9)
    assert s.surface.vertices[:, 1].max() < 0.6  # a seat, no back


def test_a_seat_each_needs_a_seat_per_sitter():
    with pytest.raises(ScenarioError, match=r"surface\.template\.seat_each: a seat each needs "
                                            r"a seat per sitter, got seats = 3 for 2 people"):
        place_scene(_scenario({"kind": "bench", "seat_each": True, "seats": 3},
                              persons=(SITTER, SITTER)))


def _pair_data(scenario) -> dict:
    return {"person": [{"pose": p.pose, "position": list(p.position)}
                       for p in scenario.persons]}


def test_a_bed_needs_lifted_sleepers():
    with pytest.raises(ScenarioError, match=r"surface\.template: The people's lowest point is "
                                            r"0\.000 m above the floor"):
        place_scene(_scenario({"kind": "bed"}))


@pytest.mark.slow
def test_a_chair_scenario_fits_through_run_fit(tmp_path):
    from solver.scene.run import run_fit

    path = tmp_path / "chair.toml"
    path.write_text(f'[surface]\ntemplate = {{ kind = "chair", seat_quads = [6, 4], '
                    f'back_quads = 3 }}\nlevel = 2\nmax_iterations = 12\n\n[[person]]\n'
                    f'pose = "{SITTER}"\nsupport = ["torso", "thighs"]\n')
    report = run_fit(path, tmp_path / "out", pictures=False, formats=("obj",))
    assert report["parameters"]["template"]["kind"] == "chair"
    assert report["parameters"]["control_mesh"] == "chair template, 6 x 7 quads"
    assert report["persons"][0]["coverage"] > 0.5
    assert report["guarantees"]["self_intersections"] == 0


def test_a_waterfall_front_is_measured_only_when_asked_and_only_over_tucked_calves():
    """`furnish`'s waterfall: the medium-sit sitter's calves tuck under the seat's measured
    front edge, so it drops by WATERFALL (at most a quarter of the depth); a seat 25 cm deep
    ends well short of them and gets none; a given drop is kept; without the flag nothing
    is measured (a scenario's template keeps the topology it was read with)."""
    from solver.scene.furnish import WATERFALL, furnish

    medium = "bvh:bundled:cmu_75_17_medium_sit.bvh#frame=200"

    def built(given, waterfall=True):
        _, people = place_scene(_scenario({"kind": "chair", **given}, persons=(medium,)))
        return furnish("chair", given, people, waterfall=waterfall)

    deep = built({})
    assert deep.params.front_drop == pytest.approx(min(WATERFALL, deep.params.seat_depth / 4))
    assert built({}, waterfall=False).params.front_drop == 0.0
    assert built({"seat_depth": 0.3}).params.front_drop == pytest.approx(0.075)
    short = built({"seat_depth": 0.25})
    assert short.params.front_drop == 0.0
    assert built({"front_drop": 0.02}).params.front_drop == 0.02
    # the drop adds a row of quads along the front (the topology a scenario must say)
    assert len(deep.quads) == len(short.quads) + 8
