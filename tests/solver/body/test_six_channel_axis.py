"""Axis exports with 6 channels on every joint (Axis Neuron and Axis Studio's default): position
channels holding each joint's translation in its parent frame for that frame, near the OFFSET
and varying as the suit's bone lengths are calibrated. Made here the way Axis writes them, from
the bundled Axis Neuron recording and from a synthetic seated motion on an Axis Studio skeleton,
with per-frame translations up to 8 cm off the offsets; each must retarget with the captured
bone directions (within 1 degree, every frame) through every way a pose gets to a body."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from capture import Motion, Skeleton, read_bvh, resolve_path, skeleton_fk, write_bvh
from capture.profiles import AXIS_STUDIO_JOINTS
from solver.body.model import make_body
from solver.body.poses import CapturedPose, load_pose, pose_body
from solver.body.retarget import RetargetError, joint_map_for, retarget

POS = ("Xposition", "Yposition", "Zposition")
ZXY = ("Zrotation", "Xrotation", "Yrotation")
# captured role -> rig joint, for the bones compared (parent role, child role)
BONES = [("left_upper_leg", "left_lower_leg"), ("left_lower_leg", "left_foot"),
         ("right_upper_leg", "right_lower_leg"), ("right_lower_leg", "right_foot"),
         ("left_upper_arm", "left_forearm"), ("left_forearm", "left_hand"),
         ("right_upper_arm", "right_forearm"), ("right_forearm", "right_hand")]
RIG = {"left_upper_leg": "LeftUpLeg", "left_lower_leg": "LeftLeg", "left_foot": "LeftFoot",
       "right_upper_leg": "RightUpLeg", "right_lower_leg": "RightLeg", "right_foot": "RightFoot",
       "left_upper_arm": "LeftArm", "left_forearm": "LeftForeArm", "left_hand": "LeftHand",
       "right_upper_arm": "RightArm", "right_forearm": "RightForeArm", "right_hand": "RightHand"}


def six_channels(skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray,
                 frame_time: float) -> tuple[Skeleton, Motion]:
    """A 6-channel-per-joint skeleton (ZXY rotations) and its motion from local rotations
    (T, J, 4) xyzw and local translations (T, J, 3) metres."""
    sk = Skeleton(skeleton.names, skeleton.parents, skeleton.offsets,
                  tuple(POS + ZXY for _ in skeleton.names), skeleton.end_sites,
                  skeleton.end_site_parents, unit_m=skeleton.unit_m)
    return sk, Motion(sk.channels_from_pose(rotations, translations), frame_time)


def calibrated(skeleton: Skeleton, frames: int, seed: int) -> np.ndarray:
    """(T, J, 3) metres: the offsets, each bone stretched or shifted by a slowly varying amount
    of up to 8 cm, as a suit's calibration moves them."""
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, size=(skeleton.num_joints, 3))
    t = np.linspace(0, 1, frames)[:, None, None]
    wobble = np.sin(2 * np.pi * t + phase)  # in [-1, 1]
    shift = 0.08 / np.sqrt(3) * wobble
    return skeleton.offsets_m[None] + shift


@pytest.fixture(scope="module")
def axis_neuron_six(tmp_path_factory):
    """The bundled Axis Neuron recording (3 channels but the root, YXZ), every 20th frame,
    rewritten as Axis writes it with displacement: 6 channels everywhere, ZXY."""
    bvh = read_bvh(resolve_path("bundled:axis_neuron_standing_yxz.bvh"))
    channels = bvh.motion.channels[::20]
    rot = bvh.skeleton.local_rotations(channels)
    trans = calibrated(bvh.skeleton, len(channels), 1)
    trans[:, 0] = bvh.skeleton.root_positions(channels)
    sk, motion = six_channels(bvh.skeleton, rot, trans, bvh.motion.frame_time * 20)
    path = tmp_path_factory.mktemp("axis") / "axis_neuron_six.bvh"
    write_bvh(path, sk, motion)
    return path


