"""Batches: a job's id covers the files its scenario reads, a result.json is trusted only when
whole, a grid names each setting and value once, every summary row has every field, and a local
cluster has no more workers than jobs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from capture import resolve_path
from posedb import PoseLibrary, PosePlacement
from solver.cli import main
from solver.scene import batch
from solver.scene.batch import (SUMMARY_FIELDS, BatchError, expand_jobs, parse_grid,
                                run_batch)
from solver.surface.subdivision import grid_mesh
from tests.conftest import high_sit_library

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"
SCENARIO = """[surface]
control_mesh = "m.obj"
level = 3
sigma = 0.003
tau_max = 0.5
margin = 0.03

[[person]]
pose = "{pose}"
facing = "capture"
support = "seat"
"""


def _write_obj(path: Path, height: float) -> None:
    vertices, faces = grid_mesh((0.5, 0.6), (8, 6), height)
    path.write_text("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices)
                    + "".join("f " + " ".join(str(i + 1) for i in f) + "\n" for f in faces))


def _scenario(folder: Path, pose: str = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    _write_obj(folder / "m.obj", 0.42)
    path = folder / "s.toml"
    path.write_text(SCENARIO.format(pose=pose))
    return path


def test_the_job_id_follows_the_files_the_scenario_reads(tmp_path):
    """The control mesh OBJ, a BVH file given by path and a library pose: each changed, the
    job is another; nothing changed, the same."""
    path = _scenario(tmp_path / "a")
    (first,) = expand_jobs([path])
    assert expand_jobs([path])[0].id == first.id
    _write_obj(tmp_path / "a" / "m.obj", 0.40)
    assert expand_jobs([path])[0].id != first.id

    bvh = tmp_path / "b" / "take.bvh"
    path = _scenario(tmp_path / "b", pose="bvh:take.bvh#frame=39")
    bvh.write_bytes(resolve_path("bundled:cmu_75_18_high_sit.bvh").read_bytes())
    before = expand_jobs([path])[0].id
    bvh.write_bytes(bvh.read_bytes() + b"\n")
    assert expand_jobs([path])[0].id != before

    db = high_sit_library(tmp_path / "poses.h5")
    lib = PoseLibrary(db)
    take = lib.takes()[0]
    path = _scenario(tmp_path / "c", pose="db:perch")
    before = expand_jobs([path], db=db)[0].id
    assert expand_jobs([path], db=db)[0].id == before
    with lib.edit() as ed:
        ed.delete_pose("perch")
    lib.add_pose(take.id, 35, "perch", tags=["sit"])  # the same name, another pose
    assert expand_jobs([path], db=db)[0].id != before
    before = expand_jobs([path], db=db)[0].id
    with lib.edit() as ed:  # the same pose, standing elsewhere (as a relaxation stores it)
        ed.delete_pose("perch")
        ed.add_pose(take.id, 35, "perch", tags=["sit"],
                    placement=PosePlacement((0.0, 0.06, 0.0), 0.0))
    assert expand_jobs([path], db=db)[0].id != before


def test_a_grid_names_each_setting_and_each_value_once(tmp_path, capsys):
    with pytest.raises(BatchError, match="--grid sigma: the same setting given twice"):
        parse_grid(["sigma=0.001", "sigma=0.002"])
    with pytest.raises(BatchError, match="--grid sigma and surface.sigma: the same setting"):
        parse_grid(["sigma=0.001", "surface.sigma=0.002"])
    with pytest.raises(BatchError, match="--grid sigma: expected each value once, got 0.003"):
        parse_grid(["sigma=0.003,0.003"])
    with pytest.raises(BatchError, match="--grid level: expected each value once, got 3"):
        parse_grid(["level=3.0,3"])  # (one whole number however written)
    with pytest.raises(BatchError, match="sigma and surface.sigma"):
        expand_jobs([EXAMPLES / "single_seated.toml"],
                    grid={"sigma": [0.001], "surface.sigma": [0.002]})
    for twice in (["sigma=0.001", "sigma=0.002"], ["sigma=0.001", "surface.sigma=0.002"],
                  ["sigma=0.003,0.003"]):
        args = ["batch", str(EXAMPLES / "single_seated.toml"), "--out", str(tmp_path / "o")]
        for item in twice:
            args += ["--grid", item]
        assert main(args) == 2
        assert "--grid sigma" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_failed_row_has_every_field_and_one_job_starts_one_worker(tmp_path, monkeypatch):
    broken = tmp_path / "broken.toml"
    broken.write_text("[surface]\nsigma = -1\n")
    started = []
    real = batch.local_cluster

    def counted(workers=2):
        started.append(workers)
        return real(workers)

    monkeypatch.setattr(batch, "local_cluster", counted)
    result = run_batch(expand_jobs([broken]), tmp_path / "out", workers=64)
    (row,) = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert row["status"] == "failed" and list(row)[:len(SUMMARY_FIELDS)] == list(SUMMARY_FIELDS)
    assert row["coverage_min"] is None and row["all_rest"] is None
    assert result["jobs"] == [row]
    record = json.loads((tmp_path / "out" / "jobs" / row["job"] / "result.json").read_text())
    assert set(SUMMARY_FIELDS) <= set(record)
    assert started == [1]


@pytest.mark.slow  # (3.5-7.5 s: the default run stays within its time)
def test_a_rerun_refits_after_the_obj_changed_and_distrusts_a_broken_record(tmp_path):
    path = _scenario(tmp_path / "d3")
    out = tmp_path / "out_obj"
    first = run_batch(expand_jobs([path]), out, workers=1)
    (row,) = first["jobs"]
    assert row["status"] == "ok" and first["counts"]["done"] == 1
    # a record that is not a whole one is not trusted: the job runs again
    record = out / "jobs" / row["job"] / "result.json"
    record.write_text(json.dumps({"status": "ok"}))
    again = run_batch(expand_jobs([path]), out, workers=1)
    assert again["counts"]["skipped"] == 0 and again["counts"]["done"] == 1
    assert again["jobs"][0]["job"] == row["job"] and again["jobs"][0]["coverage_min"] > 0.5
    assert json.loads(record.read_text())["coverage_min"] == again["jobs"][0]["coverage_min"]
    # unchanged: skipped
    assert run_batch(expand_jobs([path]), out, workers=1)["counts"]["skipped"] == 1
    # the OBJ edited: the job is another, and runs
    _write_obj(tmp_path / "d3" / "m.obj", 0.40)
    edited = run_batch(expand_jobs([path]), out, workers=1)
    assert edited["counts"]["skipped"] == 0 and edited["counts"]["done"] == 1
    assert edited["jobs"][0]["job"] != row["job"]
    assert (out / "jobs" / edited["jobs"][0]["job"] / "report.json").is_file()


@pytest.mark.slow  # (about 16 s: a batch stopped once its first job has finished)
def test_ctrl_c_stops_the_running_jobs_and_the_summary_matches_the_disk(tmp_path):
    """A batch of eight jobs on two workers, in a process group of its own, sent SIGINT (as a
    terminal's Ctrl-C) once its first job has finished (eight, not four: in a whole slow run on
    two busy cores the four had all ended, exit 0, before the Ctrl-C reached the batch): it ends
    with status 130, its processes end, and afterwards summary.json says `ok` for exactly the
    jobs with an `ok` result.json; the others are `interrupted` and no result of theirs appears
    later."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    root = Path(__file__).resolve().parents[3]
    env = dict(os.environ, PYTHONPATH=str(root), OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "studio.cli", "batch", str(EXAMPLES / "single_seated.toml"),
         "--grid", "sigma=0.002,0.003,0.004,0.005,0.006,0.008,0.01,0.012",
         "--workers", "2", "--out", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
        start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob("jobs/*/result.json")):
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.1)
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(30) == 130
        for _ in range(100):  # every process of the batch ends
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        else:
            pytest.fail("the batch's processes went on after it stopped")
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    time.sleep(8.0)  # longer than a job: one left running would have written its result
    rows = json.loads((out / "summary.json").read_text())
    assert len(rows) == 8 and {r["status"] for r in rows} <= {"ok", "interrupted"}
    assert "interrupted" in {r["status"] for r in rows}
    for row in rows:
        path = out / "jobs" / row["job"] / "result.json"
        on_disk = json.loads(path.read_text())["status"] if path.exists() else None
        assert (row["status"] == "ok") == (on_disk == "ok"), (row["job"], on_disk)
