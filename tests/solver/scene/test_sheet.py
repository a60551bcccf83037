"""A fit's design sheet: the posture of a placed person, the sheet's lines, and sheet.png from
`sitrelax fit`."""

import json
from pathlib import Path

import pytest

from solver.scene.quality import person_misses
from solver.scene.sheet import sheet_lines

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"
GUARANTEES = {"self_intersections": 0, "max_fold_deg": 72.0, "folds": 2, "min_height_m": 0.3,
              "below_floor": False, "max_penetration_dense_m": 0.02, "margin_m": 0.03,
              "floor_m": 0.0, "ok": False}


def _scenario_person(rotation):
    from solver.scene.placement import place_person
    from solver.scene.scenario import parse_scenario

    data = {"surface": {"grid": {}}, "person": [{
        "pose": "bvh:bundled:cmu_75_17_medium_sit.bvh#frame=200", "rotation_deg": rotation,
        "position": [0.0, 0.5, 0.0]}]}
    return place_person(parse_scenario(data, "test").persons[0])


@pytest.mark.parametrize("rotation, posture", [([0.0, 0.0, 0.0], "seated"),
                                               ([-35.0, 0.0, 0.0], "reclined"),
                                               ([0.0, 90.0, 0.0], "seated")])
def test_the_posture_is_read_as_the_scene_holds_the_person(rotation, posture):
    """Raised half a metre and turned about the vertical, a seated pose stays seated; turned 35
    degrees back, it reclines."""
    from solver.scene.placement import scene_posture

    assert scene_posture(_scenario_person(rotation)) == posture


def test_the_sheet_says_the_figures_and_one_line_of_misses_a_person():
    person = {"name": "sitter (x.bvh frame 1)", "posture": "seated", "support": ["pelvis"],
              "coverage": 0.5, "contact_coverage": 0.4, "peak_pressure_kpa": None,
              "peak_region": None, "mat": None,
              "equilibrium": {"stable": False, "reason": "tips over"}}
    report = {"guarantees": GUARANTEES, "persons": [person], "timing": {"fit_s": 1.25},
              "iterations": 7}
    notes, problems = sheet_lines(report)
    assert "2 folds" in notes[0] and "72 deg" in notes[0] and "1.2 s, 7 iterations" in notes[0]
    assert notes[1].startswith("sitter (x.bvh frame 1), seated, supported: pelvis")
    assert problems[0].startswith("2 folds: neighbouring faces up to 72 degrees")
    assert len(problems) == 2 and problems[1].startswith("sitter: coverage 0.50")
    assert len(person_misses(person)) == 3 and problems[1].count(";") == 2


@pytest.mark.slow
def test_fit_writes_the_design_sheet(tmp_path):
    """A short fit of the chair example: sheet.png beside scene.png, in the report's files;
    each person's posture and peak region in the report."""
    from solver.body.model import BODY_REGIONS
    from solver.scene.run import run_fit

    text = (EXAMPLES / "template_chair.toml").read_text().replace(
        "margin = 0.03", "margin = 0.03\nmax_iterations = 2")
    scenario = tmp_path / "chair.toml"
    scenario.write_text(text)
    report = run_fit(scenario, tmp_path / "out", formats=("obj",))
    assert report["files"]["sheet_png"] == "sheet.png"
    assert (tmp_path / "out" / "sheet.png").stat().st_size > 50_000
    assert json.loads((tmp_path / "out" / "report.json").read_text())["files"]["sheet_png"]
    person = report["persons"][0]
    assert person["posture"] == "seated"
    assert person["peak_region"] in BODY_REGIONS
