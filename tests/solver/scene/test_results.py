"""`sitrelax fit` and `sitrelax relax` into a folder that holds an earlier result: the folder
then holds the new result alone (the earlier one's files that the new one does not write go,
the user's own files stay), and a fit that fails leaves the earlier result as it was."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from solver.scene.run import run_fit

EXAMPLES = Path(__file__).resolve().parents[3] / "solver" / "data" / "scenarios"


def test_a_fit_written_again_into_its_folder_leaves_no_file_of_the_earlier_one(tmp_path):
    out = tmp_path / "out"
    first = run_fit(EXAMPLES / "single_seated.toml", out, formats=("obj", "3dm"),
                    pictures=False)
    assert (out / "scene.3dm").exists() and first["files"]["scene_3dm"] == "scene.3dm"
    (out / "notes.txt").write_text("the user's")
    second = run_fit(EXAMPLES / "single_seated.toml", out, formats=("ply",), pictures=False)
    listed = {v for v in second["files"].values() if isinstance(v, str)} | {
        name for v in second["files"].values() if isinstance(v, list) for name in v}
    assert sorted(p.name for p in out.iterdir()) == sorted(listed | {"report.json",
                                                                     "notes.txt"})
    assert not (out / "scene.3dm").exists() and not (out / "surface.obj").exists()
    assert json.loads((out / "report.json").read_text())["files"] == second["files"]


def test_a_fit_into_the_folder_its_scenario_came_from_keeps_the_scenario(tmp_path):
    """`sitrelax design` lists the scenario it writes among its results, and says to go on with
    `sitrelax fit`: fitting that scenario into the same folder replaced the design's results
    and removed the scenario it read. The files a fit reads stay (its control mesh too)."""
    out = tmp_path / "design"
    out.mkdir()
    scenario = (EXAMPLES / "single_seated.toml").read_text()
    grid = 'grid = { size = [0.5, 0.6], resolution = [8, 6], height = 0.42 }'
    assert grid in scenario
    run_fit(EXAMPLES / "single_seated.toml", tmp_path / "first", formats=("obj",),
            pictures=False)
    (out / "start.obj").write_bytes((tmp_path / "first" / "control.obj").read_bytes())
    (out / "scenario.toml").write_text(scenario.replace(grid, 'control_mesh = "start.obj"'))
    (out / "surface.obj").write_text("the design's")
    (out / "report.json").write_text(json.dumps(  # a design's, listing what it wrote
        {"files": {"scenario": "scenario.toml", "control_mesh": "start.obj",
                   "surface": "surface.obj"}}))
    run_fit(out / "scenario.toml", out, formats=("ply",), pictures=False)
    assert (out / "scenario.toml").read_text() == \
        scenario.replace(grid, 'control_mesh = "start.obj"')
    assert (out / "start.obj").exists()
    assert not (out / "surface.obj").exists()  # the earlier result's own file goes


def test_a_fit_that_would_write_over_its_own_control_mesh_is_refused(tmp_path):
    """A scenario whose control mesh is the folder's control.obj, fitted into that folder,
    would lose its start to the fitted net (the fit writes its own control.obj): refused
    before any work, the folder as it was."""
    out = tmp_path / "work"
    run_fit(EXAMPLES / "single_seated.toml", out, formats=("obj",), pictures=False)
    scenario = (EXAMPLES / "single_seated.toml").read_text().replace(
        'grid = { size = [0.5, 0.6], resolution = [8, 6], height = 0.42 }',
        'control_mesh = "control.obj"')
    (out / "scenario.toml").write_text(scenario)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(ValueError, match=r"control.obj is a file this fit reads"):
        run_fit(out / "scenario.toml", out, formats=("obj",), pictures=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_fit_that_fails_leaves_the_earlier_result(tmp_path):
    out = tmp_path / "out"
    run_fit(EXAMPLES / "single_seated.toml", out, formats=("obj",), pictures=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    broken = tmp_path / "broken.toml"
    broken.write_text((EXAMPLES / "single_seated.toml").read_text().replace(
        'pose = "', 'pose = "bvh:bundled:no-such-take.bvh#frame=1" # "', 1))
    with pytest.raises(Exception, match="no-such-take"):
        run_fit(broken, out, formats=("obj",), pictures=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_relaxing_onto_a_surface_out_of_reach_is_refused_and_writes_nothing(tmp_path):
    from solver.body.relax import RelaxError
    from solver.scene.run import run_relax

    fitted = tmp_path / "fitted"
    fitted.mkdir()
    (fitted / "surface.obj").write_text(  # a plate 50 m away from the sitter
        "v 50 0.4 0\nv 51 0.4 0\nv 51 0.4 -1\nv 50 0.4 -1\nf 1 2 3 4\n")
    with pytest.raises(RelaxError, match=r"entirely outside the surface's reach: its nearest "
                                          r"supported point is 4\d\.\d\d m"):
        run_relax(EXAMPLES / "single_seated.toml", tmp_path / "out", surface_dir=fitted)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("vertex, message", [
    ("v 1 0.4 nan", r"surface.obj:3: expected finite coordinates"),
    ("v 1 0.4", r"surface.obj:3: expected 'v x y z'"),
    ("v 1e300 0.4 -1", r"within 1000 m of the origin: .*surface.obj has vertex 3 at")])
def test_relaxing_onto_a_malformed_surface_file_is_refused_naming_it(tmp_path, vertex, message):
    from solver.body.relax import RelaxError
    from solver.scene.run import run_relax

    fitted = tmp_path / "fitted"
    fitted.mkdir()
    (fitted / "surface.obj").write_text(f"v 0 0.4 0\nv 1 0.4 0\n{vertex}\nv 0 0.4 -1\n"
                                        "f 1 2 3 4\n")
    with pytest.raises(RelaxError, match=message):
        run_relax(EXAMPLES / "single_seated.toml", tmp_path / "out", surface_dir=fitted)
    assert not (tmp_path / "out").exists()


def test_a_relaxation_into_a_fit_s_folder_is_refused_and_the_fit_kept(tmp_path):
    from solver.scene.run import run_relax

    out = tmp_path / "out"
    run_fit(EXAMPLES / "single_seated.toml", out, formats=("obj",), pictures=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(ValueError, match="holds a fit's results .* a folder of its own"):
        run_relax(EXAMPLES / "single_seated.toml", out, surface_dir=out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
