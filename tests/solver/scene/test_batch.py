"""Batches: grids, a broken scenario, re-runs, the library's copy, a real Dask scheduler and a
worker killed mid-batch."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from posedb import PoseLibrary
from solver.scene.batch import BatchError, expand_jobs, parse_grid, run_batch
from solver.cli import main
from tests.conftest import high_sit_library

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"


@pytest.fixture()
def library(tmp_path):
    return high_sit_library(tmp_path / "poses.h5",
                            [(frame, f"perch_{frame}", ["sit"]) for frame in (35, 39)])


def test_grid_and_template_expand_to_jobs(library, tmp_path):
    grid = parse_grid(["sigma=0.003,0.01", "body.weight=0.2,0.8"])
    assert grid == {"sigma": [0.003, 0.01], "body.weight": [0.2, 0.8]}
    jobs = expand_jobs(from_db="sit", template=EXAMPLES / "single_seated.toml", db=library,
                       grid=grid)
    assert len(jobs) == 2 * 4 and len({j.id for j in jobs}) == 8
    for job in jobs:
        (person,) = job.data["person"]
        assert person["pose"] in ("db:perch_35", "db:perch_39")
        assert job.data["surface"]["sigma"] == job.parameters["sigma"]
        assert person["body"]["weight"] == job.parameters["body.weight"]
    with pytest.raises(BatchError, match="expected numbers"):
        parse_grid(["sigma=a,b"])
    for bad in ("nan", "inf", "-inf"):
        with pytest.raises(BatchError, match=f"--grid sigma: expected finite numbers, got "
                                             f"'{bad}'"):
            parse_grid([f"sigma=0.003,{bad}"])
    assert parse_grid(["level=3.0,2"]) == {"level": [3, 2]}  # whole however written
    assert type(parse_grid(["level=3.0"])["level"][0]) is int
    with pytest.raises(BatchError, match="--grid colour"):
        expand_jobs([EXAMPLES / "single_seated.toml"], grid={"colour": [1]})
    # relief swept like any other table: each job's scenario asks for its rounds and aim
    relief = expand_jobs([EXAMPLES / "single_seated.toml"],
                         grid=parse_grid(["relief.rounds=0,3", "relief.target=0.4,0.5"]))
    assert sorted((j.data["relief"]["rounds"], j.data["relief"]["target"]) for j in relief) == \
        [(0, 0.4), (0, 0.5), (3, 0.4), (3, 0.5)]
    from solver.scene.scenario import parse_scenario

    (job,) = [j for j in relief if j.parameters == {"relief.rounds": 3, "relief.target": 0.4}]
    assert parse_scenario(job.data, "job", EXAMPLES).relief.model_dump() == \
        {"rounds": 3, "target": 0.4}
    with pytest.raises(BatchError, match="No pose"):
        expand_jobs(from_db="lying", template=EXAMPLES / "single_seated.toml", db=library)


@pytest.mark.slow
def test_batch_runs_records_failures_stores_and_skips(library, tmp_path, capsys):
    broken = tmp_path / "broken.toml"
    broken.write_text("[surface]\nsigma = -1\n")
    out = tmp_path / "out"
    before = library.read_bytes()
    args = ["batch", "--from-db", "sit", "--template", str(EXAMPLES / "single_seated.toml"),
            "--grid", "sigma=0.003,0.01", "--db", str(library), "--out", str(out),
            "--workers", "2", "--json"]
    assert main(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["counts"] == {"total": 4, "skipped": 0, "done": 4, "failed": 0,
                                "timed_out": 0, "running": 0}
    # a broken file among good ones: recorded, the rest done (status 1: a job failed)
    assert main(["batch", str(broken), str(EXAMPLES / "single_seated.toml"), "--out",
                 str(tmp_path / "mixed"), "--workers", "1", "--json"]) == 1
    mixed = json.loads(capsys.readouterr().out)
    status = {Path(r["scenario"]).name: r for r in mixed["jobs"]}
    assert status["single_seated.toml"]["status"] == "ok"
    assert status["broken.toml"]["status"] == "failed"
    assert "surface" in status["broken.toml"]["error"]

    # the summary and the library agree job for job; the poses were not touched
    rows = json.loads((out / "summary.json").read_text())
    csv_lines = (out / "summary.csv").read_text().strip().splitlines()
    assert len(csv_lines) == 1 + len(rows) == 5
    lib = PoseLibrary(library)
    stored = {s["name"]: s for s in lib.scenarios()}
    assert set(stored) == {r["job"] for r in rows}
    for row in rows:
        entry = stored[row["job"]]
        assert entry["result"]["summary"] == row
        assert entry["scenario"]["surface"]["sigma"] == row["parameters"]["sigma"]
        report = json.loads((out / "jobs" / row["job"] / "report.json").read_text())
        assert row["coverage_min"] == min(p["coverage"] for p in report["persons"])
        assert row["coverage_min"] > 0.5
        # the flat seat the seat is judged against: at the same load, where the body rests
        (person,) = report["persons"]
        if person["flat"]["same_load"]:
            assert row["flat_peak_pressure_kpa_max"] == \
                person["flat"]["same_load"]["peak_pressure_kpa"] > 0
            assert row["peak_of_flat_max"] == person["peak_of_flat"] > 0
        else:
            assert row["peak_of_flat_max"] is None
    assert lib.search_poses("sit") == ["perch_35", "perch_39"]
    assert library.read_bytes() != before

    # a re-run skips what finished and changes nothing in the results
    assert main(args) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["counts"]["skipped"] == 4 and again["counts"]["done"] == 0
    assert json.loads((out / "summary.json").read_text()) == rows


@pytest.mark.slow  # the default run stays within its time
def test_a_batch_on_one_local_worker_records_a_failure_stores_and_skips(library, tmp_path,
                                                                       capsys):
    """The default run's smoke test of `sitrelax batch`: one good job and one broken one on a
    single local worker, stored in the library; a re-run of the good one skips it."""
    broken = tmp_path / "broken.toml"
    broken.write_text("[surface]\nsigma = -1\n")
    out = tmp_path / "out"
    good = str(EXAMPLES / "single_seated.toml")
    assert main(["batch", str(broken), good, "--db", str(library), "--out", str(out),
                 "--workers", "1", "--json"]) == 1  # (a job failed)
    result = json.loads(capsys.readouterr().out)
    assert result["counts"] == {"total": 2, "skipped": 0, "done": 1, "failed": 1,
                                "timed_out": 0, "running": 0}
    status = {Path(r["scenario"]).name: r for r in result["jobs"]}
    assert status["single_seated.toml"]["status"] == "ok"
    assert status["single_seated.toml"]["coverage_min"] > 0.5
    assert status["broken.toml"]["status"] == "failed"
    assert "surface" in status["broken.toml"]["error"]
    assert len((out / "summary.csv").read_text().strip().splitlines()) == 3
    ok = status["single_seated.toml"]["job"]
    assert [s["name"] for s in PoseLibrary(library).scenarios()] == [ok]
    assert main(["batch", good, "--out", str(out), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["counts"]["skipped"] == 1 and again["jobs"][0]["job"] == ok


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(args, **kw):
    return subprocess.Popen([sys.executable, "-m", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True, **kw)


@pytest.mark.slow
def test_a_dask_scheduler_with_two_workers_and_one_killed(tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [_start(["distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port",
                     str(port), "--no-dashboard"])]
    try:
        time.sleep(2.0)
        for _ in range(2):
            procs.append(_start(["distributed.cli.dask_worker", address, "--nthreads", "1",
                                 "--no-nanny", "--host", "127.0.0.1", "--no-dashboard"]))
        jobs = expand_jobs([EXAMPLES / "single_seated.toml"],
                           grid={"sigma": [0.002, 0.003, 0.005, 0.01, 0.02, 0.03]})
        killed = {}

        def progress(counts):  # kill one worker once the first job is in
            if not killed:
                os.killpg(procs[1].pid, signal.SIGKILL)
                killed["at"] = counts["done"]

        remote = run_batch(jobs, tmp_path / "remote", scheduler=address, progress=progress)
        assert killed and remote["counts"]["done"] == 6 and remote["counts"]["failed"] == 0
        local = run_batch(jobs, tmp_path / "local", workers=2)
        numbers = ("coverage_min", "max_penetration_m", "peak_pressure_kpa_max", "iterations")
        for r, l in zip(remote["jobs"], local["jobs"], strict=True):
            # the same jobs, the same answers (to rounding: BLAS may sum in another order)
            assert (r["job"], r["status"]) == (l["job"], l["status"]) == (r["job"], "ok")
            # (a peak is None for a body that finds no rest: then on both)
            assert [k for k in numbers if r[k] is None] == [k for k in numbers if l[k] is None]
            assert {k: r[k] for k in numbers if r[k] is not None} == pytest.approx(
                {k: l[k] for k in numbers if l[k] is not None}, rel=1e-9)
    finally:
        for proc in procs:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(20)


@pytest.mark.slow
def test_warm_workers_start_each_job_process_once_and_answer_as_a_fresh_batch(tmp_path):
    """Two warmed workers, then a batch on them: every worker was ready, and the jobs' answers
    are those of a batch on a fresh cluster of one worker."""
    from distributed import Client

    from solver.scene.batch import local_cluster, warm_workers

    jobs = expand_jobs([EXAMPLES / "single_seated.toml"], grid={"sigma": [0.002, 0.02]})
    cluster = local_cluster(2)
    try:
        with Client(cluster) as client:
            assert warm_workers(client) == 2
        warm = run_batch(jobs, tmp_path / "warm", scheduler=cluster.scheduler_address)
    finally:
        cluster.close()
    fresh = run_batch(jobs, tmp_path / "fresh", workers=1)
    numbers = ("coverage_min", "max_penetration_m", "iterations")
    for w, f in zip(warm["jobs"], fresh["jobs"], strict=True):
        assert (w["job"], w["status"]) == (f["job"], f["status"]) == (w["job"], "ok")
        assert {k: w[k] for k in numbers} == pytest.approx({k: f[k] for k in numbers},
                                                          rel=1e-9)


def test_summary_figures_judge_the_seated_against_their_flat_seat_and_skip_standers():
    """A sitter with a same-load flat seat and a stander leaning on a wall (no seat load: no
    flat seat to be judged against): the flat-seat columns are the sitter's; with no sitter
    they are empty; a person without rest empties the peak column."""
    from solver.scene.batch import summary_figures

    sitter = {"coverage": 0.97, "max_penetration_m": 0.02, "peak_pressure_kpa": 7.6,
              "peak_of_flat": 0.78, "equilibrium": {"stable": True},
              "flat": {"peak_pressure_kpa": None,
                       "same_load": {"peak_pressure_kpa": 9.8, "fitted_peak_kpa": 7.6}}}
    stander = {"coverage": 0.95, "max_penetration_m": 0.025, "peak_pressure_kpa": 4.5,
               "peak_of_flat": None, "equilibrium": {"stable": True},
               "flat": {"peak_pressure_kpa": 202.8, "same_load": None}}
    row = summary_figures([sitter, stander])
    assert row == {"coverage_min": 0.95, "max_penetration_m": 0.025,
                   "peak_pressure_kpa_max": 7.6, "flat_peak_pressure_kpa_max": 9.8,
                   "peak_of_flat_max": 0.78, "all_rest": True}
    alone = summary_figures([stander])
    assert alone["flat_peak_pressure_kpa_max"] is None and alone["peak_of_flat_max"] is None
    tipped = dict(stander, peak_pressure_kpa=None, equilibrium={"stable": False})
    row = summary_figures([sitter, tipped])
    assert row["peak_pressure_kpa_max"] is None and row["all_rest"] is False
    assert row["peak_of_flat_max"] == 0.78


@pytest.mark.parametrize("value, message", [
    ("1_0", "expected numbers, got '1_0'"),  # (float() reads it as 10)
    ("1e-400", "too small: it would be read as 0"),
    ("-2.5e-999", "too small"),
])
def test_a_grid_value_no_one_means_as_read_is_refused(value, message):
    with pytest.raises(BatchError, match=message):
        parse_grid([f"sigma=0.003,{value}"])
    assert parse_grid(["sigma=0e5,1e-3"]) == {"sigma": [0, 0.001]}  # a zero written as one stays
