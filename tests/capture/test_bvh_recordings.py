"""Real recordings read right: counts, bvhio as an independent oracle, the seated phase."""

import numpy as np
import pytest

import bvhio
from scipy.spatial.transform import Rotation

from capture import Motion, bundled_recordings, read_bvh, write_bvh
from capture.recordings import bundled_dir

from tests.conftest import SHARED_BVH, recording

ALL_FILES = sorted(
    {p.name for p in SHARED_BVH.glob("*.bvh")} | set(bundled_recordings())
)


@pytest.mark.parametrize("name", ALL_FILES)
def test_every_recording_reads(name):
    bvh = read_bvh(recording(name))
    assert bvh.motion.num_frames > 0
    assert bvh.motion.channels.shape == (bvh.motion.num_frames, bvh.skeleton.num_channels)
    assert bvh.profile in ("cmu", "axis_neuron")
    assert np.isfinite(bvh.world_positions()).all()


def test_bundled_copies_are_the_shared_files():
    if not SHARED_BVH.exists():
        pytest.skip("shared recordings not beside the repository")
    for name in bundled_recordings():
        assert (bundled_dir() / name).read_bytes() == (SHARED_BVH / name).read_bytes()


def test_read_bvh_takes_bundled_names():
    """`bundled:NAME` reads the bundled file (as the command line's paths do); an unknown name
    says which are bundled."""
    named = read_bvh("bundled:cmu_75_18_high_sit.bvh")
    assert named.path == str(bundled_dir() / "cmu_75_18_high_sit.bvh")
    assert np.array_equal(named.motion.channels,
                          read_bvh(bundled_dir() / "cmu_75_18_high_sit.bvh").motion.channels)
    with pytest.raises(FileNotFoundError, match="bundled are"):
        read_bvh("bundled:nothing.bvh")


@pytest.mark.parametrize(
    "name, joints, frames, channels, profile",
    [
        ("cmu_75_18_high_sit.bvh", 31, 77, 96, "cmu"),
        ("axis_neuron_standing_yxz.bvh", 59, 2156, 180, "axis_neuron"),
        ("cmu_75_17_medium_sit.bvh", 31, 325, 96, "cmu"),
        ("cmu_82_05_floor_sit_excerpt.bvh", 31, 16, 96, "cmu"),
    ],
)
def test_counts(name, joints, frames, channels, profile):
    bvh = read_bvh(recording(name))
    assert bvh.skeleton.num_joints == joints
    assert bvh.motion.num_frames == frames
    assert bvh.skeleton.num_channels == channels
    assert bvh.profile == profile


def _bvhio_world_positions(path, unit_m):
    root = bvhio.readAsHierarchy(str(path))
    layout = root.layout()
    frames = len(root.Keyframes)
    out = np.empty((frames, len(layout), 3))
    for f in range(frames):
        root.loadPose(f)
        out[f] = [tuple(joint.PositionWorld) for joint, _, _ in layout]
    return [joint.Name for joint, _, _ in layout], out * unit_m


# bvhio takes seconds to read the 2156-frame Axis Neuron file: every frame of it is compared
# under `-m slow`, a sample in the default run (test_a_sample_of_the_axis_recording_matches_bvhio)
@pytest.mark.parametrize("name", [
    "cmu_75_18_high_sit.bvh",
    pytest.param("axis_neuron_standing_yxz.bvh", marks=pytest.mark.slow)])
def test_world_positions_match_bvhio(name):
    path = recording(name)
    bvh = read_bvh(path)
    names, expected = _bvhio_world_positions(path, bvh.skeleton.unit_m)
    assert names == list(bvh.skeleton.names)
    ours = bvh.world_positions()
    assert ours.shape == expected.shape
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-4)


@pytest.mark.slow
def test_world_rotations_match_bvhio_on_sampled_frames(axis_standing):
    # bvhio's joint frames carry a constant rest orientation per joint (its bones point along
    # their local Y), so compare motion relative to frame 0: R(f) R(0)^-1 is free of it.
    bvh = read_bvh(axis_standing)
    root = bvhio.readAsHierarchy(str(axis_standing))
    layout = root.layout()
    ours = Rotation.from_matrix(bvh.fk().rotmats.reshape(-1, 3, 3)).as_quat()
    ours = ours.reshape(bvh.motion.num_frames, bvh.skeleton.num_joints, 4)

    def theirs(frame):
        root.loadPose(frame)
        return Rotation.from_quat([(j.RotationWorld.x, j.RotationWorld.y, j.RotationWorld.z,
                                    j.RotationWorld.w) for j, _, _ in layout])

    base_theirs = theirs(0)
    base_ours = Rotation.from_quat(ours[0])
    for f in (1, 500, 1500, 2155):
        rel_theirs = theirs(f) * base_theirs.inv()
        rel_ours = Rotation.from_quat(ours[f]) * base_ours.inv()
        angle = (rel_ours * rel_theirs.inv()).magnitude()
        assert angle.max() < 1e-5, (f, angle.max())


def test_a_sample_of_the_axis_recording_matches_bvhio(axis_standing, tmp_path):
    """The default run's bvhio check of the Axis Neuron recording: the frames sampled above,
    written as a file of their own, read by bvhio; positions and rotations (relative to the
    first sampled frame) agree with ours from the whole recording."""
    frames = [0, 1, 500, 1500, 2155]
    bvh = read_bvh(axis_standing)
    sample = tmp_path / "sample.bvh"
    write_bvh(sample, bvh.skeleton, Motion(bvh.motion.channels[frames], bvh.motion.frame_time))
    names, expected = _bvhio_world_positions(sample, bvh.skeleton.unit_m)
    assert names == list(bvh.skeleton.names)
    world = bvh.fk()
    np.testing.assert_allclose(world.positions[frames], expected, rtol=0, atol=1e-4)
    root = bvhio.readAsHierarchy(str(sample))
    layout = root.layout()

    def theirs(k):
        root.loadPose(k)
        return Rotation.from_quat([(j.RotationWorld.x, j.RotationWorld.y, j.RotationWorld.z,
                                    j.RotationWorld.w) for j, _, _ in layout])

    ours = [Rotation.from_matrix(world.rotmats[f]) for f in frames]
    for k in range(1, len(frames)):
        angle = ((ours[k] * ours[0].inv()) * (theirs(k) * theirs(0).inv()).inv()).magnitude()
        assert angle.max() < 1e-5, (frames[k], angle.max())


def test_seated_phase_of_the_high_sit(cmu_high_sit):
    bvh = read_bvh(cmu_high_sit)
    hips = bvh.world_positions()[:, bvh.skeleton.index("Hips"), 1]
    standing = hips[1:8]
    seated = hips[18:52]
    assert np.all(np.abs(standing - 1.0) < 0.06), standing
    assert np.all(np.abs(seated - 0.5) < 0.06), seated
    # the sit is a clear, held phase: at least 40 cm lower than standing, and nearly still
    assert standing.mean() - seated.mean() > 0.4
    assert np.ptp(seated[5:-5]) < 0.05
