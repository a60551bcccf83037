"""Suggestion: short holds at the bottom of a motion (a synthetic squat on a CMU skeleton), the
real recordings finding what they found before, tags inherited and names printed."""

import json

import numpy as np
import pytest

from capture import identify_profile, read_bvh
from posedb.library import PoseLibrary
from posedb.suggest import held_postures, suggest_poses

from ..conftest import recording

CMU = "cmu_75_18_high_sit.bvh"
FRAME_TIME = 1 / 120


def squat(hold: float = 0.3, depth_m: float = 0.4, stand: float = 1.0, move: float = 0.7):
    """A CMU skeleton standing `stand` s, going down `depth_m` in `move` s (eased), holding
    `hold` s, up again and standing: (skeleton, channels (T, C), bottom frames [a, b])."""
    bvh = read_bvh(recording(CMU))
    sk, first = bvh.skeleton, bvh.motion.channels[0]
    n = [int(round(x / FRAME_TIME)) for x in (stand, move, hold, move, stand)]
    ease = lambda k: 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, k))  # noqa: E731
    depth = np.concatenate([np.zeros(n[0]), ease(n[1]), np.ones(n[2]), ease(n[3])[::-1],
                            np.zeros(n[4])])
    channels = np.tile(first, (len(depth), 1))
    starts = sk.channel_starts
    root_y = starts[0] + sk.channels[0].index("Yposition")
    channels[:, root_y] -= depth * depth_m / sk.unit_m
    for joint, angle in (("LeftUpLeg", -70), ("RightUpLeg", -70), ("LeftLeg", 110),
                         ("RightLeg", 110)):
        j = sk.index(joint)
        channels[:, starts[j] + sk.channels[j].index("Xrotation")] += depth * angle * depth_m / 0.4
    bottom = (n[0] + n[1], n[0] + n[1] + n[2] - 1)
    return sk, channels, bottom


def test_a_squat_bottom_held_0_3_s_is_found_with_the_defaults():
    sk, channels, (a, b) = squat()
    held = held_postures(sk, channels, FRAME_TIME, identify_profile(sk.names))
    kinds = [h.kind for h in held]
    assert kinds == ["hold", "bottom", "hold"], [h.as_dict() for h in held]
    bottom = held[1]
    assert a - 12 <= bottom.start and bottom.end <= b + 12 and a <= bottom.frame <= b
    # the old rule (0.5 s) alone misses it
    assert len(held_postures(sk, channels, FRAME_TIME, identify_profile(sk.names),
                             min_bottom_duration=None)) == 2


def test_a_short_pause_without_a_descent_is_not_a_bottom():
    # a quick 5 cm dip: its still middle is as short, but it is no squat's bottom
    sk, channels, _ = squat(depth_m=0.05, move=0.15)
    held = held_postures(sk, channels, FRAME_TIME, identify_profile(sk.names))
    assert [h.kind for h in held] == ["hold", "hold"], [h.as_dict() for h in held]


@pytest.mark.parametrize("name, expected", [
    ("cmu_75_18_high_sit.bvh", [(29, 44, 39)]),
    ("cmu_75_17_medium_sit.bvh", [(8, 43, 10), (122, 230, 215)]),
    ("cmu_82_05_floor_sit_excerpt.bvh", []),
    ("axis_neuron_standing_yxz.bvh", [(0, 2155, 0)]),
])
def test_the_recordings_find_what_they_found_before(name, expected):
    bvh = read_bvh(recording(name))
    held = held_postures(bvh.skeleton, bvh.motion.channels, bvh.motion.frame_time,
                         identify_profile(bvh.skeleton.names))
    assert [(h.start, h.end, h.frame) for h in held] == expected


def test_accepted_poses_inherit_the_take_tags_and_the_cli_prints_names(tmp_path, capsys):
    from studio.cli import main

    sk, channels, _ = squat()
    lib = PoseLibrary(tmp_path / "poses.h5", create=True)
    with lib.edit() as ed:
        ed.add_take(sk, channels, FRAME_TIME, name="squat", tags=["squat", "synthetic"])
    rows = suggest_poses(lib, "squat", accept=True, tags=["deep"])
    assert len(rows) == 3
    for row in rows:
        assert lib.pose(row["name"]).tags == ("deep", "squat", "synthetic") == tuple(row["tags"])
    db = str(tmp_path / "poses.h5")
    with lib.edit() as ed:
        for row in rows:
            ed.delete_pose(row["name"])
    assert main(["db", "suggest", "squat", "--accept", "--db", db]) == 0
    out = capsys.readouterr().out
    bottom = rows[1]["name"]
    assert f"-> pose {bottom} (tags: squat synthetic)" in out and "pose-0" not in out
    assert main(["db", "show", bottom, "--db", db, "--json"]) == 0  # the printed name works
    assert json.loads(capsys.readouterr().out)["tags"] == ["squat", "synthetic"]
    # a name that is neither: the message says it was sought as both
    assert main(["db", "show", "nosuch", "--db", db]) == 2
    assert "No pose or take 'nosuch'" in capsys.readouterr().err


@pytest.mark.parametrize("option, value", [("max_speed", -1.0), ("max_speed", float("nan")),
                                           ("max_speed", 0.0), ("min_duration", float("nan")),
                                           ("min_duration", -3.0),
                                           ("min_bottom_duration", float("inf"))])
def test_thresholds_that_are_no_numbers_or_negative_are_refused_by_name(option, value):
    from posedb.schema import LibraryError

    sk, channels, _ = squat()
    with pytest.raises(LibraryError, match=f"Expected {option} as a finite number"):
        held_postures(sk, channels, FRAME_TIME, identify_profile(sk.names), **{option: value})
