"""Every example scenario's fitted surface thickened (slow: six fits), and `sitrelax fit` with
the workshop options end to end."""

import json
from pathlib import Path

import ezdxf
import numpy as np
import pytest
import trimesh

from solver.io.reach import cutter_reach
from solver.io.solid import THICKNESS_TOLERANCE, check_solid, thicken, write_stl

from .conftest import underside_distances

SCENARIOS = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"
EXAMPLES = sorted(p.stem for p in SCENARIOS.glob("*.toml"))
THIN = 0.01  # m: a shell thinner than every example's ridges are wide (1.5 cm or more)
WORKSHOP = 0.03  # m: the workshop's slab, trimmed under the ridges


@pytest.fixture(scope="module")
def fitted():
    """Each example's limit surface (what `surface.*` and the solid are made of)."""
    from solver.scene.placement import place_scene
    from solver.scene.run import fit_people
    from solver.scene.scenario import load_scenario
    from solver.surface.limit import limit_of_level

    surfaces = {}
    for name in EXAMPLES:
        scenario, people = place_scene(load_scenario(SCENARIOS / f"{name}.toml"))
        result = fit_people(scenario, people)
        limit = limit_of_level(result.subdivision, result.surface,
                               list(scenario.surface.params.creases) or None)
        surfaces[name] = (limit, result.surface_faces)
    return surfaces


@pytest.mark.slow
@pytest.mark.parametrize("name", EXAMPLES)
@pytest.mark.parametrize("thickness", [THIN, WORKSHOP])
def test_every_example_thickens_to_a_closed_manifold(fitted, name, thickness, tmp_path):
    """The 1 cm and the 3 cm solid of every example's surface: watertight and consistently
    wound by trimesh, a manifold by manifold3d, no crossing triangles, as thick as asked
    within 0.1 mm at every vertex of its underside, and within 1 mm at its triangles'
    middles (trimesh's distances; a flat triangle of the offset is a chord of a curved
    sheet), and still closed when its STL is read back."""
    vertices, faces = fitted[name]
    solid = thicken(vertices, faces, thickness, check=False)
    check = check_solid(solid)
    mesh = trimesh.Trimesh(solid.vertices, solid.triangles, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert check.manifold_status == "NoError" and check.volume_m3 > 0
    assert check.ok, check.problem()
    assert check.intersecting_pairs == 0
    assert abs(check.thickness_min_m - thickness) <= THICKNESS_TOLERANCE
    assert abs(check.thickness_max_m - thickness) <= THICKNESS_TOLERANCE
    at_vertices, at_middles = underside_distances(solid)
    assert np.all(np.abs(at_vertices - thickness) <= THICKNESS_TOLERANCE), \
        (at_vertices.min(), at_vertices.max())
    assert np.all(np.abs(at_middles - thickness) <= 1e-3), \
        (at_middles.min(), at_middles.max())
    reach = cutter_reach(vertices, faces, 0.02)
    assert reach.min_concave_radius_m > 0
    write_stl(tmp_path / "solid.stl", solid)  # single precision, millimetres
    assert trimesh.load(tmp_path / "solid.stl").is_watertight


@pytest.mark.slow
def test_fit_writes_solid_reach_and_drawings(tmp_path):
    from studio.cli import main

    out = tmp_path / "fit"
    code = main(["fit", str(SCENARIOS / "single_seated.toml"), "--out", str(out),
                 "--format", "obj,3dm", "--solid", str(WORKSHOP), "--drawings",
                 "--tool-radius", "0.02"])
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    files, fab = report["files"], report["fabrication"]
    for key in ("solid_stl", "solid_3mf", "reach_png", "overall_dxf", "sections_png"):
        assert (out / files[key]).exists()
    assert files["section_dxf"] == ["section_1_sagittal.dxf", "section_1_transverse.dxf"]
    assert fab["solid"]["ok"] and fab["solid"]["watertight"]
    assert abs(fab["solid"]["thickness_min_m"] - WORKSHOP) <= THICKNESS_TOLERANCE
    assert abs(fab["solid"]["thickness_max_m"] - WORKSHOP) <= THICKNESS_TOLERANCE
    assert (out / files["scene_3dm"]).exists()
    surface = trimesh.load(out / "surface.obj", process=False).vertices
    solid = trimesh.load(out / "solid.stl")  # (millimetres, Z up)
    assert solid.is_watertight
    # the drawing dimensions what the workshop makes, the solid, as the STL has it
    doc = ezdxf.readfile(out / "overall.dxf")
    measured = sorted(d.get_measurement() for d in doc.modelspace().query("DIMENSION"))
    box = np.ptp(solid.vertices, axis=0)
    assert measured == pytest.approx(sorted([box[0], box[1], solid.bounds[1][2]]), abs=0.01)
    assert fab["dimensions_of"] == "solid"
    assert fab["dimensions_mm"]["depth_mm"] == pytest.approx(box[1], abs=0.01)
    section = ezdxf.readfile(out / "section_1_sagittal.dxf").modelspace()
    assert len(section.query("LWPOLYLINE[layer=='BODY']")) >= 1
    assert len(section.query("DIMENSION")) == 2
    # the surface is the solid's top face; where it overhangs (a rim curled over), its offset
    # may reach above it, by less than the thickness
    top = surface[:, 1].max() * 1000
    assert top - 0.01 <= solid.bounds[1][2] <= top + WORKSHOP * 1000


@pytest.mark.slow
def test_fit_refuses_a_solid_that_folds(tmp_path, capsys, monkeypatch):
    """A 6 cm offset of single_seated's surface made without trimming (each vertex moved along
    its normal: under the seat's 1.5 cm ridges it folds over itself) is judged by the checks,
    refused, not written, and named in the report; the command exits 1. (Trimmed, the same
    6 cm solid is sound and written.)"""
    import functools

    import solver.scene.workshop as workshop
    from studio.cli import main

    monkeypatch.setattr(workshop, "thicken", functools.partial(thicken, trim=False))
    out = tmp_path / "fit"
    code = main(["fit", str(SCENARIOS / "single_seated.toml"), "--out", str(out),
                 "--solid", "0.06"])
    assert code == 1
    assert "solid NOT written" in capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    solid = report["fabrication"]["solid"]
    assert not solid["ok"] and solid["folded_faces"] + solid["too_close"] > 0
    assert "fold" in solid["problem"] or "within" in solid["problem"]
    assert "solid_stl" not in report["files"] and not (out / "solid.stl").exists()
