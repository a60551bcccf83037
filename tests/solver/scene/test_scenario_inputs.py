"""Scenario files as a designer writes them, mistakes and all: each mistake is a ScenarioError
that names the file, the field and what was wrong, when the file is read (before any person is
posed), and what is no mistake is read."""

from __future__ import annotations

import dataclasses

import shutil

import numpy as np
import pytest

from capture import resolve_path
from solver.scene.scenario import ScenarioError, load_scenario, parse_scenario
from solver.surface.templates import make_template

POSE = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
GRID = "grid = { size = [0.5, 0.6], resolution = [8, 6], height = 0.42 }"
# two quads side by side at seat height, facing up (towards a sitter)
SQUARES = [[-0.3, 0.4, -0.3], [0.3, 0.4, -0.3], [0.3, 0.4, 0.3], [-0.3, 0.4, 0.3],
           [0.9, 0.4, -0.3], [0.9, 0.4, 0.3]]


def _write(tmp_path, surface: str, pose: str = POSE, name: str = "s.toml"):
    path = tmp_path / name
    path.write_text(f"[surface]\n{surface}\n\n[[person]]\npose = \"{pose}\"\n")
    return path


def _obj(path, faces) -> None:
    lines = [f"v {x} {y} {z}" for x, y, z in SQUARES]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in faces]
    path.write_text("\n".join(lines) + "\n")


def test_a_scenario_that_is_a_folder_is_refused_by_name(tmp_path):
    folder = tmp_path / "chair.toml"
    folder.mkdir()
    with pytest.raises(ScenarioError, match=r"chair\.toml: expected a scenario file \(TOML\), "
                                            r"got a folder"):
        load_scenario(folder)


def test_a_control_mesh_that_is_a_folder_names_the_field(tmp_path):
    (tmp_path / "seat.obj").mkdir()
    path = _write(tmp_path, 'control_mesh = "seat.obj"')
    with pytest.raises(ScenarioError, match=r"s\.toml: surface\.control_mesh: cannot read "
                                            r".*seat\.obj"):
        load_scenario(path)


def test_a_control_mesh_with_an_edge_of_three_faces_is_refused_when_read(tmp_path):
    """(It used to be read, and refused by the fit's subdivision after the people were posed,
    with a message that named neither the file nor the field.)"""
    _obj(tmp_path / "fin.obj", [[0, 3, 2, 1], [1, 2, 5, 4], [1, 2, 5, 4]])
    path = _write(tmp_path, 'control_mesh = "fin.obj"')
    with pytest.raises(ScenarioError, match=r"s\.toml: surface\.control_mesh: fin\.obj: "
                                            r"expected a manifold surface, got an edge shared "
                                            r"by 3 faces"):
        load_scenario(path)


def test_a_control_mesh_with_a_face_turned_over_is_refused_when_read(tmp_path):
    faces = [[0, 3, 2, 1], [2, 1, 4, 5]]  # the second runs the shared edge 2 -> 1 as well
    inline = f"control_mesh = {{ vertices = {SQUARES}, faces = {faces} }}"
    with pytest.raises(ScenarioError, match=r"s\.toml: surface\.control_mesh\.faces: expected "
                                            r"consistently oriented faces"):
        load_scenario(_write(tmp_path, inline))
    _obj(tmp_path / "turned.obj", faces)
    with pytest.raises(ScenarioError, match=r"surface\.control_mesh: turned\.obj: expected "
                                            r"consistently oriented"):
        load_scenario(_write(tmp_path, 'control_mesh = "turned.obj"'))
    _obj(tmp_path / "good.obj", [[0, 3, 2, 1], [1, 2, 5, 4]])
    assert load_scenario(_write(tmp_path, 'control_mesh = "good.obj"')).surface.faces.shape \
        == (2, 4)