def axis_studio_skeleton() -> Skeleton:
    """An Axis Studio skeleton (Spine2 -> Neck -> Neck1 -> Head, no Spine3) made from the Axis
    Neuron one: Spine3's offset joins the neck's, the neck's head offset is split by Neck1."""
    src = read_bvh(resolve_path("bundled:axis_neuron_standing_yxz.bvh")).skeleton
    off = {n: src.offsets[src.index(n)] for n in src.names}
    parent_of = {n: (src.names[src.parents[src.index(n)]] if src.parents[src.index(n)] >= 0
                     else None) for n in src.names}
    for n in src.names:  # Spine3's children (the neck, the shoulders) hang from Spine2
        if parent_of[n] == "Spine3":
            parent_of[n], off[n] = "Spine2", off["Spine3"] + off[n]
    off["Neck1"] = off["Head"] / 2
    off["Head"] = off["Head"] / 2
    parent_of.update(Neck1="Neck", Head="Neck1")
    names = AXIS_STUDIO_JOINTS
    parents = [names.index(parent_of[n]) if parent_of[n] else -1 for n in names]
    ends = [names.index(src.names[p]) for p in src.end_site_parents]
    return Skeleton(names, parents, [off[n] for n in names], tuple(POS + ZXY for _ in names),
                    src.end_sites, ends, unit_m=0.01)


@pytest.fixture(scope="module")
def axis_studio_seated(tmp_path_factory):
    """A synthetic seated motion on an Axis Studio skeleton: thighs forward, shins down, trunk
    leaning back a little, arms resting forward, swaying over 40 frames."""
    sk = axis_studio_skeleton()
    frames = 40
    sway = np.sin(np.linspace(0, 2 * np.pi, frames))
    rot = np.tile([0.0, 0.0, 0.0, 1.0], (frames, sk.num_joints, 1))

    def turn(joint, axis, degrees):
        angles = np.broadcast_to(np.asarray(degrees, dtype=float), (frames,))[:, None]
        rot[:, sk.index(joint)] = Rotation.from_euler(axis, angles, degrees=True).as_quat()

    for side, sign in (("Left", 1), ("Right", -1)):
        turn(f"{side}UpLeg", "x", -88 + 4 * sway)
        turn(f"{side}Leg", "x", 92 - 3 * sway)
        turn(f"{side}Arm", "z", -sign * (70 + 5 * sway))
        turn(f"{side}ForeArm", "y", sign * (40 + 10 * sway))
    turn("Spine", "x", 8 + 3 * sway)
    trans = calibrated(sk, frames, 2)
    trans[:, 0] = [0.0, 0.52, 0.0]
    skeleton, motion = six_channels(sk, rot, trans, 1 / 60)
    path = tmp_path_factory.mktemp("studio") / "axis_studio_seated.bvh"
    write_bvh(path, skeleton, motion)
    return path


