"""`sitrelax design`'s refusals of poses it cannot read, before any fit."""

import json
from pathlib import Path

import pytest

from solver.cli import main
from solver.scene.design import run_design


@pytest.mark.parametrize("pose", ["#frame=1", "bvh:#frame=1"])
def test_a_pose_without_a_file_is_refused_as_pose_show_refuses_it(tmp_path, monkeypatch,
                                                                   pose):
    # (not as the working folder, which an empty file name resolved to: "...: expected a BVH
    # file, got a directory", naming a folder the user never gave)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=r"Expected a pose as db:NAME or \[bvh:\]FILE.bvh"
                                         r"#frame=N\[&unit=U\], got '" + pose + "'"):
        run_design([pose], tmp_path / "design")
    assert list(tmp_path.iterdir()) == []


def test_the_command_says_so_in_json(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["design", "#frame=1", "--out", "chair", "--json"]) == 2
    captured = capsys.readouterr()
    assert json.loads(captured.out) == {
        "error": "Expected a pose as db:NAME or [bvh:]FILE.bvh#frame=N[&unit=U], got "
                 "'#frame=1'", "exit_status": 2}
    assert list(tmp_path.iterdir()) == []


def test_a_file_of_unknown_unit_is_answered_with_a_form_design_takes(tmp_path):
    # (`design` has no --unit: the pose's own &unit=U is the way to give it)
    bvh = (Path(__file__).parents[3] / "fixtures" / "bvh" / "dialects"
           / "synthetic_course_skeleton_end_names.bvh")
    with pytest.raises(ValueError, match="length unit is unknown") as refused:
        run_design([f"{bvh}#frame=0"], tmp_path / "design")
    assert "--unit" not in str(refused.value)
    assert "synthetic_course_skeleton_end_names.bvh#frame=0&unit=cm" in str(refused.value)
    assert not (tmp_path / "design").exists()
