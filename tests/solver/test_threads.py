"""Thread control (solver.threads): the count from SITRELAX_THREADS, the limit applied and
restored, and a fit that gives the same surface with one BLAS thread or all of them."""

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from solver.contact.supported import SupportedBody
from solver.surface.fit import FitParams, fit_surface
from solver.surface.subdivision import grid_mesh
from solver.threads import (ENV, ThreadsError, blas_threads, limited_threads,
                            worker_environment)


def _blas_counts() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


@pytest.mark.parametrize("value, count", [(None, 1), ("", 1), ("3", 3), ("all", None),
                                          ("ALL", None)])
def test_the_count_comes_from_the_environment(monkeypatch, value, count):
    if value is None:
        monkeypatch.delenv(ENV, raising=False)
    else:
        monkeypatch.setenv(ENV, value)
    assert blas_threads() == count


@pytest.mark.parametrize("value", ["0", "-2", "two", "1.5"])
def test_a_bad_count_names_the_variable(monkeypatch, value):
    monkeypatch.setenv(ENV, value)
    with pytest.raises(ThreadsError, match=f"Expected {ENV} to be a positive integer or 'all', "
                                           f"got '{value}'"):
        blas_threads()


def test_the_limit_holds_inside_and_is_restored_after(monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    before = _blas_counts()
    with limited_threads():
        assert set(_blas_counts()) <= {1}
    assert _blas_counts() == before


def test_workers_get_one_thread_each():
    env = worker_environment()
    assert env["OMP_NUM_THREADS"] == env["OPENBLAS_NUM_THREADS"] == env[ENV] == "1"


def _small_fit():
    # a cap of points under a 5x4 grid: a few iterations, a few dozen milliseconds
    grid_v, grid_f = grid_mesh((1.0, 0.8), (5, 4), 0.45)
    rng = np.random.default_rng(7)
    xz = rng.uniform([-0.3, -0.25], [0.3, 0.25], size=(300, 2))
    points = np.column_stack([xz[:, 0], 0.47 + 0.3 * (xz ** 2).sum(axis=1), xz[:, 1]])
    normals = np.tile([0.0, -1.0, 0.0], (len(points), 1))
    target = SupportedBody(points, normals, np.full(len(points), 1.0), "cap")
    return fit_surface(grid_v, grid_f, [target], FitParams(level=2, max_iterations=6))


def test_a_fit_gives_the_same_surface_with_one_thread_or_all(monkeypatch):
    monkeypatch.setenv(ENV, "1")
    one = _small_fit()
    monkeypatch.setenv(ENV, "all")
    every = _small_fit()
    assert one.iterations == every.iterations
    np.testing.assert_allclose(one.surface, every.surface, rtol=0, atol=1e-12)
    np.testing.assert_allclose(one.control, every.control, rtol=0, atol=1e-12)


def test_libigl_gets_the_count_before_it_first_runs():
    """libigl reads IGL_NUM_THREADS once: importing the mesh layer sets it to the solver's
    count (one by default; `all` leaves libigl its own), unless the environment already has
    it."""
    import os
    import subprocess
    import sys

    code = "import os, solver.mesh; print(os.environ.get('IGL_NUM_THREADS'))"
    base = {k: v for k, v in os.environ.items() if k not in ("IGL_NUM_THREADS", ENV)}
    runs = {"": "1", "3": "3", "all": "None"}
    for value, expected in runs.items():
        out = subprocess.run([sys.executable, "-c", code], env={**base, ENV: value},
                             capture_output=True, text=True, check=True).stdout.split()[-1]
        assert out == expected, (value, out)
    kept = subprocess.run([sys.executable, "-c", code],
                          env={**base, "IGL_NUM_THREADS": "2"}, capture_output=True, text=True,
                          check=True).stdout.split()[-1]
    assert kept == "2"


@pytest.mark.parametrize("value, cores, overlap", [
    (None, 2, True), ("", 4, True), (None, 1, False), ("all", 2, True), ("all", 1, False),
    ("1", 2, False), ("2", 2, True), ("2", 1, True)])
def test_a_fit_overlaps_its_searches_unless_told_one_thread(monkeypatch, value, cores,
                                                             overlap):
    """Two threads when the process has two cores and the count is unset (or `all`), or when
    the count is two or more; one when it says 1 (what batch workers get)."""
    import solver.threads as threads

    monkeypatch.setattr(threads, "_cores", lambda: cores)
    monkeypatch.setattr(threads, "cores_busy", lambda: False)  # (whatever else runs now)
    if value is None:
        monkeypatch.delenv(ENV, raising=False)
    else:
        monkeypatch.setenv(ENV, value)
    assert threads.overlapped() is overlap


def test_workers_do_not_overlap(monkeypatch):
    import solver.threads as threads

    for name, value in worker_environment().items():
        monkeypatch.setenv(name, value)
    assert threads.overlapped() is False


@pytest.mark.parametrize("line, busy", [
    ("2.66 2.63 2.04 3/108 27543\n", True),  # two others runnable on two cores (and this one)
    ("0.29 0.78 1.15 2/108 27543\n", False),  # one core free for a second thread
    ("0.10 0.10 0.10 1/90 100\n", False),  # only this process
    ("", False), ("garbage\n", False),  # unreadable: as if idle
])
def test_the_cores_are_busy_when_other_work_holds_every_one(tmp_path, monkeypatch, line, busy):
    """A fit's second thread waits its turn at every step when other work holds every core
    (with both of two cores busy, 1.3-6.7 s a fit against 0.66-0.79 s on one thread): the
    tasks runnable at this moment, /proc/loadavg's fourth field, tell."""
    import solver.threads as threads

    monkeypatch.setattr(threads, "_cores", lambda: 2)
    monkeypatch.setattr(threads.os, "cpu_count", lambda: 2)
    loadavg = tmp_path / "loadavg"
    loadavg.write_text(line)
    assert threads.cores_busy(str(loadavg)) is busy
    monkeypatch.delenv(ENV, raising=False)
    monkeypatch.setattr(threads, "LOADAVG", str(loadavg))
    assert threads.overlapped() is (not busy)
    assert threads.cores_busy(str(tmp_path / "none")) is False  # (no such file: not Linux)
    monkeypatch.setenv(ENV, "2")  # (two threads asked for: two threads)
    assert threads.overlapped() is True
    monkeypatch.setattr(threads.os, "cpu_count", lambda: 64)  # (a larger machine's tasks)
    assert threads.cores_busy(str(loadavg)) is False