def test_a_bvh_path_without_the_bvh_prefix_is_relative_to_the_scenario_too(tmp_path,
                                                                             monkeypatch):
    (tmp_path / "poses").mkdir()
    shutil.copy(resolve_path("bundled:cmu_75_18_high_sit.bvh"), tmp_path / "poses" / "sit.bvh")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    for pose in ("poses/sit.bvh#frame=39", "bvh:poses/sit.bvh#frame=39"):
        person = load_scenario(_write(tmp_path, GRID, pose)).persons[0]
        assert person.pose == f"bvh:{(tmp_path / 'poses' / 'sit.bvh').resolve()}#frame=39"
    bundled = load_scenario(_write(tmp_path, GRID, POSE[4:])).persons[0]
    assert bundled.pose == POSE


@pytest.mark.parametrize("pose", ["sit.bvh#frame=-3", "bvh:sit.bvh#frame=forty",
                                  "bvh:sit.bvh", "sit.bvh", "bvh:sit.bvh#frame=2&unit="])
def test_a_pose_reference_without_a_frame_is_refused_naming_the_person(tmp_path, pose):
    with pytest.raises(ScenarioError, match=r"s\.toml: person\[0\]\.pose: expected db:NAME or "
                                            r"bvh:FILE#frame=N .*got '" + pose.replace(
                                                "[", r"\[")):
        load_scenario(_write(tmp_path, GRID, pose))


@pytest.mark.parametrize("kind, message", [
    ('"Chair"', r"got 'Chair' \(did you mean chair\?\)"),
    ('"floor cushion"', r"got 'floor cushion' \(did you mean floor_cushion\?\)"),
    ('"sofa"', r"got 'sofa'$"),
])
def test_an_unknown_template_kind_says_what_was_given_and_what_was_meant(kind, message):
    data = f"[surface]\ntemplate = {{ kind = {kind} }}\n[[person]]\npose = \"{POSE}\"\n"
    import tomllib

    with pytest.raises(ScenarioError, match=r"s\.toml: surface\.template: expected a table "
                                            r"with kind one of \[.*\], " + message):
        parse_scenario(tomllib.loads(data), "s.toml")


@pytest.mark.parametrize("template, default", [
    # the default knee_height (0.45) is not within thigh_length of this seat, but knee_height
    # is measured on the people when they are placed
    ('{ kind = "lounger", seat_height = 0.9 }', {}),
    ('{ kind = "lounger", thigh_length = 0.12, quads_across = 4 }', {"quads_across": 4}),
    # the default seat_tilt_deg (4) would put its rear at the floor; it is measured too
    ('{ kind = "chair", seat_height = 0.05, seams = true, front_drop = 0.02, '
     'seat_quads = [4, 4] }', {"seams": True, "front_drop": 0.02, "seat_quads": (4, 4)}),
])
def test_a_template_is_not_refused_for_a_default_that_will_be_measured(tmp_path, template,
                                                                       default):
    scenario = load_scenario(_write(tmp_path, f"template = {template}"))
    kind = scenario.surface.template.kind
    expected = make_template(kind, **default)  # the faces and creases do not depend on it
    np.testing.assert_array_equal(scenario.surface.faces, expected.quads)
    assert scenario.surface.params.creases == tuple(map(tuple, expected.creases.tolist()))


@pytest.mark.parametrize("template, message", [
    ('{ kind = "chair", seat_height = 100.0 }', r"seat_height: expected a number <= 1\.2, got 100"),
    ('{ kind = "lounger", seat_height = 0.3, knee_height = 0.9 }',
     r"knee_height: expected within thigh_length"),
    # corners rounded under the floor, arms folded over a short seat: the parameter named
    ('{ kind = "floor_cushion", height = 0.1, edge_drop = 0.1 }',
     r"edge_drop: expected a drop that keeps the corners above the floor, at most 0\.050 here "
     r"\(height 0\.1\), got 0\.1"),
    ('{ kind = "chair", seat_depth = 0.3, back_angle_deg = 0.0, seat_tilt_deg = 0.0, '
     'arms = true, arm_height = 0.35 }',
     r"arm_height: expected arms that the seat is long enough to carry, below 0\.300 here"),
])
def test_a_template_is_still_refused_for_values_given(tmp_path, template, message):
    with pytest.raises(ScenarioError, match=r"s\.toml: surface\.template\." + message):
        load_scenario(_write(tmp_path, f"template = {template}"))