def _angles(captured_world, skeleton, motion) -> np.ndarray:
    """Degrees between each compared captured bone and the rig's, per frame and bone."""
    roles = joint_map_for(skeleton)
    cap = {r: captured_world.positions[:, skeleton.index(roles[r])] for r in RIG}
    rig = {r: motion.world.positions[:, motion.body.joint_index(j)] for r, j in RIG.items()}
    out = []
    for a, b in BONES:
        u, v = cap[b] - cap[a], rig[b] - rig[a]
        cos = np.sum(u * v, axis=1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        out.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.stack(out, axis=1)


@pytest.mark.parametrize("which", ["axis_neuron_six", "axis_studio_seated"])
def test_every_frame_keeps_the_captured_bone_directions(which, request):
    path = request.getfixturevalue(which)
    bvh = read_bvh(path)
    assert all(len(ch) == 6 for ch in bvh.skeleton.channels)
    # the files hold what Axis writes: per-frame translations off the offsets by up to 8 cm
    off = bvh.skeleton.local_translations(bvh.motion.channels)[:, 1:] - \
        bvh.skeleton.offsets_m[None, 1:]
    assert 0.05 < np.linalg.norm(off, axis=-1).max() <= 0.08 + 1e-9
    motion = retarget(bvh.skeleton, bvh.motion.channels, make_body())
    assert np.isfinite(motion.world.positions).all()
    angles = _angles(skeleton_fk(bvh.skeleton, bvh.motion.channels), bvh.skeleton, motion)
    assert angles.max() < 1.0, f"worst bone off by {angles.max():.2f} degrees"


def test_pose_show_poses_a_six_channel_file(axis_studio_seated, tmp_path, capsys):
    from solver.cli import main

    out = tmp_path / "posed.obj"
    assert main(["pose", "show", f"{axis_studio_seated}#frame=5", "--out", str(out),
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert 0.3 < report["pelvis_height_m"] < 0.8  # seated, on the floor
    assert out.stat().st_size > 100_000


def test_a_library_pose_of_a_six_channel_take_keeps_its_frame(axis_studio_seated, tmp_path):
    """Imported, a pose of the take retargets as the file's frame does (its own translations,
    not the offsets)."""
    from posedb import PoseLibrary

    lib = PoseLibrary(tmp_path / "poses.h5", create=True)
    take = lib.import_bvh(axis_studio_seated, name="studio_seated")
    lib.add_pose(take.id, 7, "perch")
    body = make_body()
    from_db = pose_body(load_pose("db:perch", tmp_path / "poses.h5"), body, lowest=None)
    from_file = pose_body(load_pose(f"bvh:{axis_studio_seated}#frame=7"), body, lowest=None)
    # the library keeps rotations as float32: equal to a few micrometres
    np.testing.assert_allclose(from_db.world.positions, from_file.world.positions, atol=2e-5)


@pytest.mark.slow  # the default run stays within its time
def test_a_scenario_fits_a_six_channel_pose(axis_studio_seated, tmp_path):
    from solver.scene.run import run_fit

    scenario = tmp_path / "s.toml"
    scenario.write_text(f"""
[surface]
template = {{ kind = "chair" }}
max_iterations = 15

[[person]]
pose = "bvh:{axis_studio_seated}#frame=3"
position = [0.0, 0.0, -0.05]
support = "chair"
""")
    report = run_fit(scenario, tmp_path / "out")
    person = report["persons"][0]
    assert person["coverage"] > 0.5 and np.isfinite(person["peak_pressure_kpa"])


def test_the_api_poses_a_six_channel_library_pose(axis_studio_seated, tmp_path):
    from fastapi.testclient import TestClient

    from posedb import PoseLibrary
    from studio.api import create_app

    lib = PoseLibrary(tmp_path / "poses.h5", create=True)
    take = lib.import_bvh(axis_studio_seated, name="studio_seated")
    lib.add_pose(take.id, 3, "perch")
    client = TestClient(create_app(tmp_path / "poses.h5"), base_url="http://127.0.0.1")
    reply = client.post("/api/body", json={"person": {"pose": "db:perch"}})
    assert reply.status_code == 200, reply.text
    v = np.asarray(reply.json()["vertices"])
    assert np.isfinite(v).all() and np.ptp(v[:, 1]) > 0.5


def test_a_file_that_would_pose_to_nan_names_the_joint_and_frame(tmp_path):
    """Legs without length (zero offsets and zero translations) and values that overflow to
    infinity in forward kinematics: each a named error, never a blank picture."""
    sk = axis_studio_skeleton()
    frames = 3
    rot = np.tile([0.0, 0.0, 0.0, 1.0], (frames, sk.num_joints, 1))
    trans = np.broadcast_to(sk.offsets_m, (frames,) + sk.offsets.shape).copy()
    for leg in ("LeftLeg", "LeftFoot", "RightLeg", "RightFoot"):
        trans[:, sk.index(leg)] = 0.0
    flat = Skeleton(sk.names, sk.parents, np.where(
        np.isin(np.arange(sk.num_joints), [sk.index(j) for j in ("LeftLeg", "LeftFoot",
                                                                   "RightLeg", "RightFoot")])
        [:, None], 0.0, sk.offsets), sk.channels, sk.end_sites, sk.end_site_parents, unit_m=0.01)
    path = tmp_path / "legless.bvh"
    write_bvh(path, flat, Motion(flat.channels_from_pose(rot, trans), 1 / 60))
    with pytest.raises(RetargetError, match=r"legless.bvh frame 1: Expected legs of some length"):
        pose_body(load_pose(f"{path}#frame=1"), make_body())
    # huge numbers in a large unit overflow to infinity in metres (a BVH file's values are
    # bounded by its reader now, `capture.bvh.MAX_VALUE`; a skeleton and channels made in
    # Python, or streamed, are not)
    huge = trans.copy()
    huge[2, sk.index("LeftForeArm")] = 1e306
    channels = sk.channels_from_pose(rot, huge)
    in_km = Skeleton(sk.names, sk.parents, sk.offsets, sk.channels, sk.end_sites,
                     sk.end_site_parents, unit_m=1000.0)
    with np.errstate(over="ignore", invalid="ignore"):  # the overflow is the case under test
        world = skeleton_fk(in_km, channels[2:3])
    captured = CapturedPose(in_km, world, "huge.bvh frame 2")
    with pytest.raises(RetargetError, match=r"huge.bvh frame 2: .*infinity at joint "
                                            r"'LeftForeArm' in frame 0"):
        pose_body(captured, make_body())
