"""`sitrelax design`: the posture of every bundled pose named right, the template chosen for
one and for several people, clear refusals, and a whole design fitted through run_fit."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from capture import Motion, write_bvh

from solver.body.model import make_body
from solver.body.posture import PostureError, posture_figures
from solver.body.poses import load_pose, retarget_captured
from solver.body.rig import pose_channels, rig_skeleton
from solver.scene.design import DesignError, design_scenario, pose_posture
from solver.scene.scenario import load_scenario, parse_scenario
from solver.surface.templates import TEMPLATE_PARAMS

HIGH = "bvh:bundled:cmu_75_18_high_sit.bvh#frame={}"
MEDIUM = "bvh:bundled:cmu_75_17_medium_sit.bvh#frame={}"
FLOOR = "bvh:bundled:cmu_82_05_floor_sit_excerpt.bvh#frame={}"
STANDING = "bvh:bundled:axis_neuron_standing_yxz.bvh#frame={}"


def _turned(tmp_path, pose: str, degrees: float, name: str) -> str:
    """A one-frame rig BVH of a bundled pose turned about x (negative: leaning back), made
    here: the bundled recordings hold no reclined or lying frame."""
    body = make_body()
    motion = retarget_captured(load_pose(pose), body)
    turn = Rotation.from_euler("x", degrees, degrees=True).as_matrix()
    local = motion.local_rotmats[0].copy()
    local[0] = turn @ local[0]
    skeleton, _ = rig_skeleton(body)
    path = tmp_path / f"{name}.bvh"
    write_bvh(path, skeleton, Motion(pose_channels(body, local, turn @ motion.root_positions[0])
                                     [None], 1 / 30))
    return f"bvh:{path}#frame=0"


@pytest.mark.parametrize("pose, posture", [
    (HIGH.format(25), "seated"), (HIGH.format(39), "seated"), (HIGH.format(45), "seated"),
    (MEDIUM.format(140), "seated"), (MEDIUM.format(200), "seated"),
    (MEDIUM.format(225), "seated"),
    (FLOOR.format(1), "floor"), (FLOOR.format(8), "floor"), (FLOOR.format(15), "floor"),
    (STANDING.format(0), "standing"), (STANDING.format(1500), "standing"),
    (HIGH.format(0), "standing"), (HIGH.format(70), "standing"), (MEDIUM.format(320), "standing"),
])
def test_every_bundled_pose_is_named_right(pose, posture):
    assert pose_posture(pose)[0] == posture


def test_reclined_and_lying_poses_are_named_right(tmp_path):
    reclined = _turned(tmp_path, MEDIUM.format(200), -35.0, "reclined")
    lying = _turned(tmp_path, STANDING.format(0), -90.0, "lying")
    prone = _turned(tmp_path, STANDING.format(0), 90.0, "prone")
    assert pose_posture(reclined)[0] == "reclined"
    assert pose_posture(lying)[0] == "lying"
    assert pose_posture(prone)[0] == "lying"
    figures = pose_posture(reclined)[1]
    assert figures.trunk_angle_deg == pytest.approx(35.0, abs=8.0)  # it leans back


def test_posture_figures_need_the_joints():
    with pytest.raises(PostureError, match=r"Expected positions of shape \(2, 3\), got \(3,\)"):
        posture_figures(np.zeros(3), ["Hips", "Neck"])
    with pytest.raises(PostureError, match=r"missing \['LeftUpLeg'"):
        posture_figures(np.zeros((2, 3)), ["Hips", "Neck"])


def test_a_held_sitter_leans_behind_the_ankles_a_rising_one_ahead():
    """The centre of mass against the ankles: behind them on every held sitting frame (a
    sitter leaning 22-35 degrees forward to rise included), ahead once the feet carry the body
    (measured 2026-12-07: sitting frames 2-19 cm behind, rising frames 1-12 cm ahead)."""
    for pose in (HIGH.format(21), HIGH.format(39), HIGH.format(51), MEDIUM.format(105),
                 MEDIUM.format(200)):
        reading = pose_posture(pose)
        assert reading.posture == "seated" and reading.ahead_of_ankles_m < -0.02, pose
    for pose in (HIGH.format(18), HIGH.format(57), MEDIUM.format(255), MEDIUM.format(285)):
        assert pose_posture(pose).ahead_of_ankles_m > 0.005, pose
    # and a design under a held frame keeps the figure
    _, decided = design_scenario([HIGH.format(39)])
    assert decided["figures"][0]["ahead_of_ankles_m"] == pytest.approx(-0.187, abs=0.01)


def test_one_sitter_gets_a_chair_two_a_bench_side_by_side():
    data, decided = design_scenario([HIGH.format(39)])
    assert decided["template"] == "chair" and decided["postures"] == ["seated"]
    assert data["surface"]["template"]["back"] is True
    data, decided = design_scenario([HIGH.format(39), MEDIUM.format(200)])
    assert decided["template"] == "bench"
    template = data["surface"]["template"]
    assert template["seats"] == 2 and template["back"] is True
    xs = [p["position"][0] for p in data["person"]]
    assert xs[1] - xs[0] > 0.35  # side by side, not on top of each other
    # the scenario reads back, every dimension given: the same start
    scenario = parse_scenario(data, "design")
    assert scenario.surface.template.given["seat_height"] == template["seat_height"]


@pytest.mark.parametrize("poses", [[HIGH.format(39)] * 6,
                                   [HIGH.format(f) for f in (35, 39, 45)] +
                                   [MEDIUM.format(f) for f in (150, 200, 250)]])
def test_six_sitters_get_a_bench_of_six_seats_side_by_side(poses):
    """Six copies of one pose, or six poses: a bench whose seats are each as wide as a
    person (measured with the people side by side; all at one place they were 9 cm each,
    under the template's least)."""
    data, decided = design_scenario(poses)
    template = data["surface"]["template"]
    assert decided["template"] == "bench" and template["seats"] == 6
    assert 0.35 < template["seat_width"] < 0.7
    xs = np.array([p["position"][0] for p in data["person"]])
    assert np.all(np.diff(xs) > 0.3)


def test_lying_people_get_a_bed_they_are_lifted_onto(tmp_path):
    lying = _turned(tmp_path, STANDING.format(0), -90.0, "lying")
    data, decided = design_scenario([lying])
    assert decided["template"] == "bed"
    assert data["person"][0]["position"][1] > 0.4
    assert 0.4 < data["surface"]["template"]["height"] < data["person"][0]["position"][1]
    assert data["surface"]["template"]["length"] > 1.6
    # two sleepers: a bed as wide as both, with as many quads across each as a bed for one
    data, decided = design_scenario([lying, lying])
    one = TEMPLATE_PARAMS["bed"]().quads
    assert data["surface"]["template"]["quads"] == [2 * one[0], one[1]]
    assert data["surface"]["template"]["width"] > 1.4


def test_floor_sitters_share_a_cushion_with_as_many_quads_across_each_as_one_has():
    """Four floor sitters on one cushion of one sitter's 10 quads across all missed coverage
    (0.87-0.945, an independent review, 2026-12-07); with 10 across each they meet every bar
    (measured: coverage 0.97-0.98)."""
    data, decided = design_scenario([FLOOR.format(f) for f in (2, 6, 10, 14)])
    one = TEMPLATE_PARAMS["floor_cushion"]().quads
    assert decided["template"] == "floor_cushion"
    assert data["surface"]["template"]["quads"] == [4 * one[0], one[1]]
    data, _ = design_scenario([FLOOR.format(8)])
    assert list(data["surface"]["template"]["quads"]) == list(one)  # (one: the template's)


@pytest.mark.parametrize("poses, message", [
    ([], r"Expected at least one pose, got none"),
    ([STANDING.format(0)], r"is a standing pose: there is nothing to design under it"),
    ([HIGH.format(39), FLOOR.format(8)], r"Expected poses of one posture .*: seated, .*: floor"),
    ([MEDIUM.format(75)], r"frame=75 stands on its feet: its centre of mass is 10 cm ahead of "
                          r"the ankles \(trunk 62 degrees forward, pelvis 0.67 m up\), a body "
                          r"sitting down or rising"),
    ([HIGH.format(39), MEDIUM.format(60)], r"frame=60 stands on its feet: .* 12 cm ahead"),
    # perched, rising (stools designed under these held no one: coverage 0.00-0.64, no rest)
    ([HIGH.format(13)], r"frame=13 stands on its feet"),
    ([HIGH.format(59)], r"frame=59 stands on its feet: .*\(trunk 2\d degrees forward"),
])
def test_the_designer_refuses_what_it_has_no_furniture_for(poses, message):
    with pytest.raises(DesignError, match=message):
        design_scenario(poses)


@pytest.mark.slow
def test_a_design_is_fitted_and_its_scenario_fits_again(tmp_path, capsys):
    from solver.cli import main

    assert main(["design", FLOOR.format(8), "--out", str(tmp_path / "d"), "--no-pictures"]) == 0
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    # the command line says how many rounds of relief were kept, as `sitrelax fit` does, or
    # that none was needed (every peak at the target from the start)
    kept = max([r["round"] for r in report["relief"]["rounds"] if r["kept"]], default=0)
    out = capsys.readouterr().out
    if report["relief"]["rounds"]:
        assert f"pressure relief: {kept} round(s) kept" in out
    else:
        assert report["relief"]["at_target"] and "pressure relief: no round needed" in out
    assert report["design"]["template"] == "floor_cushion"
    assert report["parameters"]["template"]["kind"] == "floor_cushion"
    assert report["guarantees"]["self_intersections"] == 0
    assert report["persons"][0]["coverage"] > 0.5
    scenario = load_scenario(tmp_path / "d" / "scenario.toml")
    assert scenario.surface.template.given["height"] == \
        pytest.approx(report["parameters"]["template"]["height"])


def test_a_reclined_person_gets_a_lounger_under_them(tmp_path):
    reclined = _turned(tmp_path, MEDIUM.format(200), -35.0, "reclined")
    data, decided = design_scenario([reclined])
    assert decided["template"] == "lounger"
    template = data["surface"]["template"]
    assert 0.1 < template["seat_height"] < 0.45
    assert 20.0 < template["back_angle_deg"] < 50.0


def test_seated_people_sit_2_cm_up_each_at_their_own_height_with_every_control_vertex_free():
    """One sitter: 2 cm up on a chair whose control vertices are all free (the seat's front
    edge too: the rim rows keep it off the calves); two sitters of different heights: each
    2 cm up as they sit, on a bench with a seat each measured as their own chair would be."""
    data, decided = design_scenario([HIGH.format(39)])
    assert decided["template"] == "chair"
    (person,) = data["person"]
    assert person["position"][1] == pytest.approx(0.02)
    assert "fixed" not in data["surface"]
    data, decided = design_scenario([HIGH.format(39), MEDIUM.format(200)])
    assert decided["template"] == "bench" and "fixed" not in data["surface"]
    assert [p["position"][1] for p in data["person"]] == pytest.approx([0.02, 0.02])
    template = data["surface"]["template"]
    assert template["seat_each"] is True and len(template["seat_profiles"]) == 2
    # each seat as the sitter's own chair: the same height and depth (the seats' widths run
    # to the seam between them)
    heights = [s["seat_height"] for s in template["seat_profiles"]]
    for k, pose in enumerate((HIGH.format(39), MEDIUM.format(200))):
        chair = design_scenario([pose])[0]["surface"]["template"]
        assert heights[k] == pytest.approx(chair["seat_height"], abs=1e-9)
        assert template["seat_profiles"][k]["seat_depth"] == \
            pytest.approx(chair["seat_depth"], abs=1e-9)
    assert heights[0] - heights[1] > 0.05  # the high sitter's seat is the higher


@pytest.mark.slow
@pytest.mark.parametrize("which, template, over_flat, calf", [
    ("high", "chair", 0, 0), ("medium", "chair", 0, 0), ("high+medium", "bench", 0, 0),
    ("floor", "floor_cushion", 0, 0), ("reclined", "lounger", 0, 0), ("lying", "bed", 0, 0),
    ("lying+lying", "bed", 0, 0),
])
def test_every_design_meets_the_bars_of_a_finished_piece(tmp_path, which, template, over_flat,
                                                         calf):
    """Issue 19's item 3: the designer, given each bundled seated, floor, reclined (made here)
    and lying (made here) pose, one or two people, picks the template and fits a surface that
    meets every bar `solver.scene.quality` reads (the surface's guarantees checked on its
    limit surface; each person's coverage, contact, rest, peak region and seated load, and the
    seat's peak against a flat seat's at the same load), after the design's rounds of pressure
    relief, but for the known misses of that last bar (`over_flat` people: none now; the bench
    with one seat height for both sitters was at 0.67 and 0.78, and a seat each measured as
    their own chair brought it to 0.54 and 0.56) and of the peak's region (`calf` people: none
    now): one more, or one fewer, fails the test, so that the counts are kept true. No design
    needs a waterfall front now: the medium-sit chair's straight front put 19.0 kPa on a calf
    before relief, which its first round relieves."""
    from solver.scene.design import run_design
    from solver.scene.quality import person_misses, surface_misses

    made = {"high": HIGH.format(39), "medium": MEDIUM.format(200), "floor": FLOOR.format(8),
            "reclined": _turned(tmp_path, MEDIUM.format(200), -35.0, "reclined"),
            "lying": _turned(tmp_path, STANDING.format(0), -90.0, "lying")}
    report = run_design([made[name] for name in which.split("+")], tmp_path / "out",
                        pictures=False)
    assert report["design"]["template"] == template
    assert report["design"]["waterfall"] is None, report["design"]["waterfall"]
    # relief ran, or every peak was at its target from the start (the beds, the lounger and
    # the floor cushion since the flat seat carries the steeper parts' load too)
    assert report["relief"]["rounds"] or report["relief"]["at_target"], report["relief"]
    misses = surface_misses(report["guarantees"]) + \
        [m for person in report["persons"] for m in person_misses(person)]
    flat = [m for m in misses if "of a flat seat's at the same load" in m]
    on_calf = [m for m in misses if "on the calves, which are not to be supported" in m]
    assert [m for m in misses if m not in flat and m not in on_calf] == []
    assert len(flat) == over_flat, flat
    assert len(on_calf) == calf, on_calf


@pytest.mark.parametrize("misses_after, kept", [(1, True), (2, False), (3, False)])
def test_a_seat_with_a_peak_on_the_calves_is_tried_again_with_a_waterfall_front(
        tmp_path, monkeypatch, misses_after, kept):
    """run_design's second try, its fits stood in for (each writes its scenario's front drop
    into a file of the folder it fits in, and reports misses as told): the straight front puts
    the peak on a calf (2 misses); the waterfall front, fitted in a folder of its own, replaces
    the first design's files only if it misses fewer bars, and its folder is gone after."""
    import tomllib

    import solver.scene.design as design
    import solver.scene.run as run

    def fake_fit(path, out, **_):
        drop = tomllib.loads(path.read_text())["surface"]["template"].get("front_drop", 0.0)
        (out / "surface.obj").write_text(f"drop {drop}\n")
        (out / "report.json").write_text("{}")
        return {"scenario": str(path), "guarantees": {}, "misses": 2 if drop == 0 else
                misses_after,
                "persons": [{"peak_region": "calves" if drop == 0 else "thighs",
                             "support": ["pelvis", "thighs", "lower_back", "upper_back"]}]}

    monkeypatch.setattr(run, "run_fit", fake_fit)
    monkeypatch.setattr(design, "_misses", lambda report: report["misses"])
    report = design.run_design([MEDIUM.format(200)], tmp_path / "out", pictures=False)
    out = tmp_path / "out"
    tried = report["design"]["waterfall"]
    assert tried["front_drop_m"] > 0 and tried["misses_before"] == 2
    assert tried["misses_after"] == misses_after and tried["kept"] is kept
    drop = tomllib.loads((out / "scenario.toml").read_text())["surface"]["template"][
        "front_drop"]
    assert (drop > 0) is kept
    assert (out / "surface.obj").read_text() == f"drop {drop}\n"
    assert report["scenario"] == str(out / "scenario.toml")
    assert json.loads((out / "report.json").read_text())["design"]["waterfall"] == tried
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "scenario.toml",
                                                      "surface.obj"]


