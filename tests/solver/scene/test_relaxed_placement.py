"""A pose stored by a relaxation (`sitrelax relax --save`) carries where the relaxation left it,
so put back into its scenario it stands there, and moves and turns with its person; a
scenario's ``placement = "standard"`` places it as any other pose."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver.body.model import BodyShape
from solver.body.relax import RelaxResult
from solver.body.rig import rig_pose
from solver.body.skinning import skin
from solver.scene.placement import place_person, placement
from solver.scene.run import save_relaxed
from solver.scene.scenario import PersonSpec, ScenarioError, parse_scenario
from tests.conftest import high_sit_library

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"
HEAVY = {"gender": 0.5, "weight": 1.0, "muscle": 0.0, "height": 0.5}


@pytest.fixture
def db(tmp_path):
    return high_sit_library(tmp_path / "poses.h5", [(39, "perched", ["sitting"])])


def _relaxed(person, turn_deg=6.0, move=(0.012, -0.061, 0.021)):
    """A stand-in for a relaxation of a placed person (what `relax_person` returns, in the
    scene frame): its pelvis turned about the vertical, its left knee bent 10 degrees further
    and the whole body moved by `move` metres (the 6.1 cm that figure 8's heavy body sank into
    the thin body's seat)."""
    body = person.body
    rot, shift = person.transform[:3, :3], person.transform[:3, 3]
    local = person.motion.local_rotmats[0].copy()
    local[0] = Rotation.from_euler("y", turn_deg, degrees=True).as_matrix() @ rot @ local[0]
    knee = body.joint_index("LeftLeg")
    local[knee] = local[knee] @ Rotation.from_euler("x", 10, degrees=True).as_matrix()
    root = rot @ person.motion.root_positions[0] + shift + np.asarray(move)
    world = rig_pose(body, local, root)
    vertices, _ = skin(body, world, normals=False)
    return RelaxResult(np.zeros(3 * len(local) + 3), local, world, vertices, 0.0, 0, 1, 0)


def _distance(a, b):
    return float(np.linalg.norm(a - b, axis=1).max())


@pytest.mark.parametrize("facing", ["front", "capture"])
def test_a_stored_relaxed_pose_stands_where_the_relaxation_left_it(db, facing):
    spec = PersonSpec(pose="db:perched", body=BodyShape(**HEAVY),
                      position=(0.3, 0.02, -0.1), rotation_deg=(0.0, 30.0, 0.0), facing=facing)
    person = place_person(spec, db)
    res = _relaxed(person)
    saved = save_relaxed(db, [(person, res)], "test")[0]
    stored = dataclasses.replace(spec, pose=f"db:{saved['name']}")

    again = place_person(stored, db)  # the same scenario, position and rotation
    assert _distance(again.vertices, res.vertices) < 1e-4  # (measured: 4e-8 m)

    # moved and turned in a scenario, the relaxed body moves and turns with its person
    there = dataclasses.replace(stored, position=(-1.0, 0.4, 0.5), rotation_deg=(10.0, 80.0, 5.0))
    moved = place_person(there, db)
    before, after = placement(spec.position, spec.rotation_deg), \
        placement(there.position, there.rotation_deg)
    expected = (res.vertices - before[:3, 3]) @ before[:3, :3] @ after[:3, :3].T + after[:3, 3]
    assert _distance(moved.vertices, expected) < 1e-4


def test_a_scenario_may_place_a_stored_pose_the_standard_way(db):
    spec = PersonSpec(pose="db:perched", position=(0.3, 0.02, -0.1),
                      rotation_deg=(0.0, 30.0, 0.0))
    person = place_person(spec, db)
    saved = save_relaxed(db, [(person, _relaxed(person))], "test")[0]
    stored = dataclasses.replace(spec, pose=f"db:{saved['name']}")
    standard = place_person(dataclasses.replace(stored, placement="standard"), db)
    # its lowest point on the floor (raised by position's 2 cm), its pelvis over the position
    assert standard.vertices[:, 1].min() == pytest.approx(0.02, abs=1e-9)
    pelvis = standard.transform[:3, :3] @ standard.motion.world.positions[0, 0] + \
        standard.transform[:3, 3]
    np.testing.assert_allclose(pelvis[[0, 2]], [0.3, -0.1], atol=1e-9)
    assert _distance(place_person(stored, db).vertices, standard.vertices) > 0.05

    # a pose without a stored placement places the same either way
    np.testing.assert_array_equal(
        place_person(dataclasses.replace(spec, placement="standard"), db).vertices,
        person.vertices)


def test_a_scenario_names_a_placement_it_does_not_know():
    data = {"surface": {"grid": {"size": [0.5, 0.6], "resolution": [8, 6], "height": 0.42}},
            "person": [{"pose": "db:perched", "placement": "relaxed"}]}
    with pytest.raises(ScenarioError, match=r"person\[0\]\.placement"):
        parse_scenario(data, "s.toml", files=False)
    data["person"][0]["placement"] = "standard"
    assert parse_scenario(data, "s.toml", files=False).persons[0].placement == "standard"


@pytest.mark.slow
def test_relax_save_then_the_stored_pose_in_the_same_scenario(db, tmp_path, capsys):
    """End to end through the commands: figure 8's heavy body relaxed onto the thin body's
    seat (README), stored, and placed again in its scenario."""
    import json

    import trimesh

    from solver.cli import main
    from solver.scene.scenario import load_scenario

    thin = tmp_path / "thin"
    assert main(["fit", str(EXAMPLES / "seat_for_thin.toml"), "--out", str(thin)]) == 0
    scenario = tmp_path / "heavy.toml"
    scenario.write_text((EXAMPLES / "seat_for_heavy.toml").read_text().replace(
        'pose = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"', 'pose = "db:perched"'))
    out = tmp_path / "heavy_on_thin"
    capsys.readouterr()
    assert main(["relax", str(scenario), "--surface", str(thin), "--db", str(db), "--save",
                 "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)["persons"][0]
    assert report["relaxation"]["accepted"]
    spec = load_scenario(scenario).persons[0]
    again = place_person(dataclasses.replace(spec, pose=f"db:{report['saved_pose']['name']}"),
                         db)
    relaxed = trimesh.load(out / "person_1_relaxed.obj", process=False).vertices
    assert _distance(again.vertices, relaxed) < 1e-3  # (measured: 0.0009 mm, the OBJ's digits)
    # the standard placement would set it down (README: 6.1 cm lower)
    standard = place_person(dataclasses.replace(spec, pose=f"db:{report['saved_pose']['name']}",
                                                placement="standard"), db)
    assert (relaxed - standard.vertices).mean(axis=0)[1] > 0.05
