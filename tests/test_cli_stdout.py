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


def test_a_perched_design_whose_fit_meets_a_non_convex_programme_prints_json(tmp_path,
                                                                              capfd):
    # high sit frame 59 (perched, rising): the stool's fit falls back to OSQP, which printed
    # "ERROR in LDL_factor ..." ahead of the report (measured 2026-12-07)
    assert main(["design", "bvh:bundled:cmu_75_18_high_sit.bvh#frame=59", "--out",
                 str(tmp_path / "d"), "--json", "--no-pictures"]) == 0
    out, err = capfd.readouterr()
    report = json.loads(out)
    assert report["design"]["template"] == "stool"
    assert "ERROR in LDL_factor" in err


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