def test_a_seat_whose_peak_is_not_on_the_calves_is_fitted_once(tmp_path, monkeypatch):
    import solver.scene.design as design
    import solver.scene.run as run

    fits = []

    def fake_fit(path, out, **_):
        fits.append(path)
        return {"scenario": str(path), "guarantees": {},
                "persons": [{"peak_region": "pelvis", "support": ["pelvis", "thighs"]}]}

    monkeypatch.setattr(run, "run_fit", fake_fit)
    monkeypatch.setattr(design, "_misses", lambda report: 1)
    report = design.run_design([MEDIUM.format(200)], tmp_path / "out", pictures=False)
    assert len(fits) == 1 and report["design"]["waterfall"] is None


def test_a_waterfall_front_that_fails_leaves_the_straight_front_as_it_was(tmp_path,
                                                                          monkeypatch):
    """The second try's fit fails (a FitError): the first design's files and report stand,
    "design" says why, and the try's folder is gone."""
    import solver.scene.design as design
    import solver.scene.run as run
    from solver.surface.fit import FitError

    def fake_fit(path, out, **_):
        if out.name.startswith(".waterfall-"):
            raise FitError("no step")
        (out / "surface.obj").write_text("straight\n")
        return {"scenario": str(path), "guarantees": {}, "misses": 2,
                "persons": [{"peak_region": "calves", "support": ["pelvis", "thighs"]}]}

    monkeypatch.setattr(run, "run_fit", fake_fit)
    monkeypatch.setattr(design, "_misses", lambda report: report["misses"])
    report = design.run_design([MEDIUM.format(200)], tmp_path / "out", pictures=False)
    out = tmp_path / "out"
    assert report["design"]["waterfall"]["kept"] is False
    assert report["design"]["waterfall"]["error"] == "no step"
    assert (out / "surface.obj").read_text() == "straight\n"
    assert "front_drop = 0.0\n" in (out / "scenario.toml").read_text()
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "scenario.toml",
                                                      "surface.obj"]


