"""Skeletons no profile knows, and recordings in any heading: a 24-joint course skeleton with
unfamiliar names is posed by automatic mapping alone, with a joint-map file, and from a library
pose imported with that map; a missing required joint names itself; the same seated pose
recorded facing +X, -X and +Z fits to the same surface."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from capture import Motion, Skeleton, read_bvh, resolve_path, skeleton_fk, write_bvh
from capture.jointmap import guess_joint_map, name_role
from solver.body.model import make_body
from solver.body.poses import load_pose, pose_body
from solver.body.retarget import RetargetError

# a course skeleton (SMPL's 24 joints and names): (name, parent, offset in metres)
COURSE = [
    ("pelvis", None, (0, 0.95, 0)),
    ("l_hip", "pelvis", (0.08, -0.08, 0)), ("l_knee", "l_hip", (0.01, -0.40, 0)),
    ("l_ankle", "l_knee", (0, -0.42, -0.02)), ("l_foot", "l_ankle", (0, -0.05, 0.13)),
    ("r_hip", "pelvis", (-0.08, -0.08, 0)), ("r_knee", "r_hip", (-0.01, -0.40, 0)),
    ("r_ankle", "r_knee", (0, -0.42, -0.02)), ("r_foot", "r_ankle", (0, -0.05, 0.13)),
    ("spine1", "pelvis", (0, 0.10, -0.01)), ("spine2", "spine1", (0, 0.13, 0)),
    ("spine3", "spine2", (0, 0.06, 0.01)), ("neck", "spine3", (0, 0.21, -0.02)),
    ("head", "neck", (0, 0.09, 0.04)),
    ("l_collar", "spine3", (0.07, 0.11, -0.01)), ("l_shoulder", "l_collar", (0.12, 0.03, 0)),
    ("l_elbow", "l_shoulder", (0.26, 0, 0)), ("l_wrist", "l_elbow", (0.25, 0, 0)),
    ("l_hand", "l_wrist", (0.08, 0, 0)),
    ("r_collar", "spine3", (-0.07, 0.11, -0.01)), ("r_shoulder", "r_collar", (-0.12, 0.03, 0)),
    ("r_elbow", "r_shoulder", (-0.26, 0, 0)), ("r_wrist", "r_elbow", (-0.25, 0, 0)),
    ("r_hand", "r_wrist", (-0.08, 0, 0)),
]


def course_skeleton() -> Skeleton:
    names = [n for n, _, _ in COURSE]
    parents = [names.index(p) if p else -1 for _, p, _ in COURSE]
    channels = [("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
                if p is None else ("Zrotation", "Xrotation", "Yrotation") for _, p, _ in COURSE]
    ends = [names.index(n) for n in ("l_foot", "r_foot", "head", "l_hand", "r_hand")]
    end_offsets = [(0, 0, 0.05), (0, 0, 0.05), (0, 0.12, 0), (0.05, 0, 0), (-0.05, 0, 0)]
    return Skeleton(names, parents, [o for _, _, o in COURSE], channels, end_offsets, ends,
                    unit_m=1.0)


def seated(skeleton: Skeleton, frames: int = 3) -> np.ndarray:
    """Channels of a seated pose (thighs forward, shins down, arms on the thighs)."""
    rot = np.tile([0.0, 0.0, 0.0, 1.0], (frames, skeleton.num_joints, 1))
    for name, axis, deg in (("l_hip", "x", -85), ("r_hip", "x", -85), ("l_knee", "x", 88),
                            ("r_knee", "x", 88), ("l_shoulder", "z", -65),
                            ("r_shoulder", "z", 65), ("l_elbow", "y", 50),
                            ("r_elbow", "y", -50)):
        rot[:, skeleton.index(name)] = Rotation.from_euler(axis, deg, degrees=True).as_quat()
    trans = np.broadcast_to(skeleton.offsets_m, (frames,) + skeleton.offsets.shape).copy()
    trans[:, 0] = [0.1, 0.5, 0.2]
    return skeleton.channels_from_pose(rot, trans)


@pytest.fixture(scope="module")
def course_file(tmp_path_factory):
    sk = course_skeleton()
    path = tmp_path_factory.mktemp("course") / "course.bvh"
    write_bvh(path, sk, Motion(seated(sk), 1 / 30))
    return path


def test_common_naming_schemes_name_their_roles():
    cases = {"mixamorig:LeftUpLeg": "left_upper_leg", "Hips": "hips", "LeftLeg":
             "left_lower_leg", "l_hip": "left_upper_leg", "lhip": "left_upper_leg",
             "Left_Hip": "left_upper_leg", "LThigh": "left_upper_leg", "femur_l":
             "left_upper_leg", "tibia.R": "right_lower_leg", "rknee": "right_lower_leg",
             "pelvis": "hips", "r_wrist": "right_hand", "L_Elbow": "left_forearm",
             "RightForeArm": "right_forearm", "lclavicle": "left_shoulder", "Neck": "neck",
             "Head": "head", "LeftToeBase": "left_toe", "l_ankle": "left_foot"}
    assert {n: name_role(n) for n in cases} == cases
    assert name_role("leg") is None and name_role("Neck1") is None  # no side, no such part


def test_the_course_skeleton_maps_by_name_and_structure(course_file):
    guess = guess_joint_map(read_bvh(course_file, unit="m").skeleton)
    assert not guess.missing
    assert guess.roles["left_upper_arm"] == "l_shoulder"  # SMPL's shoulder is the upper arm
    assert guess.roles["left_shoulder"] == "l_collar"
    assert guess.roles["left_toe"] == "l_foot" and guess.how["left_toe"] == "structure"
    assert guess.roles["head_top"] == "end:head"


def _rig_bone(motion, a, b):
    w = motion.world.positions[0]
    v = w[motion.body.joint_index(b)] - w[motion.body.joint_index(a)]
    return v / np.linalg.norm(v)


def test_the_course_skeleton_is_posed_from_the_command_line(course_file, tmp_path, capsys):
    from solver.cli import main

    code = main(["pose", "show", f"{course_file}#frame=1", "--unit", "m", "--out",
                 str(tmp_path / "auto.obj"), "--json"])
    assert code == 0
    auto = json.loads(capsys.readouterr().out)
    assert auto["profile"] is None and auto["roles"]["left_forearm"] == "l_elbow"
    assert auto["roles_found_by"]["left_toe"] == "structure"
    assert {"spine1", "spine2"} <= set(auto["joints_without_role"])
    assert 0.3 < auto["pelvis_height_m"] < 0.8
    # a joint-map file naming the same roles gives the same posed body
    roles = {k: v for k, v in auto["roles"].items()}
    (tmp_path / "course.toml").write_text("[roles]\n" + "".join(
        f'{k} = "{v}"\n' for k, v in roles.items()))
    assert main(["pose", "show", f"bvh:{course_file}#frame=1&unit=m", "--joint-map",
                 str(tmp_path / "course.toml"), "--out", str(tmp_path / "mapped.obj"),
                 "--json"]) == 0
    mapped = json.loads(capsys.readouterr().out)
    assert set(mapped["roles_found_by"].values()) == {"map"}
    assert (tmp_path / "auto.obj").read_text() == (tmp_path / "mapped.obj").read_text()
    # the captured thigh's direction is the rig's
    sk = read_bvh(course_file, unit="m").skeleton
    w = skeleton_fk(sk, read_bvh(course_file, unit="m").motion.channels[1:2]).positions[0]
    thigh = w[sk.index("l_knee")] - w[sk.index("l_hip")]
    motion = pose_body(load_pose(f"{course_file}#frame=1", unit="m"), make_body())
    assert np.dot(_rig_bone(motion, "LeftUpLeg", "LeftLeg"), thigh / np.linalg.norm(thigh)) \
        > np.cos(np.radians(1.0))


def test_a_library_pose_imported_with_a_joint_map_just_works(course_file, tmp_path):
    from posedb import PoseLibrary

    bvh = read_bvh(course_file, unit="m")
    lib = PoseLibrary(tmp_path / "poses.h5", create=True)
    # a map that could not be guessed: the wrists play the hands
    mapped = bvh.skeleton.with_joint_map({"left_hand": "l_wrist", "right_hand": "r_wrist",
                                          "left_forearm": "l_elbow",
                                          "right_forearm": "r_elbow"})
    with lib.edit() as ed:
        take = ed.add_take(mapped, bvh.motion.channels, bvh.motion.frame_time, name="course")
        ed.add_pose(take, 2, "course_sit")
    captured = load_pose("db:course_sit", tmp_path / "poses.h5")
    assert dict(captured.skeleton.joint_map)["left_hand"] == "l_wrist"
    motion = pose_body(captured, make_body())
    assert np.isfinite(motion.world.positions).all()


def test_db_import_stores_a_joint_map_file_with_the_skeleton(course_file, tmp_path):
    from solver.cli import main

    (tmp_path / "map.toml").write_text('left_hand = "l_wrist"\nright_hand = "r_wrist"\n'
                                       'left_forearm = "l_elbow"\nright_forearm = "r_elbow"\n')
    db = str(tmp_path / "poses.h5")
    assert main(["db", "import", str(course_file), "--db", db, "--unit", "m", "--name",
                 "course", "--joint-map", str(tmp_path / "map.toml")]) == 0
    assert main(["db", "pose", "add", "course", "1", "--name", "perch", "--db", db]) == 0
    captured = load_pose("db:perch", db)
    assert dict(captured.skeleton.joint_map)["right_hand"] == "r_wrist"
    assert np.isfinite(pose_body(captured, make_body()).world.positions).all()
    (tmp_path / "bad.toml").write_text('left_hnd = "l_wrist"\n')
    with pytest.raises(ValueError, match="did you mean left_hand"):
        main(["--debug", "db", "import", str(course_file), "--db", db, "--unit", "m",
              "--name", "course2", "--joint-map", str(tmp_path / "bad.toml")])


def test_a_missing_required_joint_names_itself(tmp_path):
    sk = course_skeleton()
    keep = [n for n, _, _ in COURSE if n not in ("l_elbow", "l_wrist", "l_hand")]
    names = list(keep)
    parents = [names.index(p) if p else -1 for n, p, _ in COURSE if n in keep]
    offsets = [o for n, _, o in COURSE if n in keep]
    channels = [sk.channels[sk.index(n)] for n in keep]
    armless = Skeleton(names, parents, offsets, channels, unit_m=1.0)
    rot = np.tile([0.0, 0.0, 0.0, 1.0], (1, len(names), 1))
    path = tmp_path / "armless.bvh"
    write_bvh(path, armless, Motion(armless.channels_from_pose(
        rot, armless.offsets_m[None]), 1 / 30))
    with pytest.raises(RetargetError, match=r"armless.bvh frame 0: .*'left_forearm', "
                                            r"'left_hand'"):
        pose_body(load_pose(f"{path}#frame=0&unit=m"), make_body())


def _turned_copy(path, yaw_deg: float, out):
    """The recording with its root turned about the vertical (another capture heading)."""
    bvh = read_bvh(path)
    sk, ch = bvh.skeleton, bvh.motion.channels
    rot = sk.local_rotations(ch)
    trans = sk.local_translations(ch)
    turn = Rotation.from_euler("y", yaw_deg, degrees=True)
    rot[:, 0] = (turn * Rotation.from_quat(rot[:, 0])).as_quat()
    trans[:, 0] = turn.apply(trans[:, 0])
    write_bvh(out, sk, Motion(sk.channels_from_pose(rot, trans), bvh.motion.frame_time))
    return out


@pytest.mark.slow  # the default run stays within its time
@pytest.mark.filterwarnings("ignore:Gimbal lock detected")  # a quarter turn in Z-Y-X angles
def test_the_same_pose_in_any_capture_heading_fits_the_same_surface(tmp_path):
    from solver.scene.run import fit_people
    from solver.scene.placement import place_person
    from solver.scene.scenario import parse_scenario

    source = resolve_path("bundled:cmu_75_18_high_sit.bvh")
    surfaces = []
    for name, yaw in (("plus_z", 0.0), ("plus_x", 90.0), ("minus_x", -90.0)):
        path = _turned_copy(source, yaw, tmp_path / f"{name}.bvh")
        scenario = parse_scenario({
            "surface": {"grid": {"size": [0.5, 0.6], "resolution": [8, 6], "height": 0.42},
                        "max_iterations": 20},
            "person": [{"pose": f"bvh:{path}#frame=39", "position": [0.0, 0.0, -0.1],
                        "support": ["legs"]}]}, "test", tmp_path)
        people = [place_person(p) for p in scenario.persons]
        surfaces.append(fit_people(scenario, people).surface)
    for other in surfaces[1:]:
        assert np.abs(other - surfaces[0]).max() < 1e-3, np.abs(other - surfaces[0]).max()
    # and keeping the capture's heading does turn the seat's person away
    scenario = parse_scenario({"surface": {"grid": {}}, "person": [
        {"pose": f"bvh:{tmp_path / 'plus_x.bvh'}#frame=39", "facing": "capture"}]}, "t")
    turned = place_person(scenario.persons[0])
    hips = [turned.motion.body.joint_index(j) for j in ("LeftUpLeg", "RightUpLeg")]
    left = turned.transform[:3, :3] @ (turned.motion.world.positions[0, hips[0]]
                                       - turned.motion.world.positions[0, hips[1]])
    assert abs(left[2]) > 0.8 * np.linalg.norm(left)  # the hip axis along z: facing +-X


def test_a_scenario_s_joint_map_is_the_one_its_person_is_posed_by(course_file):
    """A person's `joint_map` in a scenario is checked against the skeleton and used: the
    automatic map's own joints pose the body alike, the left wrist named as the forearm's
    joint (the elbow, bent 50 degrees, left out) moves the left arm; a joint the skeleton
    lacks is refused by name."""
    from solver.body.poses import PoseSourceError
    from solver.scene.placement import place_person
    from solver.scene.scenario import parse_scenario

    def placed(joint_map):
        person = {"pose": f"bvh:{course_file}#frame=1&unit=m"}
        if joint_map is not None:
            person["joint_map"] = joint_map
        scenario = parse_scenario({"surface": {"grid": {}}, "person": [person]})
        return place_person(scenario.persons[0])

    guessed, same = placed(None), placed({"left_hand": "l_hand", "right_hand": "r_hand"})
    assert np.allclose(guessed.vertices, same.vertices)
    straight = placed({"left_forearm": "l_wrist", "left_hand": "l_hand"})
    moved = np.linalg.norm(straight.vertices - guessed.vertices, axis=1)
    assert moved.max() > 0.02
    with pytest.raises(PoseSourceError, match="left_hand names 'NoSuchJoint', which is no "
                                              "joint of the skeleton"):
        placed({"left_hand": "NoSuchJoint"})
