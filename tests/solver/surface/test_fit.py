"""The surface fit on a shape whose answer is known (a ball resting on a seat), and scenarios."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from solver.contact.settle import Foam
from solver.contact.evaluate import evaluate_person
from solver.mesh import SurfaceMesh
from solver.contact.supported import SupportedBody
from solver.surface.fit import FitError, FitParams, fit_surface
from solver.scene.scenario import ScenarioError, load_scenario, parse_scenario
from solver.surface.subdivision import grid_mesh


def _fit(ball, **kw):
    v, t, normals, areas, importance = ball
    grid_v, grid_f = grid_mesh((1.2, 0.8), (8, 6), 0.45)
    params = FitParams(**{"margin": 0.02, "max_iterations": 25, **kw})
    target = SupportedBody(v, normals, importance, "ball", t, areas, mass_kg=30.0)
    result = fit_surface(grid_v, grid_f, [target], params)
    figures, _ = evaluate_person(SurfaceMesh.from_quads(result.surface, result.surface_faces),
                                 target, params.margin, Foam(200e3))
    return grid_v, result, figures


def test_ball_is_cradled_without_being_cut(ball):
    start, result, figures = _fit(ball, sigma=0.01)
    assert figures["coverage"] > 0.9
    assert 0.0 < figures["contact_coverage"] <= figures["coverage"]
    assert figures["max_penetration_m"] <= 0.02 + 0.005
    assert result.surface[:, 1].min() < 0.45  # a bowl formed under the ball
    assert all(s in ("solved", "solved inaccurate") for s in result.qp_statuses)


def test_sigma_trades_smoothness_for_coverage(ball):
    runs = [_fit(ball, sigma=s) for s in (0.001, 0.1, 1.0)]
    laplacian = [r.energy_terms["laplacian_m2"] for _, r, _ in runs]
    coverage = [f["coverage"] for _, _, f in runs]
    assert laplacian[0] > laplacian[1] > laplacian[2]
    assert coverage[0] > coverage[1] > coverage[2]


def test_fixed_vertices_move_less_than_free_ones(ball):
    fixed = (30, 31, 32, 38, 39)  # under the ball, where the pull is strongest
    start, free_run, _ = _fit(ball, sigma=0.01)
    _, fixed_run, _ = _fit(ball, sigma=0.01, fixed=fixed, gamma=100.0)
    moved_free = np.linalg.norm(free_run.control - start, axis=1)
    moved_fixed = np.linalg.norm(fixed_run.control - start, axis=1)
    assert moved_fixed[list(fixed)].max() < 0.25 * moved_free[list(fixed)].max()


def test_points_beyond_the_pull_range_still_count_in_the_energy(ball):
    """Important points farther than pull_range do not pull, but the loop's point-to-point term
    still counts them at their nearest surface vertex (the paper's E sums every point): it can
    only exceed the mean squared distance to the nearest vertex of the final surface (the loop
    pairs before it solves), and by little."""
    from scipy.spatial import cKDTree

    v, t, normals, areas, importance = ball
    far = np.array([[0.5, 0.8, 0.3], [0.5, 0.8, 0.32]])  # 0.35 m over the grid's corner
    target = SupportedBody(np.vstack([v, far]), np.vstack([normals, [[0.0, -1.0, 0.0]] * 2]),
                        np.concatenate([importance, [1.0, 1.0]]), "ball and beyond")
    grid_v, grid_f = grid_mesh((1.2, 0.8), (8, 6), 0.45)
    params = FitParams(margin=0.02, sigma=0.01, tau_max=0.0, max_iterations=12)
    result = fit_surface(grid_v, grid_f, [target], params)
    rho = target.importance
    keep = rho > 1e-3
    # the data terms aim `sink` into the skin, along its normals
    aimed = target.vertices - params.sink * target.normals
    nearest, _ = cKDTree(result.surface).query(aimed[keep])
    independent = float(np.sum(rho[keep] * nearest ** 2) / rho[keep].sum())
    term = result.energy_terms["point_to_point_m2"]
    assert independent <= term * (1 + 1e-12) and term < 1.5 * independent  # equal: rounding


@pytest.mark.parametrize("tau_max", [0.0, 1.0])
def test_tau_extremes_converge(ball, tau_max):
    _, result, figures = _fit(ball, sigma=0.01, tau_max=tau_max, max_iterations=40)
    assert np.isfinite(result.energies).all()
    assert figures["max_penetration_m"] <= 0.025


def test_person_out_of_reach_is_named(ball):
    v, t, normals, areas, importance = ball
    grid_v, grid_f = grid_mesh()
    with pytest.raises(FitError, match="entirely outside the surface's reach"):
        fit_surface(grid_v, grid_f, [SupportedBody(v + [5.0, 0, 0], normals, importance, "ball")])


def test_a_floor_over_the_people_is_refused_at_once(ball):
    """A floor far above the supported skin (a height typed wrong) asks every surface vertex up
    through the bodies: each programme of such a fit took 5-9 s. It is refused before the fit
    starts; a floor under the skin, or over it by no more than the margin (holding the surface
    up under a body sunk into it: `test_the_floor_holds_the_surface_up`), is not."""
    v, t, normals, areas, importance = ball
    grid_v, grid_f = grid_mesh((1.2, 0.8), (8, 6), 0.45)
    body = [SupportedBody(v, normals, importance, "ball")]
    lowest = v[importance > 1e-3, 1].min()
    with pytest.raises(FitError, match=r"floor \(y = 1 m\) lies more than the margin \(0.02 "
                                       r"m\) above ball's lowest supported"):
        fit_surface(grid_v, grid_f, body, FitParams(margin=0.02, floor=1.0, max_iterations=2))
    with pytest.raises(FitError, match="more than the margin"):
        fit_surface(grid_v, grid_f, body, FitParams(margin=0.02, floor=lowest + 0.021,
                                                    max_iterations=2))
    for floor in (lowest - 0.01, lowest + 0.019):
        fit_surface(grid_v, grid_f, body, FitParams(margin=0.02, floor=floor, max_iterations=2))


SCENARIO = """
[surface]
grid = { size = [1.2, 0.8], resolution = [8, 6], height = 0.45 }
sigma = 0.1

[[person]]
pose = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
"""


@pytest.mark.parametrize("edit, message", [
    (("sigma = 0.1", "sigma = -1"), r"surface.sigma: expected a number >= 0, got -1"),
    (("sigma = 0.1", "sigma = 'high'"), r"surface.sigma: expected a number"),
    (("sigma = 0.1", "tau_max = 2"), r"surface.tau_max: expected a number <= 1"),
    (("sigma = 0.1", "fixed = [99]"), r"surface.fixed\[0\]: expected a whole number in 0..62"),
    (("sigma = 0.1", "smoothness = 1"), r"surface.smoothness: unknown field"),
    (("pose = ", "posture = "), r"person\[0\].posture: unknown field"),
    (("#frame=39\"", "#frame=39\"\nbody = { weight = 3 }"), r"person\[0\].body: .*weight"),
    (("#frame=39\"", "#frame=39\"\nsupport = ['tail']"), r"person\[0\].support"),
    (("grid = { size = [1.2, 0.8], resolution = [8, 6], height = 0.45 }",
      "control_mesh = 'missing.obj'"), r"surface.control_mesh: no such file"),
    (("sigma = 0.1", "sigmma = 0.1"),
     r"surface.sigmma: unknown field \(did you mean sigma\? expected one of \['anchor', "),
    (("pose = ", "psoe = "), r"person\[0\].psoe: unknown field \(did you mean pose\?"),
    (("sigma = 0.1", "sigma = nan"), r"s.toml: surface.sigma: expected a finite number, got nan"),
    (("sigma = 0.1", "step = inf"), r"surface.step: expected a finite number, got inf"),
    (("sigma = 0.1", "pull_range = 0"), r"surface.pull_range: expected a number > 0, got 0"),
    (("sigma = 0.1", "level = 9"), r"surface.level: expected a whole number in 1..5, got 9"),
    (("sigma = 0.1", "creases = [[0, 99]]"),
     r"surface.creases\[0\]: expected a whole number in 0..62, got 99"),
    (("#frame=39\"", "#frame=39\"\nposition = [0, 0]"),
     r"person\[0\].position: expected a list of 3 numbers, got \[0, 0\]"),
    # numbers no furniture has: refused by name, not by the solver's numerics
    (("sigma = 0.1", "sigma = 1e308"), r"surface.sigma: expected a number <= 100, got 1e\+308"),
    (("sigma = 0.1", "gamma = 1e308"), r"surface.gamma: expected a number <= 1e\+06"),
    (("size = [1.2, 0.8]", "size = [1e308, 0.8]"),
     r"surface.grid.size\[0\]: expected a number <= 1000, got 1e\+308"),
    (("height = 0.45", "height = -1e9"), r"surface.grid.height: expected a number >= -1000"),
    (("#frame=39\"", "#frame=39\"\nposition = [0, 1e300, 0]"),
     r"person\[0\].position\[1\]: expected a number <= 1000"),
])
def test_bad_scenarios_name_the_field(tmp_path, edit, message):
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.replace(*edit))
    with pytest.raises(ScenarioError, match=message):
        load_scenario(path)


def test_every_fit_parameter_is_a_scenario_field_with_the_fit_s_default():
    import dataclasses

    from solver.scene import schema

    scenario = parse_scenario({"surface": {"grid": {}}, "person": [{"pose": "db:any"}]})
    assert scenario.surface.params == FitParams()
    assert FitParams().sigma == 0.003
    for f in dataclasses.fields(FitParams):
        expected = list(f.default) if isinstance(f.default, tuple) else f.default
        assert schema.Surface.model_fields[f.name].default == expected
    set_all = {"anchor": 0.002, "pull_range": 0.3, "step": 0.04, "tolerance": 0.02,
               "max_iterations": 7, "creases": [[0, 1]], "fixed": [5], "gamma": 3.0}
    params = parse_scenario({"surface": {"grid": {}, **set_all},
                             "person": [{"pose": "db:any"}]}).surface.params
    assert params == FitParams(**{**set_all, "creases": ((0, 1),), "fixed": (5,)})


def test_a_scenario_written_as_toml_reads_back_equal(tmp_path):
    from solver.scene.scenario import scenario_toml

    data = {"surface": {"grid": {"size": [1.0, 0.5]}, "sigma": 0.01, "creases": [[0, 1]]},
            "evaluation": {"foam_stiffness": 150.0},
            "person": [{"name": "Zo\u00eb \U0001F600", "pose": "db:any",
                        "body": {"weight": 0.25}, "support": ["legs"]},
                       {"name": "tab\tquote\" back\\slash", "pose": "db:other"}]}
    path = tmp_path / "zoe.toml"
    path.write_text(scenario_toml(data), encoding="utf-8")
    import tomllib

    assert tomllib.loads(path.read_text(encoding="utf-8")) == data
    assert load_scenario(path).persons[0].name == "Zo\u00eb \U0001F600"
    with pytest.raises(ScenarioError, match="Expected numbers"):
        scenario_toml({"surface": {"sigma": None}})


def test_non_quad_control_mesh_is_refused(tmp_path):
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n")
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.replace(
        "grid = { size = [1.2, 0.8], resolution = [8, 6], height = 0.45 }",
        "control_mesh = 'tri.obj'"))
    with pytest.raises(ScenarioError, match="tri.obj:4: expected a quad control mesh"):
        load_scenario(path)


@pytest.mark.parametrize("value, message", [
    ("nan", r"quad.obj:3: expected finite coordinates, got 'v 1 0.4 nan'$"),
    ("1e308", r"quad.obj: expected vertex coordinates within 1000 m, got .* \(vertex 3\)$")])
def test_a_control_mesh_file_with_a_coordinate_out_of_bounds_is_refused(tmp_path, value,
                                                                        message):
    (tmp_path / "quad.obj").write_text(f"v 0 0.4 0\nv 1 0.4 0\nv 1 0.4 {value}\nv 0 0.4 1\n"
                                       "f 1 2 3 4\n")
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.replace(
        "grid = { size = [1.2, 0.8], resolution = [8, 6], height = 0.45 }",
        "control_mesh = 'quad.obj'"))
    with pytest.raises(ScenarioError, match=r"surface.control_mesh: .*" + message):
        load_scenario(path)


@pytest.mark.parametrize("text, message", [
    ("v 0 0.4 0\nv 0 0.4 0\nv 0 0.4 0\nv 0 0.4 0\nf 1 2 3 4\n",
     r"quad.obj: expected faces of non-zero area; face 0 has none"),
    ("v 0 0.4 0\nv 1 0.4 0\nv 1 0.4\nv 0 0.4 1\nf 1 2 3 4\n",
     r"quad.obj:3: expected 'v x y z', got 'v 1 0.4'"),
    ("v 0 0.4 0\nv 1 0.4 0\nv 1 0.4 1\nv 0 0.4 1\nf 1 2 x 4\n",
     r"quad.obj:5: expected 'f' and vertex numbers .* got 'f 1 2 x 4'"),
    ("v 0 0.4 0\nv 1 0.4 0\nv 1 0.4 1\nv 0 0.4 1\nf 0 1 2 3\n",
     r"quad.obj:5: expected 'f' and vertex numbers"),
    ("v 0 0.4 0\nv 1 0.4 0\nv 1 0.4 1\nv 0 0.4 1\nf 1 2 2 4\n",
     r"quad.obj: expected distinct vertices in every face")])
def test_a_malformed_control_mesh_file_is_refused_naming_file_and_line(tmp_path, text, message):
    """An OBJ control mesh is checked as an inline one is: a degenerate quad, a short vertex
    line or a face index that is no vertex number stops with the file (and line) named."""
    (tmp_path / "quad.obj").write_text(text)
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.replace(
        "grid = { size = [1.2, 0.8], resolution = [8, 6], height = 0.45 }",
        "control_mesh = 'quad.obj'"))
    with pytest.raises(ScenarioError, match=r"surface.control_mesh: .*" + message):
        load_scenario(path)


def test_missing_scenario_and_unknown_pose(tmp_path):
    with pytest.raises(ScenarioError, match="No scenario file"):
        load_scenario(tmp_path / "none.toml")
    scenario = parse_scenario({"surface": {"grid": {}}, "person": [{"pose": "db:nobody"}]})
    from solver.scene.placement import place_person
    from solver.body.poses import PoseSourceError

    with pytest.raises(PoseSourceError, match="needs a pose library"):
        place_person(scenario.persons[0])


@pytest.mark.parametrize("key", ["floor_stiffness", "foam_stiffness"])
def test_a_stiffness_past_any_floor_s_is_refused_by_name(key):
    """A floor or foam stiffer than 1e6 kPa per metre is refused where it is given (1e308 made
    the settle's products overflow into NaN, and the person "found no balance")."""
    from solver.scene.scenario import parse_scenario

    data = {"surface": {"grid": {}}, "evaluation": {key: 1e308},
            "person": [{"pose": "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"}]}
    with pytest.raises(ScenarioError, match=rf"s.toml: evaluation.{key}: expected a number "
                                            r"<= 1e\+06, got 1e\+308"):
        parse_scenario(data, "s.toml")


def test_a_pose_from_a_file_without_frames_says_so(tmp_path):
    from solver.body.poses import PoseSourceError, load_pose

    text = (Path(__file__).resolve().parents[3] / "capture" / "data" /
            "cmu_75_18_high_sit.bvh").read_text()
    header = text[:text.index("Frames:")]
    (tmp_path / "empty.bvh").write_text(header + "Frames: 0\nFrame Time: 0.0333333\n")
    with pytest.raises(PoseSourceError, match=r"empty.bvh has no frames"):
        load_pose(f"bvh:{tmp_path / 'empty.bvh'}#frame=0")


def test_a_pose_read_in_the_wrong_unit_says_to_check_it():
    """CMU units (0.056 m) read as metres make a 16 m skeleton: refused, naming the unit."""
    from solver.body.poses import PoseSourceError, load_pose

    with pytest.raises(PoseSourceError, match=r"frame 39: its joints span 15.\d m, more than "
                                              r"any body's 10 m: is the file's length unit"):
        load_pose("bvh:bundled:cmu_75_18_high_sit.bvh#frame=39&unit=m")


def test_a_fit_that_cannot_pose_its_people_leaves_no_results_folder(tmp_path, capsys):
    from solver.cli import main

    scenario = tmp_path / "bad.toml"
    scenario.write_text(SCENARIO.replace("#frame=39", "#frame=9999"))
    out = tmp_path / "new" / "out"
    assert main(["fit", str(scenario), "--out", str(out)]) == 2
    assert "Expected a frame in 0..76" in capsys.readouterr().err
    assert not out.exists() and not out.parent.exists()  # nor the parent made for it
    kept = tmp_path / "kept"  # a folder that was there before stays, with what it held
    kept.mkdir()
    (kept / "notes.txt").write_text("mine")
    assert main(["fit", str(scenario), "--out", str(kept)]) == 2
    assert (kept / "notes.txt").read_text() == "mine"


@pytest.mark.slow  # the default run stays within its time
def test_fit_command_writes_files_that_open_again(tmp_path):
    import json

    import trimesh

    from solver.cli import main

    scenario = tmp_path / "ball.toml"
    scenario.write_text(SCENARIO)
    out = tmp_path / "out"
    assert main(["fit", str(scenario), "--out", str(out), "--json"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert {"iterations", "stop_reason", "timing", "persons", "parameters"} <= set(report)
    assert report["timing"]["total_s"] > 0
    person = report["persons"][0]
    for key in ("coverage", "contact_coverage", "max_penetration_m", "contact_area_m2", "peak_pressure_kpa",
                "mean_pressure_kpa", "flat"):
        assert key in person
    assert {"coverage", "peak_pressure_kpa"} <= set(person["flat"])
    assert person["support_inside_others"] == 0.0  # alone in the scene
    control = trimesh.load(out / "control.obj", process=False)
    text = (out / "control.obj").read_text().splitlines()
    faces = [line for line in text if line.startswith("f ")]
    assert len(faces) == 48 and all(len(f.split()) == 5 for f in faces)  # all quads
    assert len(control.vertices) == report["control_vertices"] == 63
    for name in ("surface.obj", "surface.ply", "surface.glb"):
        mesh = trimesh.load(out / name, process=False, force="mesh")
        assert len(mesh.vertices) == report["surface_vertices"]
        assert len(mesh.faces) in (3072, 2 * 3072)  # quads, or quads as triangle pairs
    guarantees = report["guarantees"]  # of the surface that surface.obj holds
    assert {"self_intersections", "max_fold_deg", "folds", "below_floor", "ok",
            "max_penetration_dense_m"} <= set(guarantees)
    limit = trimesh.load(out / "surface.obj", process=False, force="mesh").vertices
    assert guarantees["min_height_m"] == pytest.approx(limit[:, 1].min(), abs=1e-6)
    assert report["files"]["bodies"] == ["person_1.ply"]
    assert report["files"]["bodies_obj"] == ["person_1.obj"]
    body = trimesh.load(out / "person_1.ply", process=False)
    assert len(body.vertices) == 13380 and len(body.faces) == 2 * 13378
    same = trimesh.load(out / "person_1.obj", process=False)
    assert np.allclose(same.vertices, body.vertices, atol=1e-5)
    assert report["pictures"] is True
    assert (out / "scene.png").stat().st_size > 10_000
    assert (out / "pressure.png").stat().st_size > 10_000
    assert (out / "pressure_map.png").stat().st_size > 10_000
    from solver.contact.mat import read_pressure_csv

    maps = read_pressure_csv(out / "pressure_map.csv")
    assert maps and all(np.isfinite(m).all() and m.max() > 0 for m in maps.values())


def test_fit_without_pictures_writes_no_png_and_says_so(tmp_path, capsys):
    import json

    from solver.cli import main

    scenario = tmp_path / "ball.toml"
    # a short fit: the pictures are what is tested
    scenario.write_text(SCENARIO.replace("sigma = 0.1", "sigma = 0.1\nlevel = 2\n"
                                                        "max_iterations = 3"))
    out = tmp_path / "out"
    assert main(["fit", str(scenario), "--out", str(out), "--no-pictures",
                 "--format", "obj"]) == 0
    assert "pictures skipped: --no-pictures" in capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    assert report["pictures"] is False
    assert list(out.glob("*.png")) == []
    assert not any(key.endswith("_png") for key in report["files"])


EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"


# The seated examples support a seat (pelvis and thighs); each grid's front edge ends 3 cm short
# of the calves' skin (the person placed so), and the fit's rim rows keep it from advancing over
# them. facing_pair's one surface runs on under both people's calves (the lid rows keep it off
# the south person's since 44cc48e), and its north person tips back: its calves lie in the
# surface's foam and press it back (alone on the same long grid it tips too; on single_seated's
# grid, which ends before the calves, the same body and pose rests). Measured after the rim rows
# and the knee crease; a strict xfail fails the run once its example meets the bar.
NO_REST = "tips back: the one surface runs on under its calves, which press it back"
_EXAMPLE_MARKS = {
    "facing_pair": {"rest": NO_REST},
}
# the people of each example, and those a bar's mark is for (all when not named): each person
# is a test of the rest bar of its own, so that one who misses it does not hide the others
_PEOPLE = {"single_seated": 1, "reclining": 1, "facing_pair": 2, "seat_for_thin": 1,
           "seat_for_heavy": 1, "six_overlapping": 6}
_MARKED_PEOPLE = {("facing_pair", "rest"): (0,)}  # north
_REPORTS: dict = {}


def _example_report(name: str, tmp_path_factory) -> dict:
    """run_fit's report of an example, computed once for both of its tests."""
    from solver.scene.run import run_fit

    if name not in _REPORTS:
        out = tmp_path_factory.mktemp(name)
        _REPORTS[name] = {**run_fit(EXAMPLES / f"{name}.toml", out), "out": str(out)}
    return _REPORTS[name]


def _examples(bar: str) -> list:
    """single_seated is the default run's smoke test; the other examples run under `-m slow`.
    An example known to miss the bar is a strict xfail: passing it fails the run, so the mark
    goes when the example meets the bar again."""
    params = []
    for name in ("single_seated", "reclining", "facing_pair", "seat_for_thin", "seat_for_heavy",
                 "six_overlapping"):
        marks = [] if name == "single_seated" else [pytest.mark.slow]
        reason = _EXAMPLE_MARKS.get(name, {}).get(bar)
        if reason:
            marks.append(pytest.mark.xfail(strict=True, reason=reason))
        params.append(pytest.param(name, marks=marks))
    return params


@pytest.mark.parametrize("name", _examples("energy"))
def test_example_fits_never_raise_their_judged_energy(name, tmp_path_factory):
    """From one accepted iterate to the next the judged energy never rises by more than 1 %
    (it may not rise at all; the 1 % is the bar), in the fit's loop and in each round of rows
    on dense samples after it; and every example's surface comes out without a fold or a
    crossing (the loop's guards)."""
    report = _example_report(name, tmp_path_factory)
    runs = [report["energies"]] + [r["energies"] for r in report["energy_terms"]["repairs"]]
    for energies in runs:
        e = np.asarray(energies)
        assert np.all(e[1:] <= e[:-1] * 1.01), e
    assert len(report["energies"]) >= 3
    g = report["guarantees"]
    assert g["folds"] == 0 and g["self_intersections"] == 0 and not g["below_floor"], g


@pytest.mark.parametrize("name", _examples("surface"))
def test_example_surfaces_meet_the_bar(name, tmp_path_factory):
    """Within-margin coverage at least 0.95 and contact coverage (within 5 mm) at least 0.8 of
    the supported importance, no cut deeper than the margin plus 5 mm, at most 2 % of a
    person's support inside another body; the fit's judged energy never rose from one accepted
    iterate to the next; the exported surface is furniture by libraries other than ours
    (`_check_exported_surface`)."""
    report = _example_report(name, tmp_path_factory)
    margin = report["parameters"]["margin"]
    energies = np.asarray(report["energies"])
    assert np.all(energies[1:] <= energies[:-1] * 1.01), energies
    for person in report["persons"]:
        assert person["support_inside_others"] <= 0.02, person
        assert person["coverage"] >= 0.95, person
        assert person["contact_coverage"] >= 0.8, person
        assert person["max_penetration_m"] <= margin + 0.005, person
    _check_exported_surface(Path(report["out"]), report)


def _example_people(bar: str) -> list:
    """(example, person index) for each person of `_examples`, marked as their example is,
    but a mark named for some people (`_MARKED_PEOPLE`) only on those."""
    params = []
    for param in _examples(bar):
        name = param.values[0]
        marked = _MARKED_PEOPLE.get((name, bar))
        for k in range(_PEOPLE[name]):
            marks = [m for m in param.marks
                     if marked is None or k in marked or m.name != "xfail"]
            params.append(pytest.param(name, k, marks=marks, id=f"{name}-{k}"))
    return params


@pytest.mark.parametrize("name, index", _example_people("rest"))
def test_example_people_rest_on_their_surfaces(name, index, tmp_path_factory):
    """The body at rest on the surface (and the floor) in equilibrium (on a flat seat at the
    same height most of these poses tip over, which the report says; the flat seat held at the
    fitted seat's load carries a good part of the weight), with the peak on a region the person
    asks support for; at least 60 % of the load on the pelvis and thighs, under 10 % on the
    calves. One test per person."""
    report = _example_report(name, tmp_path_factory)
    assert len(report["persons"]) == _PEOPLE[name]
    person = report["persons"][index]
    balance = person["equilibrium"]
    assert balance["stable"], person
    assert balance["net_force_n"] <= 0.01 * balance["weight_n"], person
    assert balance["net_moment_nm"] <= 1.0, person
    flat = person["flat"]
    assert flat["supported"] == flat["equilibrium"]["stable"]
    if not flat["supported"]:
        assert flat["peak_pressure_kpa"] is None and flat["equilibrium"]["reason"], person
    same = flat["same_load"]  # the flat seat at the seat's load, held as the body rests
    assert 0.3 < same["load_share"] <= 1.01 and same["peak_pressure_kpa"] > 0, same
    # the surface's peak on the regions the flat seat carries, whichever part presses them
    assert same["regions"] and set(same["regions"]) <= {"pelvis", "thighs"}, same
    # its load: the seat's, and what the steeper parts put on those regions, by the mat's own
    # path (the seat part's figures, and the other parts' by region)
    supports = person["mat"]["supports"]
    steeper = sum(max(sum(f["vertical_load_n"] for region, f in figures["regions"].items()
                          if region in same["regions"]), 0.0)
                  for part, figures in supports.items() if part not in ("seat", "floor"))
    assert same["load_n"] == pytest.approx(supports["seat"]["vertical_load_n"] + steeper,
                                           rel=1e-6, abs=1e-6)
    held = [f["peak_kpa"] for part, figures in person["mat"]["supports"].items()
            if part != "floor" for region, f in figures["regions"].items()
            if region in same["regions"]]
    assert same["fitted_peak_kpa"] == pytest.approx(max(held), rel=1e-9)
    assert person["peak_of_flat"] == pytest.approx(same["fitted_peak_kpa"] /
                                                   same["peak_pressure_kpa"])
    on_surface = {region: f for support, figures in person["mat"]["supports"].items()
                  if support != "floor" for region, f in figures["regions"].items()}
    peak_region = max(on_surface, key=lambda r: on_surface[r]["peak_kpa"])
    assert peak_region in person["support"], (peak_region, person["support"])
    if name == "reclining":
        return
    # seated: the load where anatomy needs it, most on the pelvis and thighs, little on
    # the calves
    regions = person["mat"]["total"]["regions"]
    share = {r: regions.get(r, {}).get("load_share", 0.0) for r in ("pelvis", "thighs",
                                                                      "calves")}
    assert share["pelvis"] + share["thighs"] >= 0.6 and share["calves"] < 0.1, share


@pytest.mark.xfail(strict=True, reason="the feet barely touch the floor: it carries 2 % of the "
                   "weight (published: about a fifth), the seat 90 %")
def test_single_seated_puts_a_fifth_of_the_weight_on_the_floor(tmp_path_factory):
    """Seated with the feet on the floor, the floor carries 10-30 % of the weight (19 % in an
    upright posture, Collins 2001; 20-30 % across three postures, Mbada et al. 2016)."""
    report = _example_report("single_seated", tmp_path_factory)
    supports = report["persons"][0]["equilibrium"]["supports"]
    assert supports["seat"]["load_share"] >= 0.5, supports
    assert 0.1 <= supports["floor"]["load_share"] <= 0.3, supports


def _check_exported_surface(out: Path, report: dict) -> None:
    """surface.obj (the limit surface) judged by CGAL (through libigl), trimesh and libigl's
    winding numbers: no pair of its triangles crosses, neighbouring faces within 60 degrees, at
    or above the floor, and no point of it (15 samples a triangle) deeper in a body than the
    margin plus 1 mm."""
    import igl
    import igl.copyleft.cgal as cgal

    surface = trimesh.load(out / "surface.obj", process=False)
    v, f = np.asarray(surface.vertices, dtype=np.float64), np.asarray(surface.faces)
    crossing = cgal.remesh_self_intersections(v, f.astype(np.int64), detect_only=True)[2]
    assert len(crossing) == 0, f"{len(crossing)} crossing triangle pairs"
    # neighbouring triangles of one quad are nearly coplanar; across quads the fold shows
    assert np.degrees(surface.face_adjacency_angles.max()) <= 60.0
    if report["parameters"]["floor"] is not None:
        assert v[:, 1].min() >= report["parameters"]["floor"] - 1e-3
    a, b = np.meshgrid(np.arange(5), np.arange(5), indexing="ij")
    keep = a + b <= 4
    bary = np.stack([4 - a[keep] - b[keep], a[keep], b[keep]], axis=1) / 4.0
    samples = np.einsum("sk,fkd->fsd", bary, v[f]).reshape(-1, 3)
    margin = report["parameters"]["margin"]
    for k in range(len(report["persons"])):
        body = trimesh.load(out / f"person_{k + 1}.obj", process=False)
        bv, bt = np.asarray(body.vertices, dtype=np.float64), np.asarray(body.faces, np.int64)
        inside = samples[igl.fast_winding_number(bv, bt, samples) > 0.5]
        if len(inside):
            depth = np.sqrt(igl.point_mesh_squared_distance(inside, bv, bt)[0].max())
            assert depth <= margin + 1e-3, depth


def test_support_inside_other_bodies_is_the_share_of_importance_they_contain():
    """A unit cube's corners against a box that holds the four at x = +0.5: half its support
    (uniform importance) lies inside the other body; one corner weighted 5x moves it to 8/12 when
    it is among them; a box elsewhere holds nothing."""
    from solver.contact.evaluate import support_inside

    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    v = np.asarray(cube.vertices)
    holder = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    hv, ht = np.asarray(holder.vertices) + [1.0, 0.0, 0.0], np.asarray(holder.faces)
    uniform = np.ones(len(v))
    assert support_inside(v, uniform, [(hv, ht)]) == pytest.approx(0.5)
    heavy = uniform.copy()
    heavy[np.flatnonzero(v[:, 0] > 0)[0]] = 5.0
    assert support_inside(v, heavy, [(hv, ht)]) == pytest.approx(8.0 / 12.0)
    assert support_inside(v, uniform, [(hv + [10.0, 0.0, 0.0], ht)]) == 0.0
    assert support_inside(v, np.zeros(len(v)), [(hv, ht)]) == 0.0


@pytest.mark.slow  # the default run stays within its time
def test_the_floor_holds_the_surface_up(ball):
    # the ball's bottom is at 0.42 m: without a floor the bowl under it goes below 0.44 m
    v, t, normals, areas, importance = ball
    grid_v, grid_f = grid_mesh((1.2, 0.8), (8, 6), 0.45)
    target = SupportedBody(v, normals, importance, "ball", t, areas, mass_kg=30.0)
    low = [fit_surface(grid_v, grid_f, [target], FitParams(
        level=2, margin=0.02, sigma=0.01, max_iterations=8, floor=floor)).surface[:, 1].min()
        for floor in (None, 0.44)]
    assert low[0] < 0.435
    assert low[1] >= 0.44 - 1e-3


def test_a_control_mesh_facing_away_from_the_body_stops_and_says_to_flip_it(ball):
    """The same grid with every face's vertex order reversed faces down, away from the ball
    resting on it: the fit stops with a message that says so, instead of fitting badly."""
    v, t, normals, areas, importance = ball
    grid_v, grid_f = grid_mesh((1.2, 0.8), (8, 6), 0.45)
    target = SupportedBody(v, normals, importance, "ball", t, areas, mass_kg=30.0)
    params = FitParams(margin=0.02, max_iterations=2, level=2)
    fit_surface(grid_v, grid_f, [target], params)  # faces up: fits
    with pytest.raises(FitError, match="flip"):
        fit_surface(grid_v, grid_f[:, ::-1], [target], params)
