"""`run_fit` checks the guarantees on a second thread beside the evaluation and the exports; a
batch's workers (one per core) check them in turn. Both ways give the same report."""

from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[3] / "solver" / "data" / "scenarios"


def test_the_check_beside_gives_the_report_the_check_in_turn_gives(tmp_path):
    from solver.scene.run import run_fit

    text = (EXAMPLES / "single_seated.toml").read_text().replace(
        "margin = 0.03", "margin = 0.03\nmax_iterations = 3")
    scenario = tmp_path / "seat.toml"
    scenario.write_text(text)
    beside = run_fit(scenario, tmp_path / "beside", formats=("obj",), pictures=False)
    in_turn = run_fit(scenario, tmp_path / "in_turn", formats=("obj",), pictures=False,
                      beside=False)
    assert beside["guarantees"] == in_turn["guarantees"]
    assert beside["persons"] == in_turn["persons"]
    assert beside["files"] == in_turn["files"]
    assert {"fit_s", "evaluate_s", "export_s", "guarantees_s", "total_s"} <= set(
        beside["timing"])
    assert (tmp_path / "beside" / "surface.obj").read_bytes() == \
        (tmp_path / "in_turn" / "surface.obj").read_bytes()
