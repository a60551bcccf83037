"""A library whose stored rotations are no unit quaternions (a zero one, a scaled one: bits
flipped in uncompressed data) is reported by `db check` and refused, naming the file, by the
readers, rather than passed to scipy (which refuses a zero quaternion with its own words and
silently normalises any other)."""

import json

import h5py
import numpy as np
import pytest

from posedb import PoseLibrary
from posedb.schema import StorageError
from posedb.verify import verify
from studio.cli import main
from tests.conftest import high_sit_library


@pytest.fixture
def library(tmp_path):
    return high_sit_library(tmp_path / "lib.h5")


def _damage(path, dataset, index, value):
    with h5py.File(path, "r+") as f:
        f[dataset][index] = value


@pytest.mark.parametrize("value", [[0, 0, 0, 0], [10, 0, 0, 1], [0, 0, 0, 0.5]])
def test_a_pose_rotation_that_is_no_unit_quaternion_is_damage(library, value, capsys):
    _damage(library, "/poses/rotations", 3, value)
    problems = verify(library)
    assert problems and "/poses/rotations: row 3" in problems[0]
    assert "not a unit quaternion" in problems[0]
    with pytest.raises(StorageError, match=r"pose 'perch'.*row 3.*not a unit quaternion.*db check"):
        PoseLibrary(library).pose_data("perch")
    capsys.readouterr()
    assert main(["db", "check", "--db", str(library), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is False and "not a unit quaternion" in report["problems"][0]


def test_a_take_rotation_that_is_no_unit_quaternion_is_damage(library):
    _damage(library, "/takes/take-00001/local_rotations", (20, 4), [0, 0, 0, 0])
    problems = verify(library)
    assert any("/takes/take-00001/local_rotations: row 20" in p for p in problems)
    with pytest.raises(StorageError, match=r"local_rotations: frame 20 .*norm 0, not a unit"):
        PoseLibrary(library).take_data("high_sit")
    # a part of the take without it reads
    assert PoseLibrary(library).take_data("high_sit", 0, 20).local_rotations.shape[0] == 20


def test_rotations_as_written_are_unit_quaternions(library):
    assert verify(library) == []
    _, _, rot, _ = PoseLibrary(library).pose_data("perch")
    assert np.allclose(np.linalg.norm(rot, axis=-1), 1, atol=1e-6)