def _calf_peak_fit(fits):
    """A stand-in for run_fit whose straight front puts the peak on a calf (2 misses)."""
    def fake_fit(path, out, **_):
        fits.append(out.name)
        (out / "surface.obj").write_text(f"{out.name}\n")
        return {"scenario": str(path), "guarantees": {}, "misses": 2,
                "persons": [{"peak_region": "calves", "support": ["pelvis", "thighs"]}]}
    return fake_fit


def test_no_second_fit_when_no_calves_tuck_under_the_front(tmp_path, monkeypatch):
    import solver.scene.design as design
    import solver.scene.run as run

    import solver.scene.furnish as furnish

    fits = []
    monkeypatch.setattr(run, "run_fit", _calf_peak_fit(fits))
    monkeypatch.setattr(design, "_misses", lambda report: report["misses"])
    monkeypatch.setattr(furnish, "WATERFALL", 0.0)  # (the measure gives no drop)
    report = design.run_design([MEDIUM.format(200)], tmp_path / "out", pictures=False)
    assert len(fits) == 1 and fits[0].startswith(".straight-")  # (then moved in whole)
    assert report["design"]["waterfall"] == {"front_drop_m": 0.0, "misses_before": 2,
                                             "kept": False, "straight_fit_s": None}


def test_the_first_design_is_complete_before_the_second_try(tmp_path, monkeypatch):
    """The second try is stopped from outside (an interrupt in its fit): the straight front's
    report already says what was designed, and the try's folder is gone."""
    import solver.scene.design as design
    import solver.scene.run as run

    fits = []
    first = _calf_peak_fit(fits)

    def fake_fit(path, out, **kw):
        if out.name.startswith(".waterfall-"):
            raise KeyboardInterrupt
        return first(path, out, **kw)

    monkeypatch.setattr(run, "run_fit", fake_fit)
    monkeypatch.setattr(design, "_misses", lambda report: report["misses"])
    (tmp_path / "out" / ".waterfall-stale").mkdir(parents=True)  # an earlier run's, unfinished
    (tmp_path / "out" / ".straight-stale").mkdir()
    with pytest.raises(KeyboardInterrupt):
        design.run_design([MEDIUM.format(200)], tmp_path / "out", pictures=False)
    out = tmp_path / "out"
    saved = json.loads((out / "report.json").read_text())
    assert saved["design"]["template"] == "chair" and saved["design"]["waterfall"] is None
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "scenario.toml",
                                                      "surface.obj"]



