"""A batch's jobs run under a time limit: a job that never ends (its control mesh a FIFO that
no one writes) is stopped and recorded as timed out, and the others finish."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from solver.scene.batch import expand_jobs, run_batch

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"
FOREVER = """[surface]
control_mesh = "{mesh}"

[[person]]
pose = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
"""


@pytest.mark.slow  # the default run stays within its time
def test_a_never_ending_job_times_out(tmp_path):
    """The default run's smoke test: one FIFO job on one worker, a 2 s limit."""
    os.mkfifo(tmp_path / "never.obj")
    path = tmp_path / "forever.toml"
    path.write_text(FOREVER.format(mesh="never.obj"))
    start = time.monotonic()
    result = run_batch(expand_jobs([path]), tmp_path / "out", workers=1, time_limit=2.0)
    assert [row["status"] for row in result["jobs"]] == ["timeout"]
    assert result["counts"]["timed_out"] == 1 and time.monotonic() - start < 30


@pytest.mark.slow
def test_two_never_ending_jobs_time_out_and_the_others_finish(tmp_path):
    scenarios = [EXAMPLES / "single_seated.toml"]
    for k in range(2):
        os.mkfifo(tmp_path / f"never{k}.obj")
        path = tmp_path / f"forever{k}.toml"
        path.write_text(FOREVER.format(mesh=f"never{k}.obj"))
        scenarios.append(path)
    os.mkfifo(tmp_path / "scenario_fifo.toml")  # a scenario on a FIFO: refused, not read
    scenarios.append(tmp_path / "scenario_fifo.toml")
    start = time.monotonic()
    jobs = expand_jobs(scenarios)
    assert time.monotonic() - start < 5.0
    # a single_seated job takes ~5-7 s here (fit, pictures, export) with both cores busy
    result = run_batch(jobs, tmp_path / "out", workers=2, time_limit=12.0)
    status = [(row["scenario"], row["status"]) for row in result["jobs"]]
    assert [s for n, s in status if "single_seated" in n] == ["ok"]
    assert [s for n, s in status if "forever" in n] == ["timeout"] * 2
    assert [s for n, s in status if "scenario_fifo" in n] == ["failed"]
    assert result["counts"]["timed_out"] == 2
    timed_out = next(r for r in result["jobs"] if r["status"] == "timeout")
    assert "time limit of 12 s" in timed_out["error"] and timed_out["seconds"] < 20
    assert (tmp_path / "out" / "summary.csv").read_text().count("timeout") == 2
    assert time.monotonic() - start < 60
