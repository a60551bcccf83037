"""`run_fit` checks the guarantees and draws the design sheet on a second thread, beside the
evaluation and the exports; a batch's workers (one per core) do it all in turn. Both ways give
the same report and files, and beside they do run on another thread."""

import threading
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[3] / "solver" / "data" / "scenarios"


def test_the_work_beside_gives_the_report_and_files_the_work_in_turn_gives(tmp_path,
                                                                          monkeypatch):
    import solver.scene.run as run
    import solver.scene.sheet as sheet

    threads = []

    def noting(func):
        def noted(*args, **kwargs):
            threads.append((func.__name__, threading.current_thread() is
                            threading.main_thread()))
            return func(*args, **kwargs)
        return noted

    monkeypatch.setattr(run, "fit_guarantees", noting(run.fit_guarantees))
    monkeypatch.setattr(sheet, "write_design_sheet", noting(sheet.write_design_sheet))
    text = (EXAMPLES / "single_seated.toml").read_text().replace(
        "margin = 0.03", "margin = 0.03\nmax_iterations = 3")
    scenario = tmp_path / "seat.toml"
    scenario.write_text(text)
    beside = run.run_fit(scenario, tmp_path / "beside", formats=("obj",), beside=True)
    assert threads == [("fit_guarantees", False), ("write_design_sheet", False)]
    threads.clear()
    in_turn = run.run_fit(scenario, tmp_path / "in_turn", formats=("obj",), beside=False)
    assert threads == [("fit_guarantees", True), ("write_design_sheet", True)]
    assert beside["guarantees"] == in_turn["guarantees"]
    assert beside["persons"] == in_turn["persons"]
    assert beside["files"] == in_turn["files"]
    assert beside["files"]["sheet_png"] == "sheet.png"
    assert (tmp_path / "beside" / "sheet.png").stat().st_size > 10_000
    assert set(beside["timing"]) == set(in_turn["timing"]) >= {
        "fit_s", "evaluate_s", "export_s", "guarantees_s", "sheet_s", "total_s"}
    for name in ("surface.obj", "control.obj", "pressure_map.csv"):
        assert (tmp_path / "beside" / name).read_bytes() == \
            (tmp_path / "in_turn" / name).read_bytes()
