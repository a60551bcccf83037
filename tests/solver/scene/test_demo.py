"""`sitrelax demo` end to end: every file it promises, and figures that mean something."""

import json

import numpy as np
import pytest
import trimesh

from posedb import PoseLibrary
from solver.cli import main


@pytest.mark.slow
def test_demo_makes_everything(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)

    # the library holds both recorded takes and the accepted poses, tagged
    lib = PoseLibrary(out / "poses.h5")
    takes = {t.name: t for t in lib.takes()}
    assert set(takes) == {"standing", "sitting"}
    assert takes["sitting"].frames == 77 and takes["sitting"].kind == "stream"
    assert summary["takes"]["sitting"]["dropped"] == 0
    seated = lib.search_poses("sit and demo")
    assert seated and seated == summary["takes"]["sitting"]["poses"]

    # the fit's outputs open again, with the counts the report and the meshes imply
    fit = json.loads((out / "fit" / "report.json").read_text())
    assert len(fit["persons"]) == 2
    control = trimesh.load(out / "fit" / "control.obj", process=False)
    surface = trimesh.load(out / "fit" / "surface.obj", process=False)
    # the bench template: a regular grid of 16 x 12 quads (seat, waterfall front and back),
    # level 3
    assert fit["parameters"]["template"]["front_drop"] == 0.08
    assert len(control.vertices) == fit["control_vertices"] == 17 * 13
    assert len(surface.vertices) == fit["surface_vertices"] == (16 * 8 + 1) * (12 * 8 + 1)
    # the waterfall front keeps the peak off the slighter person's calves (a straight front
    # put 16.7 kPa there)
    assert all(p["peak_region"] not in (None, "calves") for p in fit["persons"])
    for k in (1, 2):
        body = trimesh.load(out / "fit" / f"person_{k}.ply", process=False)
        assert len(body.vertices) == 13380
    for name in ("surface.ply", "surface.glb", "scene.png", "pressure.png"):
        assert (out / "fit" / name).stat().st_size > 10_000
    # relaxation: a mesh and a BVH a person, and the before/after report
    relax = json.loads((out / "relax" / "report.json").read_text())
    for k in (1, 2):
        assert (out / "relax" / f"person_{k}_relaxed.bvh").stat().st_size > 1000
        mesh = trimesh.load(out / "relax" / f"person_{k}_relaxed.obj", process=False)
        assert len(mesh.vertices) == 13380
    assert (out / "relax" / "relax.png").stat().st_size > 10_000

    # the figures: both supported, neither cut deeper than the margin plus 5 mm, and the fitted
    # surface presses less than a flat seat at its height where that carries them at all
    masses = []
    for person, relaxed, fitted in zip(summary["persons"], relax["persons"], fit["persons"]):
        assert person["coverage"] >= 0.9
        assert person["max_penetration_m"] <= 0.035
        # the fitted surface carries the body; a flat seat without a back may let it tip over
        assert person["peak_pressure_kpa"] is not None
        assert (person["flat_peak_pressure_kpa"] is None
                or person["peak_pressure_kpa"] < person["flat_peak_pressure_kpa"])
        assert relaxed["after"] == person["relaxed"]
        # the summary's flat seat is the baseline the bars use, the flat seat at the same load
        assert person["flat"].startswith(f"{fitted['flat']['same_load']['peak_pressure_kpa']:.1f}"
                                         " kPa at the same load"), person["flat"]
        # and --json gives the same flat seat, with the ratio the bars judge
        assert person["flat_peak_pressure_kpa"] == fitted["flat"]["same_load"]["peak_pressure_kpa"]
        assert person["peak_of_flat"] == fitted["peak_of_flat"]
        masses.append(person["mass_kg"])
    assert masses[1] > masses[0] + 10  # two different builds
    assert np.isclose(summary["timing"]["total_s"], sum(
        v for k, v in summary["timing"].items() if k != "total_s"), rtol=0.05)


# The demo's own scene, cut to one slight person on a coarser seat, and a shorter standing
# stream: every stage of `sitrelax demo` in a few seconds (the default run's smoke test).
QUICK_SCENARIO = """\
[surface]
grid = {{ size = [0.6, 0.6], resolution = [6, 4], height = 0.42 }}
level = 2
sigma = 0.003
tau_max = 0.5
margin = 0.03

[[person]]
name = "slight"
pose = "db:{pose}"
body = {{ gender = 0.2, weight = 0.3, height = 0.4 }}
position = [0.0, 0.0, -0.1]
support = "seat"
"""


@pytest.mark.slow  # the default run stays within its time
def test_the_demo_command_runs_every_stage_on_a_smaller_scene(tmp_path, capsys, monkeypatch):
    from solver.scene import demo

    monkeypatch.setattr(demo, "STANDING_SECONDS", 0.5)
    monkeypatch.setattr(demo, "SCENARIO", QUICK_SCENARIO)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    lib = PoseLibrary(out / "poses.h5")
    takes = {t.name: t for t in lib.takes()}
    assert set(takes) == {"standing", "sitting"}
    assert takes["sitting"].frames == 77 and summary["takes"]["sitting"]["dropped"] == 0
    assert lib.search_poses("sit and demo") == summary["takes"]["sitting"]["poses"]
    for made in ("fit/report.json", "fit/surface.obj", "fit/person_1.ply",
                 "relax/report.json", "relax/person_1_relaxed.bvh", "relax/relax.png"):
        assert (out / made).stat().st_size > 0, made
    (person,) = summary["persons"]
    assert person["coverage"] > 0.5 and person["relaxed"]["coverage"] > 0.5
    # a second run into the same folder is refused
    assert main(["demo", "--out", str(out)]) != 0


def test_the_demo_refuses_a_folder_that_holds_files(tmp_path):
    from solver.scene.demo import DemoError, run_demo

    (tmp_path / "scenario.toml").write_text("a designer's")
    with pytest.raises(DemoError, match="is not empty: give the demo an empty or new folder"):
        run_demo(tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["scenario.toml"]
