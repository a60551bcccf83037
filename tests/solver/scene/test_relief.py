"""Pressure relief (solver.scene.relief): what a round eases, when one is refused, and a whole
relief run on an example judged by the evaluation against the plain fit."""

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from solver.scene.relief import RISE, excess_depth, refused, relief_text, relieve
from solver.scene.scenario import ScenarioError, parse_scenario

SCENARIOS = Path(__file__).resolve().parents[3] / "solver" / "data" / "scenarios"


def test_the_excess_is_the_depth_the_pressure_over_the_aim_presses():
    pressure = np.array([0.0, 4.0, 5.0, 10.0])  # kPa
    depth = excess_depth(pressure, 4.0, 200e3)  # 200 kPa per metre
    np.testing.assert_allclose(depth, [0.0, 0.0, 0.005, 0.03])


def _person(name="sitter", ratio=0.7, **change) -> dict:
    """A report row as person_miss_kinds reads it (reclined: no seated loads asked)."""
    row = {"name": name, "posture": "reclined", "support": ["pelvis", "thighs"],
           "coverage": 0.97, "contact_coverage": 0.9, "peak_pressure_kpa": 7.0,
           "peak_region": "thighs", "equilibrium": {"stable": True, "reason": None},
           "mat": {"total": {"regions": {}}, "supports": {}}, "max_penetration_m": 0.02,
           "peak_of_flat": ratio,
           "flat": {"same_load": None if ratio is None else {
               "fitted_peak_kpa": 10.0 * ratio, "peak_pressure_kpa": 10.0}}}
    row.update(change)
    return row


def test_a_round_that_lowers_the_peak_and_misses_nothing_new_is_kept():
    assert refused([_person(ratio=0.7)], [_person(ratio=0.62)], 0.03) is None
    # a bar missed before may stay missed
    before = [_person(ratio=0.7, coverage=0.93)]
    assert refused(before, [_person(ratio=0.6, coverage=0.94)], 0.03) is None


@pytest.mark.parametrize("after, words", [
    (_person(ratio=0.6, coverage=0.94), "coverage 0.94"),
    (_person(ratio=0.6, contact_coverage=0.7), "contact coverage"),
    (_person(ratio=0.6, peak_region="calves"), "on the calves"),
    (_person(ratio=0.6, max_penetration_m=0.035), "cuts 35 mm"),
    (_person(ratio=None, equilibrium={"stable": False, "reason": "tips over"}),
     "does not come to rest"),
    (_person(ratio=0.7), "did not fall"),
    (_person(ratio=0.71), "did not fall"),
    (_person(ratio=0.8), "rose from 0.70 to 0.80"),
])
def test_a_round_that_misses_a_bar_it_met_or_does_not_lower_the_peak_is_refused(after, words):
    why = refused([_person(ratio=0.7)], [after], 0.03)
    assert why is not None and words in why, why


def test_one_person_may_not_pay_for_another():
    """The highest peak falls, but another person's may rise by RISE at most, and not over
    the bar if it was under it."""
    before = [_person("a", 0.9), _person("b", 0.62)]
    worse = [_person("a", 0.8), _person("b", 0.62 + 2 * RISE)]
    assert "b: the peak over the flat seat's rose from 0.62" in refused(before, worse, 0.03)
    assert refused(before, [_person("a", 0.8), _person("b", 0.62 + RISE / 2)], 0.03) is None
    lost = [_person("a", 0.8), _person("b", None)]
    assert "b: the peak over the flat seat's is lost" in refused(before, lost, 0.03)
    met = [_person("a", 0.9), _person("b", 0.58)]  # b meets the flat seat's bar (0.6)
    crossed = refused(met, [_person("a", 0.8), _person("b", 0.6 + RISE / 2)], 0.03)
    assert "misses a bar it met: b: peak pressure on the skin the flat seat presses" in crossed, \
        crossed


def test_a_rise_is_counted_from_the_fit_before_any_round_not_round_by_round():
    first = [_person("a", 0.9), _person("b", 0.65)]
    now = [_person("a", 0.8), _person("b", 0.65 + 0.8 * RISE)]  # after a kept round
    after = [_person("a", 0.7), _person("b", 0.65 + 1.6 * RISE)]  # each round rises < RISE
    assert refused(now, after, 0.03) is None  # (round by round it would pass)
    assert "b: the peak over the flat seat's rose from 0.65" in refused(now, after, 0.03, first)


