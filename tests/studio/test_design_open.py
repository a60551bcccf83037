"""Opening a scenario file in the Design view (`Design.open_scenario`, the "Open scenario
(TOML)" upload): the session becomes the scenario, keeps every field it does not edit (so
that Save TOML at once writes a scenario parsing to the one opened), holds a template as the
template, refuses bad files with one line naming the problem, and is one step of the history."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from solver.scene.scenario import Scenario, load_scenario, parse_scenario, scenario_toml
from studio.design import Design, DesignError

SCENARIOS = Path(__file__).resolve().parents[2] / "fixtures" / "scenarios"
POSE = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


def _alone(path: Path) -> bool:
    """Whether a scenario file needs no file beside it (an upload of it alone can open)."""
    data = tomllib.loads(path.read_text())
    return not isinstance(data["surface"].get("control_mesh"), str) and all(
        p["pose"].startswith(("db:", "bvh:bundled:")) and not isinstance(p.get("joint_map"), str)
        for p in data["person"])


ALONE = [pytest.param(p, id=p.stem, marks=[pytest.mark.slow] if p.stem == "six_overlapping"
                      else [])  # (six people posed: over the default run's budget)
         for p in sorted(SCENARIOS.glob("*.toml")) if _alone(p)]


def differences(a: Scenario, b: Scenario) -> list[str]:
    """What differs between two parsed scenarios: the surface (its control mesh, or None for
    a template not yet built; its parameters, source and template request), the people, the
    evaluation and the relief."""
    sa, sb = a.surface, b.surface
    found = []
    for name in ("vertices", "faces"):
        x, y = getattr(sa, name), getattr(sb, name)
        if (x is None) != (y is None) or (x is not None and not np.array_equal(x, y)):
            found.append(f"surface.{name}")
    if sa.params != sb.params:
        found.append("surface parameters")
    if sa.source != sb.source:
        found.append(f"surface source {sa.source!r} != {sb.source!r}")
    ta, tb = sa.template, sb.template
    if (ta is None) != (tb is None) or (ta is not None and (ta.kind, ta.given) !=
                                        (tb.kind, tb.given)):
        found.append("template")
    found += [name for name in ("persons", "evaluation", "relief")
              if getattr(a, name) != getattr(b, name)]
    return found


def saved(design: Design, tmp_path: Path, base: Path | None = None) -> Scenario:
    """What Save TOML writes now, parsed (relative paths relative to `base`)."""
    path = design.save_toml(tmp_path / "saved.toml")
    return parse_scenario(tomllib.loads(path.read_text()), str(path), base)


def state(design: Design) -> tuple:
    return (scenario_toml(design._data()), design.can_undo, design.can_redo)


def test_a_two_person_grid_scenario_opens_and_undoes_as_one_step(tmp_path):
    design = Design()
    design.add_person(POSE)
    before = state(design)
    opened = design.open_scenario((SCENARIOS / "facing_pair.toml").read_bytes(),
                                  "facing_pair.toml")
    assert [p["name"] for p in design.people] == [p.name for p in opened.persons]
    assert np.array_equal(design.vertices, opened.surface.vertices)
    assert differences(load_scenario(SCENARIOS / "facing_pair.toml"), saved(design, tmp_path)) \
        == []
    design.undo()
    assert state(design)[0] == before[0] and len(design.people) == 1
    design.redo()
    assert len(design.people) == 2


@pytest.mark.parametrize("path", ALONE)
def test_save_toml_right_after_opening_writes_the_scenario_opened(path, tmp_path):
    design = Design()
    design.open_scenario(path.read_bytes(), path.name)
    assert differences(load_scenario(path), saved(design, tmp_path, path.parent)) == []


def test_every_fixture_that_needs_no_file_beside_it_is_round_tripped():
    assert len(ALONE) >= 15  # (all but fig1_multipurpose, whose OBJ lies beside it)


def test_a_sitrelax_design_output_opens_as_its_template(tmp_path):
    from solver.scene.design import design_scenario

    data, _ = design_scenario([POSE])
    # as `sitrelax design` writes it (a comment header, then the scenario)
    path = tmp_path / "scenario.toml"
    path.write_text(f"# sitrelax design {POSE}\n" + scenario_toml(data))
    design = Design()
    design.open_scenario(path.read_bytes(), path.name)
    assert design.start["key"] == "template" and design.start["table"] == \
        data["surface"]["template"]
    written = saved(design, tmp_path)
    assert differences(load_scenario(path), written) == []
    assert written.raw["surface"]["template"] == data["surface"]["template"]
    assert written.relief.rounds == data["relief"]["rounds"]


def test_a_template_is_held_until_its_mesh_or_its_people_change(tmp_path):
    path = SCENARIOS / "template_chair.toml"
    design = Design()
    opened = design.open_scenario(path.read_bytes(), path.name)
    # built around the people as `sitrelax fit` builds it: its creases kept sharp
    assert opened.surface.template.kind == "chair" and opened.surface.vertices is None
    assert len(design.vertices) == int(opened.surface.faces.max()) + 1
    assert {tuple(c) for c in opened.surface.params.creases} <= design.creases
    assert saved(design, tmp_path).raw["surface"]["template"] == \
        {"kind": "chair", "seat_depth": 0.42, "seams": False}
    design.set_parameter("sigma", 0.01)  # a parameter: still the template
    assert saved(design, tmp_path).raw["surface"]["template"]["kind"] == "chair"
    design.update_person(0, position=[0.0, 0.05, 0.0])  # the chair stays where it was built
    kept = saved(design, tmp_path)
    assert "template" not in kept.raw["surface"] and np.array_equal(kept.surface.vertices,
                                                                    design.vertices)
    design.undo()
    design.move_vertex(0, design.vertices[0] + 0.01)
    assert "control_mesh" in saved(design, tmp_path).raw["surface"]


def test_what_the_panel_does_not_edit_is_kept_through_edits(tmp_path):
    text = f"""