def test_a_design_whose_fit_fails_leaves_the_earlier_design_as_it_was(tmp_path, monkeypatch):
    """An earlier design in the folder; the new one's fit fails: its scenario.toml, report
    and files are the earlier design's still, nothing of the new one mixed in."""
    import solver.scene.design as design
    import solver.scene.run as run
    from solver.surface.fit import FitError

    out = tmp_path / "out"
    out.mkdir()
    for name in ("scenario.toml", "control.obj", "report.json"):
        (out / name).write_text("earlier")

    def failing(path, out, **_):
        raise FitError("no fit")

    monkeypatch.setattr(run, "run_fit", failing)
    with pytest.raises(FitError):
        design.run_design([MEDIUM.format(200)], out, pictures=False)
    assert {p.name: p.read_text() for p in out.iterdir()} == {
        "scenario.toml": "earlier", "control.obj": "earlier", "report.json": "earlier"}


def test_a_designs_scenario_is_listed_with_its_results(tmp_path, monkeypatch):
    """scenario.toml is one of the design's files (report.json's `files`), so that a later
    result in the same folder (a fit) removes it with the rest rather than leaving it beside
    results it did not make."""
    import solver.scene.design as design
    import solver.scene.run as run

    import solver.scene.furnish as furnish

    monkeypatch.setattr(run, "run_fit", _calf_peak_fit([]))
    monkeypatch.setattr(design, "_misses", lambda report: report["misses"])
    monkeypatch.setattr(furnish, "WATERFALL", 0.0)
    out = tmp_path / "out"
    design.run_design([MEDIUM.format(200)], out, pictures=False)
    saved = json.loads((out / "report.json").read_text())
    assert saved["files"]["scenario"] == "scenario.toml"
    assert "scenario.toml" in run.previous_results(out)


def test_a_design_sheet_is_titled_by_its_template_and_poses():
    """Every design's scenario is scenario.toml: its sheet's title names what was designed."""
    from solver.scene.design import _design_title

    data = {"surface": {"template": {"kind": "floor_cushion"}},
            "person": [{"pose": "bvh:/data/cmu_75_17_medium_sit.bvh#frame=150"},
                       {"pose": "db:alice-sit"}]}
    assert _design_title(data) == ("sitrelax design: a floor cushion for "
                                   "cmu_75_17_medium_sit.bvh frame 150, db:alice-sit")