def test_a_body_that_comes_to_rest_is_not_held_to_bars_never_judged_before():
    """A body at no rest is judged on coverage, contact, rest and the cut only: one that comes
    to rest over the flat seat's bar is not refused for it (the highest known peak falls)."""
    restless = _person("b", None, equilibrium={"stable": False, "reason": "tips over"})
    before = [_person("a", 0.9), restless]
    assert refused(before, [_person("a", 0.8), _person("b", 0.65)], 0.03) is None
    worse = [_person("a", 0.8), _person("b", 0.65, coverage=0.9)]
    assert "misses a bar it met: b: coverage" in refused(before, worse, 0.03)


def test_a_standing_person_counts_for_no_seat():
    stander = _person("s", 0.95, posture="standing")
    before = [_person("a", 0.9), _person("s", 0.3, posture="standing")]
    assert refused(before, [_person("a", 0.7), stander], 0.03) is None


@pytest.mark.parametrize("change, words", [
    ({"coverage": 0.92}, "coverage fell further, 0.940 -> 0.920"),
    ({"contact_coverage": 0.7}, "contact coverage fell further, 0.750 -> 0.700"),
    ({"max_penetration_m": 0.037}, "the cut deepened, 35 -> 37 mm"),
])
def test_a_bar_missed_may_not_get_worse(change, words):
    missing = {"coverage": 0.94, "contact_coverage": 0.75, "max_penetration_m": 0.035}
    before = [_person(ratio=0.7, **missing)]
    assert refused(before, [_person(ratio=0.6, **missing)], 0.03) is None
    why = refused(before, [_person(ratio=0.6, **{**missing, **change})], 0.03)
    assert why is not None and words in why, why


@pytest.mark.parametrize("relief, field", [({"rounds": -1}, "relief.rounds"),
                                           ({"rounds": 11}, "relief.rounds"),
                                           ({"target": 0.1}, "relief.target"),
                                           ({"aim": 0.5}, "relief.aim")])
def test_a_bad_relief_names_its_field(relief, field):
    data = {"surface": {"grid": {"size": [0.5, 0.5], "resolution": [4, 4], "height": 0.4}},
            "person": [{"pose": "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"}],
            "relief": relief}
    with pytest.raises(ScenarioError, match=field):
        parse_scenario(data, "test")


def test_a_cancel_stops_the_rounds_with_what_was_kept_and_says_so():
    """Asked before each fit: a cancel that says so at once leaves the fit as it was."""
    scenario = SimpleNamespace(surface=SimpleNamespace(params=SimpleNamespace(margin=0.03)),
                               evaluation=SimpleNamespace(foam_stiffness=200.0))
    people = [SimpleNamespace(vertices=np.zeros((3, 3)), normals=np.zeros((3, 3)))]
    persons = [{"peak_of_flat": 0.8, "flat": {"same_load": None}}]

    def never(*_):
        raise AssertionError("no fit after the cancel")

    result, kept, maps, relief = relieve(scenario, people, "fit", persons, [None], fit=never,
                                         evaluate=never, rounds=3, target=0.5,
                                         cancel=lambda: True)
    assert (result, kept, maps) == ("fit", persons, [None])
    assert relief.record() == {"rounds": [], "kept": 0, "stopped": True,
                               "at_target": False}
    assert relief_text(relief.record()) is None  # (nothing tried: no line)
    tried = {"rounds": [{"round": 1, "kept": True, "fit_s": 0.5},
                        {"round": 2, "kept": False, "fit_s": 0.25}], "stopped": True}
    assert relief_text(tried) == ("pressure relief: 1 round(s) kept, 2 fit(s) tried (0.8 s of "
                                  "fitting, stopped early: out of time)")


def _stub_scene(ratios):
    """relieve's inputs for stand-in fits: a person per ratio on a seat, pressed 8 kPa over
    its 3 vertices against a flat seat's 10 kPa (a step of 5 mm at the aim of 5 kPa)."""
    from solver.contact.settle import Settled
    from solver.contact.mat import SupportContact

    scenario = SimpleNamespace(surface=SimpleNamespace(params=SimpleNamespace(margin=0.03)),
                               evaluation=SimpleNamespace(foam_stiffness=200.0))
    contact = SupportContact("seat", np.arange(3), np.full(3, 8.0), np.zeros((3, 3)),
                             np.tile([0.0, 1.0, 0.0], (3, 1)), np.zeros((3, 3)),
                             np.zeros(3, dtype=int), np.full(3, 1e-3))  # 8 N on 10 cm^2
    settled = Settled(True, None, np.zeros((3, 3)), np.zeros(3), np.zeros(3), np.zeros(3),
                      [contact], np.zeros(3), np.zeros(3), 100.0)
    maps = [SimpleNamespace(settled=settled) for _ in ratios]

    @dataclasses.dataclass(frozen=True)
    class Skin:
        vertices: np.ndarray
        normals: np.ndarray

    people = [Skin(np.zeros((3, 3)), np.tile([0.0, -1.0, 0.0], (3, 1))) for _ in ratios]
    persons = [_person(f"p{k}", r) for k, r in enumerate(ratios)]
    return scenario, people, persons, maps