def test_a_measured_template_value_out_of_range_says_the_scenario_did_not_set_it(tmp_path):
    """A bench for one person cut into 20 seats: each seat's width is measured on the person
    and comes out too narrow. The error names that parameter, which the scenario never wrote,
    and says where it came from (it read as if the designer had set it)."""
    from solver.scene.placement import place_scene

    path = _write(tmp_path, 'template = { kind = "bench", seats = 20 }')
    with pytest.raises(ScenarioError, match=r"surface\.template\.seat_width: .*not set in the "
                                            r"scenario: measured on the people"):
        place_scene(load_scenario(path))


def test_a_template_value_the_scenario_sets_is_blamed_on_it_alone(tmp_path):
    from solver.scene.placement import place_scene

    path = _write(tmp_path, 'template = { kind = "bench", seats = 20, seat_width = 0.03 }')
    with pytest.raises(ScenarioError, match=r"surface\.template\.seat_width") as caught:
        place_scene(load_scenario(path))
    assert "not set in the scenario" not in str(caught.value)


def test_a_low_cushions_default_edge_drop_is_as_much_as_its_corners_allow(tmp_path):
    """A cushion 5 cm high: the default edge drop (3 cm, rounded along both edges at a corner)
    would take its corners under the floor. Left unset, it is as much as they allow, not an
    error the designer did not cause; set, it is refused."""
    from solver.scene.placement import place_scene
    from solver.surface.templates import FloorCushionParams, edge_drop_limit

    scenario, _ = place_scene(load_scenario(_write(
        tmp_path, 'template = { kind = "floor_cushion", height = 0.05 }')))
    built = dataclasses.asdict(scenario.surface.template.built)
    assert built["edge_drop"] == edge_drop_limit("floor_cushion", built)
    assert 0.0 < built["edge_drop"] < FloorCushionParams.edge_drop
    assert scenario.surface.vertices[:, 1].min() >= -1e-9
    with pytest.raises(ScenarioError, match=r"surface\.template\.edge_drop: expected a drop "
                                            r"that keeps the corners above the floor"):
        place_scene(load_scenario(_write(
            tmp_path, 'template = { kind = "floor_cushion", height = 0.05, edge_drop = 0.03 }')))


def test_a_template_default_that_clashes_is_not_blamed_on_the_people():
    """A value the scenario leaves unset is named as measured on the people only when it was
    (moving them changes it); a default is named as the default."""
    from solver.scene.scenario import template_error
    from solver.surface.templates import TemplateError

    for measured, said in (({"arm_height"}, "measured on the people as placed"),
                           ({"seat_depth"}, "the template's default; set it there")):
        exc = TemplateError("chair.arm_height: expected arms the seat is long enough to carry")
        exc.measured = measured
        text = str(template_error(exc, "s.toml", {"kind": "chair"}))
        assert "surface.template.arm_height" in text and said in text, text


def test_a_stool_whose_corners_allow_no_drop_is_refused_by_name(tmp_path):
    """A stool tilted so far that its corners allow no rounding at all: the default drop is
    not clamped to nothing (an unrounded top has other faces, which read as a template built
    with other faces than the one read), but refused naming edge_drop as the default."""
    from solver.scene.placement import place_scene

    path = _write(tmp_path, 'template = { kind = "stool", seat_height = 0.2, seat_depth = 0.36, '
                            'seat_width = 0.4, seat_tilt_deg = 26.527 }')
    with pytest.raises(ScenarioError, match=r"surface\.template\.edge_drop: expected a drop that "
                                            r"keeps the corners 2 cm above the floor.*the "
                                            r"template's default"):
        place_scene(load_scenario(path))