[surface]
grid = {{ size = [1.0, 0.6], resolution = [4, 3], height = 0.4 }}
level = 2
sigma = 0.01
fixed = [0, 3]
creases = [[0, 1]]
gamma = 50.0
pull_range = 0.3
floor = 0.05
min_ridge_radius = 0.02
anchor = 0.002
sink = 0.01

[evaluation]
foam_stiffness = 150.0
friction = 0.3

[relief]
rounds = 2
target = 0.6

[[person]]
pose = "{POSE}"
body = {{ weight = 0.8 }}
facing = "capture"
placement = "standard"
joint_map = {{ hips = "Hips" }}
support = ["pelvis", "thighs", "lower_back"]
"""
    design = Design()
    opened = design.open_scenario(text, "kept.toml")
    assert design.params == {"level": 2, "sigma": 0.01, "tau_max": 0.5, "margin": 0.03}
    assert design.fixed == {0, 3} and design.creases == {(0, 1)}
    assert differences(opened, saved(design, tmp_path)) == []
    # edits of the panel and the mesh keep the rest (and the fit uses it)
    design.set_parameter("margin", 0.02)
    design.move_vertex(5, design.vertices[5] + [0.0, 0.01, 0.0])
    design.update_person(0, position=[0.0, 0.01, 0.0])
    now = design.scenario()
    p, q = now.surface.params, opened.surface.params
    assert (p.gamma, p.pull_range, p.floor, p.min_ridge_radius, p.anchor, p.sink) == \
        (q.gamma, q.pull_range, q.floor, q.min_ridge_radius, q.anchor, q.sink)
    assert p.fixed == q.fixed and p.creases == q.creases and p.margin == 0.02
    assert now.evaluation == opened.evaluation and now.relief == opened.relief
    person = now.persons[0]
    assert (person.body, person.facing, person.placement, person.joint_map,
            person.support) == (opened.persons[0].body, "capture", "standard",
                                (("hips", "Hips"),), opened.persons[0].support)
    written = saved(design, tmp_path)
    assert written.evaluation == opened.evaluation and written.relief == opened.relief
    assert written.persons[0].joint_map == (("hips", "Hips"),)


def test_an_obj_beside_it_is_named_when_uploaded_alone_and_read_from_a_folder(tmp_path):
    design = Design()
    before = state(design)
    fig1 = SCENARIOS / "fig1_multipurpose.toml"
    with pytest.raises(DesignError, match=r"fig1_multipurpose.toml: surface.control_mesh "
                                          r"names the file 'fig1_multipurpose.obj'.*not given"):
        design.open_scenario(fig1.read_bytes(), fig1.name)
    assert state(design) == before
    # a folder the caller may read: the OBJ is read from it, inline in the session
    (tmp_path / "mesh").mkdir()
    (tmp_path / "mesh" / "seat.obj").write_text(
        "v 0 0.4 0\nv 1 0.4 0\nv 1 0.4 1\nv 0 0.4 1\nv 2 0.4 0\nv 2 0.4 1\n"
        "f 1 4 3 2\nf 2 3 6 5\n")
    path = tmp_path / "mesh" / "seat.toml"
    path.write_text(f'[surface]\ncontrol_mesh = "seat.obj"\nfixed = [4]\n'
                    f'[[person]]\npose = "{POSE}"\n')
    design.open_scenario(path.read_bytes(), path.name, base=path.parent)
    assert design.vertices.shape == (6, 3) and design.fixed == {4}
    assert differences(load_scenario(path), saved(design, tmp_path)) == [
        f"surface source {str(path.parent / 'seat.obj')!r} != "
        f"'inline control mesh, 6 vertices, 2 quads'"]


@pytest.mark.parametrize("content, problem", [
    (b"[surface]\ngrid = {}\n# caf\xe9\n", r"bad.toml: not a text file \(expected UTF-8, got "
                                           r"byte 0xe9 at offset 25\)"),
    ("[surface\ngrid = {}", r"bad.toml: not valid TOML: "),
    (f'[surface]\ngrid = {{}}\nsigma = -1.0\n[[person]]\npose = "{POSE}"\n',
     r"bad.toml: surface.sigma: "),
    (f'[surface]\ngrid = {{}}\ncolour = "red"\n[[person]]\npose = "{POSE}"\n',
     r"bad.toml: surface.colour: "),
    (f'[surface]\ngrid = {{}}\nfixed = [99]\n[[person]]\npose = "{POSE}"\n',
     r"bad.toml: surface.fixed\[0\]: expected a whole number in 0..62, got 99"),
    ('[surface]\ngrid = {}\n[[person]]\npose = "bvh:takes/sit.bvh#frame=3"\n',
     r"bad.toml: person\[0\].pose names the BVH file of 'bvh:takes/sit.bvh#frame=3'"),
    ('[surface]\ngrid = {}\n[[person]]\npose = "db:nobody"\n',
     r"bad.toml: person\[0\]: Pose 'db:nobody' needs a pose library"),
    ('[surface]\ngrid = {}\n[[person]]\npose = "bvh:bundled:none.bvh#frame=0"\n',
     r"bad.toml: person\[0\]: No bundled recording 'none.bvh'"),
    (f'[surface]\ngrid = {{}}\n[[person]]\npose = "{POSE}"\njoint_map = "map.toml"\n',
     r"bad.toml: person\[0\].joint_map names the file 'map.toml'"),
])
def test_a_bad_file_is_refused_with_its_problem_and_the_session_unchanged(content, problem):
    design = Design()
    design.add_person(POSE)
    design.set_parameter("sigma", 0.02)
    before = state(design)
    with pytest.raises(ValueError, match=problem):
        design.open_scenario(content, "bad.toml")
    assert state(design) == before


def test_the_view_opens_an_uploaded_scenario_and_says_what_it_opened(design_view):
    from viser import UploadedFile

    from studio.context import PROBLEM

    view = design_view
    path = SCENARIOS / "template_stool.toml"
    view.open._impl.value = UploadedFile(path.name, path.read_bytes())
    view._guarded(view._open_scenario)
    assert view.status_text.startswith("Opened template_stool.toml: 1 person on stool "
                                       "template"), view.status_text
    assert view.name.value == "template_stool" and view.selected.value.startswith("1: sitter (")
    assert view.design.params["level"] == view.level.value == 3
    assert not view.undo.disabled
    view._guarded(view._save_toml)  # Save TOML writes the stool again
    written = load_scenario(view.out / "template_stool.toml")
    assert differences(load_scenario(path), written) == []
    kept = state(view.design)
    view.open._impl.value = UploadedFile("broken.toml", b"[surface\n")
    view._guarded(view._open_scenario)
    assert view.status_text.startswith(f"{PROBLEM} broken.toml: not valid TOML"), \
        view.status_text
    assert state(view.design) == kept and view.name.value == "template_stool"


@pytest.mark.slow
def test_an_export_says_the_relief_its_fit_had_not_the_one_opened(tmp_path):
    """An opened scenario asks for rounds of relief, which the studio's fit does not run:
    the export (the fit on screen, with its report) writes a scenario.toml and a report that
    ask for none, so that `sitrelax fit` of it gives the fit exported; Save TOML keeps them."""
    import json

    text = (SCENARIOS / "single_seated.toml").read_text() + "\n[relief]\nrounds = 3\n"
    design = Design()
    design.open_scenario(text, "single_seated.toml")
    assert design.fit() is not None
    design.export(tmp_path / "export", formats=("obj",))
    exported = load_scenario(tmp_path / "export" / "scenario.toml")
    report = json.loads((tmp_path / "export" / "report.json").read_text())
    assert exported.relief.rounds == 0 and report["parameters"]["relief"]["rounds"] == 0
    assert report["relief"] is None
    assert saved(design, tmp_path).relief.rounds == 3