def test_a_cancel_after_a_fit_keeps_what_was_kept_before_it():
    scenario, people, persons, maps = _stub_scene([0.8])
    fits, asked = [], []

    def fit(targets):
        fits.append(targets)
        return SimpleNamespace(seconds=0.1, iterations=5)

    def cancel():  # says so once the first fit is made
        asked.append(1)
        return bool(fits)

    result, kept, _, relief = relieve(scenario, people, "fit", persons, maps, fit=fit,
                                      evaluate=lambda r: pytest.fail("not evaluated"),
                                      rounds=3, target=0.5, cancel=cancel)
    assert len(fits) == 1 and result == "fit" and kept is persons
    assert relief.record() == {"rounds": [], "kept": 0, "stopped": True,
                               "at_target": False}
    # the first fit's aim: the skin out along its normal by (8 - 5) kPa / 200 kPa/m = 15 mm,
    # at most STEP a round
    np.testing.assert_allclose(fits[0][0].vertices, [[0.0, -0.005, 0.0]] * 3)


def test_rounds_stop_once_the_skin_is_out_by_the_margin():
    """Once every aimed-at point is out by the margin, no round refits the same aim again."""
    scenario, people, persons, maps = _stub_scene([0.8])
    scenario.surface.params.margin = 0.007  # two rounds' worth of 5 mm, capped
    fits = []
    ratio = iter([0.75, 0.7, 0.65, 0.6])

    def fit(targets):
        fits.append(float(-targets[0].vertices[0, 1]))
        return SimpleNamespace(seconds=0.1, iterations=5)

    def evaluate(_):
        return [_person("p0", next(ratio))], maps

    result, kept, _, relief = relieve(scenario, people, "fit", persons, maps, fit=fit,
                                      evaluate=evaluate, rounds=6, target=0.5)
    assert fits == pytest.approx([0.005, 0.007])  # then nothing left to ease: no third fit
    assert relief.record()["kept"] == 2 and kept[0]["peak_of_flat"] == 0.7


def test_relief_is_off_unless_asked_for():
    data = {"surface": {"grid": {"size": [0.5, 0.5], "resolution": [4, 4], "height": 0.4}},
            "person": [{"pose": "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"}]}
    assert parse_scenario(data, "test").relief.rounds == 0


def test_relief_lowers_the_seated_peak_and_keeps_every_bar_the_fit_met(tmp_path):
    """single_seated fitted plainly and with two rounds of relief: the evaluation (the body
    settled on each surface, the flat seat at the same load) finds the relieved seat's peak
    lower against its flat seat, and the relieved person misses no bar the plain fit met."""
    from solver.scene.quality import person_miss_kinds
    from solver.scene.run import run_fit

    plain_toml = (SCENARIOS / "single_seated.toml").read_text()
    plain = run_fit(SCENARIOS / "single_seated.toml", tmp_path / "plain", pictures=False,
                    formats=("obj",))
    scenario = tmp_path / "relieved.toml"
    scenario.write_text(plain_toml + "\n[relief]\nrounds = 2\n")
    relieved = run_fit(scenario, tmp_path / "relieved", pictures=False, formats=("obj",))
    assert plain["relief"] is None
    rounds = relieved["relief"]["rounds"]
    assert any(r["kept"] for r in rounds), rounds
    before, after = plain["persons"][0], relieved["persons"][0]
    assert after["peak_of_flat"] < before["peak_of_flat"] - 0.02, (before["peak_of_flat"],
                                                                     after["peak_of_flat"])
    margin = plain["parameters"]["margin"]
    missed = {kind for kind, _ in person_miss_kinds(before, margin)}
    assert {kind for kind, _ in person_miss_kinds(after, margin)} <= missed
    assert relieved["guarantees"]["ok"] or not plain["guarantees"]["ok"]
    # the files are the kept fit's: the surface written is not the plain fit's, and the
    # report's iterations are those of the kept fit, not the first
    assert (tmp_path / "relieved" / "surface.obj").read_bytes() != \
        (tmp_path / "plain" / "surface.obj").read_bytes()
    kept = [r for r in rounds if r["kept"]][-1]
    assert relieved["iterations"] == kept["iterations"] and \
        relieved["timing"]["fit_s"] == kept["fit_s"]
    assert relieved["persons"][0]["peak_of_flat"] == pytest.approx(kept["peak_of_flat"][0])
    json.dumps(relieved, allow_nan=False)


