"""Batches, as a designer mistypes them: a grid key or value no scenario takes is refused
before a job runs, a scenario file whose tables are not tables fails its own jobs only (also
under a grid), a grid too large is refused, and a re-run trusts a finished job only when its
report is whole and the one its record was made from."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from solver.cli import main
from solver.scene import batch
from solver.scene.batch import BatchError, expand_jobs, parse_grid, run_batch

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"
SEATED = EXAMPLES / "single_seated.toml"


@pytest.mark.parametrize("item, message", [
    ("surface.sigmaa=0.1,0.2", r"--grid surface.sigmaa: surface has no setting 'sigmaa' "
                               r"\(did you mean surface.sigma\?"),
    ("body.wieght=0.2", r"--grid body.wieght: body has no setting 'wieght' \(did you mean "
                        r"body.weight\?"),
    ("evaluation.x=1", r"--grid evaluation.x: evaluation has no setting 'x'"),
    # a misspelt shortcut or table gets a suggestion as well
    ("sigmaa=0.1", r"--grid sigmaa: no such setting \(did you mean sigma\?\); expected sigma, "),
    ("tau_mx=0.1", r"--grid tau_mx: no such setting \(did you mean tau_max\?\)"),
    ("surfce.sigma=0.1", r"--grid surfce.sigma: no such setting \(did you mean surface.sigma\?"),
    ("bdy.weight=0.2", r"--grid bdy.weight: no such setting \(did you mean body.weight\?"),
    ("xyz=1", r"--grid xyz: expected sigma, tau_max, margin, level, surface.KEY"),
    ("level=3,7", r"--grid level: surface.level cannot be 7 \(input should be less than or "
                  r"equal to 5\)"),
    ("level=2.5", r"--grid level: surface.level cannot be 2.5"),
    ("sigma=-1", r"--grid sigma: surface.sigma cannot be -1"),
    ("body.weight=0.5,2", r"--grid body.weight: body.weight cannot be 2"),
    ("evaluation.floor=0,1", r"--grid evaluation.floor: evaluation.floor cannot be 0"),
    ("person.pose=1", r"--grid person.pose: person.pose cannot be 1"),
])
def test_a_grid_no_scenario_takes_is_refused_before_a_job_runs(item, message):
    with pytest.raises(BatchError, match=message):
        expand_jobs([SEATED], grid=parse_grid([item]))


def test_a_grid_typo_exits_2_with_json_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["batch", str(SEATED), "--grid", "surface.sigmaa=0.1", "--out", str(out),
                 "--json"]) == 2
    said = json.loads(capsys.readouterr().out)
    assert said["exit_status"] == 2 and "did you mean surface.sigma" in said["error"]
    assert not out.exists()


def test_an_empty_value_list_and_a_huge_grid_are_refused(tmp_path, monkeypatch):
    with pytest.raises(BatchError, match="--grid sigma: expected at least one value"):
        expand_jobs([SEATED], grid={"sigma": []})
    monkeypatch.setattr(batch, "MAX_JOBS", 10)
    with pytest.raises(BatchError, match="The grid has 12 points; a batch has at most 10"):
        expand_jobs([SEATED], grid={"sigma": [0.001, 0.002, 0.003],
                                    "margin": [0.01, 0.02, 0.03, 0.04]})
    with pytest.raises(BatchError, match="3 scenarios times 4 grid points make 12 jobs"):
        expand_jobs([SEATED] * 3, grid={"margin": [0.01, 0.02, 0.03, 0.04]})
    copies = [tmp_path / f"{k}.toml" for k in range(2)]
    for copy in copies:
        copy.write_text(SEATED.read_text())
    assert len(expand_jobs(copies, grid={"margin": [0.01, 0.02, 0.03, 0.04]})) == 8


GRID_SURFACE = "[surface]\ngrid = { size = [0.5, 0.6], resolution = [8, 6], height = 0.42 }\n"
PERSON = "[[person]]\npose = \"bvh:bundled:cmu_75_18_high_sit.bvh#frame=39\"\n"


@pytest.mark.parametrize("text, field", [
    ("surface = 3\n" + PERSON, "surface"),
    ("evaluation = 5\n" + GRID_SURFACE + PERSON, "evaluation"),
    ("person = 3\n" + GRID_SURFACE, "person"),
    ("person = [\"x\"]\n" + GRID_SURFACE, "person[0]"),
    (GRID_SURFACE + "[person]\npose = \"db:x\"\n", "person"),  # ([person], not [[person]])
    (GRID_SURFACE + PERSON + "body = 0.5\n", "person[0].body"),
])
def test_a_scenario_whose_tables_are_not_tables_fails_its_own_jobs_under_a_grid(
        tmp_path, text, field):
    broken = tmp_path / "broken.toml"
    broken.write_text(text)
    grid = parse_grid(["sigma=0.01", "evaluation.friction=0.4", "relief.rounds=0",
                       "body.weight=0.3"])
    jobs = expand_jobs([SEATED, broken], grid=grid)
    good, bad = jobs
    assert good.problem == "" and good.data["person"][0]["body"]["weight"] == 0.3
    assert bad.problem.startswith(f"{broken}: ") and field in bad.problem


def test_one_bad_file_among_good_ones_is_a_failed_job_and_the_batch_exits_1(
        tmp_path, monkeypatch, capsys):
    """The CLI, with a grid over every person's body, a scenario whose `person` is a number:
    that job is failed (exit status 1, valid JSON); it used to crash the batch with a
    TypeError before any job ran. (The runner is replaced: no fit is needed to show it.)"""
    broken = tmp_path / "broken.toml"
    broken.write_text("person = 3\n" + GRID_SURFACE)

    def fake_run(jobs, out, **kw):
        rows = [{"job": j.id, "scenario": j.scenario, "parameters": j.parameters,
                 "status": "failed" if j.problem else "ok", "error": j.problem}
                for j in jobs]
        return {"out": str(out), "jobs": rows, "stored": [], "seconds": 0.0,
                "counts": {"total": 2, "skipped": 0, "done": 1, "failed": 1, "timed_out": 0,
                           "running": 0}}

    monkeypatch.setattr(batch, "run_batch", fake_run)
    assert main(["batch", str(SEATED), str(broken), "--grid", "body.weight=0.3",
                 "--out", str(tmp_path / "out"), "--json"]) == 1
    result = json.loads(capsys.readouterr().out)
    assert [r["status"] for r in result["jobs"]] == ["ok", "failed"]
    assert "person" in result["jobs"][1]["error"]


def _finished_job(out: Path) -> tuple[batch.Job, Path]:
    """A job of the seated example with a finished record and report written as a job
    writes them (figures of one made-up person), without fitting; the job and its folder."""
    (job,) = expand_jobs([SEATED])
    folder = out / "jobs" / job.id
    folder.mkdir(parents=True)
    person = {"coverage": 0.9, "max_penetration_m": 0.02, "peak_pressure_kpa": 7.0,
              "peak_of_flat": 0.8, "equilibrium": {"stable": True},
              "flat": {"same_load": {"peak_pressure_kpa": 9.0}}}
    report = {"iterations": 12, "persons": [person]}
    row = {"job": job.id, "scenario": job.scenario, "parameters": job.parameters,
           "status": "ok", "seconds": 1.0, "error": "", "iterations": 12,
           **batch.summary_figures(report["persons"])}
    (folder / "report.json").write_text(json.dumps(report))
    (folder / "result.json").write_text(json.dumps(batch._full_row(row)))
    return job, folder


def test_a_finished_job_is_trusted_only_beside_its_own_whole_report(tmp_path):
    job, folder = _finished_job(tmp_path)
    assert batch._finished(tmp_path, job)["coverage_min"] == 0.9  # (whole, matching: skipped)
    report = folder / "report.json"
    whole = report.read_text()
    report.write_text(whole[:100])  # cut short
    assert batch._finished(tmp_path, job) is None
    report.write_text(json.dumps({"iterations": 12}))  # no people
    assert batch._finished(tmp_path, job) is None
    edited = json.loads(whole)
    edited["persons"][0]["coverage"] = 0.5  # another report than the record's
    report.write_text(json.dumps(edited))
    assert batch._finished(tmp_path, job) is None
    report.unlink()
    assert batch._finished(tmp_path, job) is None


def test_a_rerun_over_a_damaged_report_runs_the_job_again_and_stores_it(tmp_path,
                                                                       monkeypatch):
    """A re-run with --db over a finished job whose report.json was cut short: the job is
    run again (here: a stand-in writing a whole report), not skipped and then failing the
    whole batch as the library store reads the damaged report."""
    from tests.conftest import high_sit_library

    db = high_sit_library(tmp_path / "poses.h5")
    out = tmp_path / "out"
    job, folder = _finished_job(out)
    whole = (folder / "report.json").read_text()
    (folder / "report.json").write_text(whole[:100])
    def fake_run_job(job, db, out_root, time_limit, stop_event):  # (on a worker)
        (Path(out_root) / "jobs" / job.id / "report.json").write_text(whole)
        return json.loads((Path(out_root) / "jobs" / job.id / "result.json").read_text())

    monkeypatch.setattr(batch, "run_job", fake_run_job)
    result = run_batch([job], out, db=db, workers=1)
    assert result["counts"]["skipped"] == 0 and result["counts"]["done"] == 1
    assert result["stored"] == [job.id]


def test_a_scenario_file_given_twice_is_refused(tmp_path, capsys):
    """The same file twice made one job twice: run once, but counted, summarised and stored
    twice."""
    with pytest.raises(BatchError, match="single_seated.toml: the same scenario given twice"):
        expand_jobs([SEATED, SEATED], grid={"sigma": [0.01, 0.02]})
    assert main(["batch", str(SEATED), str(SEATED), "--out", str(tmp_path / "o")]) == 2
    assert "given twice" in capsys.readouterr().err and not (tmp_path / "o").exists()
