"""A batch on a Dask scheduler not started by it, interrupted mid-job: the job's process on the
worker ends within a couple of seconds, whether the client is stopped with Ctrl-C (then the
summary marks the jobs interrupted and no result of theirs appears), killed outright (the
worker goes on serving others), or loses its scheduler."""

from __future__ import annotations

import errno
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from tests.solver.scene.test_batch import _free_port, _start

ROOT = Path(__file__).resolve().parents[3]
FOREVER = """[surface]
control_mesh = "{mesh}"

[[person]]
pose = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
"""


def _has_reader(fifo: Path, held: list[int]) -> bool:
    """Whether a process has `fifo` open for reading (a job waiting on it); if so, it is kept
    open for writing (its fd appended to `held`) so the reader goes on waiting, never at EOF."""
    try:
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno == errno.ENXIO:  # (no reader)
            return False
        raise
    held.append(fd)
    return True


def _wait_for(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"waited {timeout:g} s for {what}")
        time.sleep(0.05)


def _listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


# (about 4 s each: a scheduler, and a worker whose job process loads its modules)
@pytest.mark.parametrize("stop", [pytest.param("ctrl_c", marks=pytest.mark.slow),
                                  pytest.param("client_killed", marks=pytest.mark.slow),
                                  pytest.param("scheduler_killed", marks=pytest.mark.slow)])
def test_an_interrupted_client_stops_the_jobs_on_a_schedulers_worker(tmp_path, stop):
    """Two never-ending jobs (control meshes that are FIFOs no one writes) on a scheduler with
    one worker of one thread: once the first waits on its FIFO, the client is sent Ctrl-C
    (SIGINT), or the client or the scheduler is killed. The job's process ends within 3 s (not
    at its 120 s time limit) and the other job never starts; the worker is still there unless
    its scheduler went. The client exits with 130 after Ctrl-C, with 2 when its scheduler went,
    and then the summary says both jobs were interrupted; no result is written."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    scenarios = []
    for k in range(2):
        os.mkfifo(tmp_path / f"never{k}.obj")
        path = tmp_path / f"forever{k}.toml"
        path.write_text(FOREVER.format(mesh=f"never{k}.obj"))
        scenarios.append(path)
    fifos = [tmp_path / f"never{k}.obj" for k in range(2)]
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    procs = [_start(["distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port",
                     str(port), "--no-dashboard"])]
    held: list[int] = []
    client = None
    try:
        _wait_for(lambda: _listening(port), 30, "the scheduler")
        procs.append(_start(["distributed.cli.dask_worker", address, "--nthreads", "1",
                             "--no-nanny", "--host", "127.0.0.1", "--no-dashboard"]))
        client = subprocess.Popen(
            [sys.executable, "-m", "studio.cli", "batch", *map(str, scenarios),
             "--scheduler", address, "--job-time-limit", "120", "--out", str(out)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
            start_new_session=True)
        waiting = []

        def a_job_waits() -> bool:
            assert client.poll() is None, "the batch ended before its job started"
            for fifo in fifos:
                if _has_reader(fifo, held):
                    waiting.append(fifo)
                    return True
            return False

        _wait_for(a_job_waits, 90, "a job to wait on its FIFO")
        worker = psutil.Process(procs[1].pid)
        children = [p for p in worker.children(recursive=True)
                    if "_serve_jobs" in " ".join(p.cmdline())]
        assert len(children) == 1
        sent = time.monotonic()
        if stop == "scheduler_killed":
            os.killpg(procs[0].pid, signal.SIGKILL)
        else:
            os.killpg(client.pid, signal.SIGINT if stop == "ctrl_c" else signal.SIGKILL)
        gone, _ = psutil.wait_procs(children, timeout=3.0)
        assert gone, f"the job's process was still running {time.monotonic() - sent:.1f} s on"
        code = client.wait(30)
        if stop != "scheduler_killed":
            assert procs[1].poll() is None  # (the worker is not the batch's to end)
        time.sleep(1.5)  # (time for a job wrongly started to open its FIFO)
        other = next(f for f in fifos if f not in waiting)
        assert not _has_reader(other, held), "a job started after the batch was stopped"
        assert not list(out.glob("jobs/*/result.json"))
        if stop != "client_killed":
            assert code == (130 if stop == "ctrl_c" else 2)
            rows = json.loads((out / "summary.json").read_text())
            assert [r["status"] for r in rows] == ["interrupted"] * 2
        if stop == "ctrl_c":
            assert all("interrupted" in r["error"] for r in rows)
            cut = next(r for r in rows if Path(r["scenario"]).stem[-1] == waiting[0].stem[-1])
            assert cut["error"] == "the job was stopped: the batch was interrupted"
    finally:
        for fd in held:
            os.close(fd)
        for proc in ([client] if client is not None else []) + procs:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(20)