def test_a_relief_round_shows_its_fit_s_iterations_and_evaluation(monkeypatch):
    """A relief try on a large scene takes tens of seconds: its fit's iterations and its
    evaluation are told as they come, as the first fit's are."""
    import solver.scene.relief as relief_module
    import solver.scene.run as run

    def fake_fit_people(scenario, people, progress=None, **_):
        for i in (1, 2):
            progress(i, 0.5 / i, 0.5)
        return "refit"

    def fake_relieve(scenario, people, result, persons, maps, *, fit, evaluate, say, **_):
        evaluate(fit(people))
        say("relief round 1: kept")
        return result, persons, maps, None

    monkeypatch.setattr(run, "fit_people", fake_fit_people)
    monkeypatch.setattr(run, "evaluate_fit", lambda scenario, people, fit: (None, [], []))
    monkeypatch.setattr(relief_module, "relieve", fake_relieve)
    said = []
    scenario = SimpleNamespace(surface=SimpleNamespace(params=None),
                               relief=SimpleNamespace(rounds=1, target=0.5))
    run.relieve_fit(scenario, ["a", "b"], "fit", [], [], said.append)
    assert said == ["relief fit: iteration 1: energy 0.5",
                    "relief fit: iteration 2: energy 0.25",
                    "relief: evaluating 2 person(s) on the refitted surface",
                    "relief round 1: kept"]


def test_the_tries_of_a_round_are_told_apart():
    """A refused try is tried again (as long, then shorter, and where the refused fit pressed
    harder): each line says which try it is, so two alike are not read as one said twice."""
    scenario, people, persons, maps = _stub_scene([0.8])
    ratio = iter([0.85, 0.7])  # the first try raises the peak: refused; the second is kept

    def evaluate(_):
        return [_person("p0", next(ratio))], maps

    said = []
    relieve(scenario, people, "fit", persons, maps,
            fit=lambda targets: SimpleNamespace(seconds=0.1, iterations=5), evaluate=evaluate,
            rounds=1, target=0.5, say=said.append)
    assert len(said) == 2 and said[0].startswith("relief round 1: skin aimed at moved out")
    # (the refused fit pressed no harder anywhere new here: the same aim again at full length
    # would be the same fit, so the next try is the half step)
    assert said[1].startswith("relief round 1, try 2 (0.5 of the step): skin aimed at moved "
                              "out"), said


def test_a_failed_fit_is_not_tried_again_as_it_was():
    """A try whose fit fails leaves nothing to widen the step by: the next try of the same
    length would be the same fit, so the round goes on with the half step."""
    from solver.surface.fit import FitError

    scenario, people, persons, maps = _stub_scene([0.8])
    fits, said = [], []

    def fit(targets):
        fits.append(float(-targets[0].vertices[0, 1]))
        raise FitError("no fit")

    relieve(scenario, people, "fit", persons, maps, fit=fit,
            evaluate=lambda r: pytest.fail("not evaluated"), rounds=1, target=0.5,
            say=said.append)
    assert fits == pytest.approx([0.005, 0.0025, 0.00125])  # 1, then 0.5 and 0.25 of the step
    assert said[1].startswith("relief round 1, try 2 (0.5 of the step): refused"), said


def test_relief_asked_for_and_not_needed_says_so():
    """Every person already at the target: no fit is tried, and the report and its line say
    that none was needed (a line for rounds that were asked for), not nothing."""
    from solver.surface.fit import FitError

    scenario, people, persons, maps = _stub_scene([0.45])

    def fit(targets):
        raise AssertionError("no fit is needed")

    result, kept, _, relief = relieve(scenario, people, "fit", persons, maps, fit=fit,
                                      evaluate=None, rounds=6, target=0.5)
    record = relief.record()
    assert result == "fit" and record["rounds"] == [] and record["at_target"]
    assert relief_text(record) == "pressure relief: no round needed (every peak at the target " \
                                  "already)"
    def failing(targets):
        raise FitError("no fit")

    over = _stub_scene([0.55])  # over the target: a round is tried, and at_target stays False
    _, _, _, relief = relieve(*over[:2], "fit", *over[2:], fit=failing, evaluate=None,
                              rounds=1, target=0.5)
    assert not relief.record()["at_target"] and relief.rounds[0]["refused"].startswith(
        "the fit failed")


def test_relief_with_no_peak_to_judge_is_not_at_its_target():
    """No person with a peak over a flat seat's (none rests, or none sits): nothing is tried and
    nothing is said to be at the target."""
    scenario, people, persons, maps = _stub_scene([None])
    _, _, _, relief = relieve(scenario, people, "fit", persons, maps, fit=None, evaluate=None,
                              rounds=6, target=0.5)
    assert relief.record()["rounds"] == [] and not relief.record()["at_target"]
    assert relief_text(relief.record()) is None
