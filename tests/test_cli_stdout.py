"""`--json` output is the report alone: what a C library prints on standard output past Python
while a fit runs (OSQP's "ERROR in LDL_factor ..." when a programme is not convex) goes to
standard error."""

import json
import os
import sys

from solver.cli import main

NOISE = b"ERROR in LDL_factor: Error in KKT matrix LDL factorization\n"


def _print_as_libraries_do() -> None:
    sys.stdout.write(NOISE.decode())  # (OSQP: PySys_WriteStdout)
    sys.stdout.flush()
    os.write(1, NOISE)  # (a C library's printf: past sys.stdout)


def _noisy(report: dict):
    def run(*args, **kwargs):
        _print_as_libraries_do()
        return report
    return run


def test_design_json_is_json_when_a_library_prints(tmp_path, monkeypatch, capfd):
    import solver.scene.design as design

    monkeypatch.setattr(design, "run_design", _noisy({"design": {"template": "chair"}}))
    assert main(["design", "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39", "--out",
                 str(tmp_path / "d"), "--json"]) == 0
    out, err = capfd.readouterr()
    assert json.loads(out) == {"design": {"template": "chair"}}
    assert "ERROR in LDL_factor" in err


def test_fit_json_is_json_when_a_library_prints(tmp_path, monkeypatch, capfd):
    import solver.scene.run as run

    monkeypatch.setattr(run, "run_fit", _noisy({"persons": []}))
    assert main(["fit", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"),
                 "--json"]) == 0
    out, err = capfd.readouterr()
    assert json.loads(out) == {"persons": []}
    assert "ERROR in LDL_factor" in err


def test_standard_output_is_given_back_after_the_work(tmp_path, monkeypatch, capfd):
    import solver.scene.design as design

    def fails(*args, **kwargs):
        _print_as_libraries_do()
        raise design.DesignError("no furniture for that")

    monkeypatch.setattr(design, "run_design", fails)
    assert main(["design", "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39", "--out",
                 str(tmp_path / "d"), "--json"]) == 2
    os.write(1, b"after\n")
    out, err = capfd.readouterr()
    assert json.loads(out.splitlines()[0]) == {"error": "no furniture for that",
                                               "exit_status": 2}
    assert out.splitlines()[1] == "after"
    assert "ERROR in LDL_factor" in err and "no furniture for that" in err


def test_a_rising_frame_is_refused_in_json_before_any_fit(tmp_path, capfd):
    # high sit frame 59 (perched, rising): its stool's fit fell back to OSQP, which printed
    # "ERROR in LDL_factor ..." ahead of the report, and the stool held no one (measured
    # 2026-12-07); the frame stands on its feet and is now refused before any fit (the
    # monkeypatched tests above keep what a library prints off standard output)
    assert main(["design", "bvh:bundled:cmu_75_18_high_sit.bvh#frame=59", "--out",
                 str(tmp_path / "d"), "--json", "--no-pictures"]) == 2
    out, err = capfd.readouterr()
    answer = json.loads(out)
    assert answer["exit_status"] == 2 and "stands on its feet" in answer["error"]
    assert not (tmp_path / "d").exists()


def test_a_command_started_without_standard_error_still_answers(tmp_path):
    # (fd 2 closed: Python has no sys.stderr, and the next file opened takes descriptor 2;
    # standard output is not sent there)
    import subprocess

    done = subprocess.run(
        [sys.executable, "-m", "solver.cli", "design",
         "bvh:bundled:cmu_75_18_high_sit.bvh#frame=0", "--out", str(tmp_path / "d"), "--json"],
        stdout=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(2), timeout=120)
    assert done.returncode == 2
    assert json.loads(done.stdout.splitlines()[-1])["exit_status"] == 2
    assert not (tmp_path / "d").exists()


def _design_report(supported: list[bool]) -> dict:
    """A design's report as `run_design` returns it, with people who rest or not."""
    people = [{"name": f"person {k + 1}", "coverage": 0.97 if ok else 0.0,
               "max_penetration_m": 0.02, "supported": ok, "peak_pressure_kpa": 5.0 if ok
               else None, "equilibrium": {"stable": ok, "reason": None if ok else
                                          "finds no balance"}}
              for k, ok in enumerate(supported)]
    return {"design": {"postures": ["seated"] * len(people), "template": "chair",
                       "waterfall": None},
            "guarantees": {"folds": 0, "max_fold_deg": 10.0, "self_intersections": 0,
                           "below_floor": False, "max_penetration_dense_m": 0.02},
            "timing": {"fit_s": 0.5}, "iterations": 9, "persons": people,
            "misses": [f"{p['name']}: does not come to rest" for p in people
                       if not p["supported"]], "pictures": []}


def test_a_design_someone_finds_no_rest_on_exits_1(tmp_path, monkeypatch, capsys):
    """A design is for its people: one that someone finds no rest on has failed (exit 1), its
    files written all the same; resting people exit 0."""
    import solver.scene.design as design

    pose = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
    for supported, status in (([True], 0), ([False], 1), ([True, False], 1)):
        monkeypatch.setattr(design, "run_design", lambda *a, **k: _design_report(supported))
        assert main(["design", pose, "--out", str(tmp_path / "d")]) == status
        out = capsys.readouterr().out
        assert ("no rest on this design for" in out) == bool(status)
        if status:
            assert out.rstrip().endswith(f"no rest on this design for person "
                                         f"{len(supported)} (exit status 1)")
        assert main(["design", pose, "--out", str(tmp_path / "d"), "--json"]) == status
        assert json.loads(capsys.readouterr().out)["persons"][-1]["supported"] is supported[-1]


def test_an_interrupted_json_command_answers_in_json(tmp_path, monkeypatch, capsys):
    """Ctrl-C during `fit --json`: exit 130, and the reader of standard output gets a JSON
    answer saying so rather than nothing; without --json, standard output stays empty."""
    import solver.scene.run as run

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(run, "run_fit", interrupted)
    command = ["fit", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")]
    assert main(command + ["--json"]) == 130
    out, err = capsys.readouterr()
    assert json.loads(out) == {"error": "interrupted", "exit_status": 130}
    assert "interrupted" in err
    assert main(command) == 130
    assert capsys.readouterr().out == ""
