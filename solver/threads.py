"""BLAS thread control in one place (threadpoolctl).

The solver's dense and sparse products are small (an 8x6 control mesh, a few thousand surface
points): spreading each over several BLAS threads costs more in hand-offs than it gains, and on
a shared machine the threads compete with the other processes. So the fit and the evaluation
run with `blas_threads()` BLAS threads: 1 unless the environment variable `SITRELAX_THREADS`
says otherwise (a count, or ``all`` for the library's own choice). Batch workers get one BLAS
thread each through their environment (`worker_environment`), since they run side by side.

libigl's loops (normals, winding numbers, distances) start threads of their own on every call
unless told otherwise, and on a busy machine each call then waits for its threads to be
scheduled; libigl reads its count (`IGL_NUM_THREADS`) once, when it first runs, so importing
this module (as `solver.mesh` does, below every use of libigl) sets it to `blas_threads()` unless
the environment already says.

A fit gives the same surface with one thread or several (tested to 1e-12).

Apart from BLAS, a fit overlaps its two independent halves of judging a step (the pairing,
energy and folds; the depths and rows against the bodies, nearest-point searches that run
outside Python's lock) on a second thread when `overlapped()` says so: when the machine gives
this process at least two cores (its CPU affinity: a container's CPU quota is not seen),
`SITRELAX_THREADS` is unset or ``all`` and the machine's cores are not all busy with other work
as the fit starts (`cores_busy`), or when it is a count of two or more (which also gives BLAS
that many). `SITRELAX_THREADS=1` (what batch workers get) keeps every fit on one thread. The
surface is the same either way (tested bit for bit).
"""

from __future__ import annotations

import functools
import os
from contextlib import contextmanager
from typing import Callable, Iterator, TypeVar

ENV = "SITRELAX_THREADS"
DEFAULT_THREADS = 1
# what a worker process's BLAS and OpenMP read at start-up
_WORKER_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                     "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "IGL_NUM_THREADS")
IGL_ENV = "IGL_NUM_THREADS"  # libigl's own count, read once per process

F = TypeVar("F", bound=Callable)


class ThreadsError(ValueError):
    """A thread count that is not a positive integer (nor ``all``)."""


def blas_threads() -> int | None:
    """The BLAS thread count the solver runs with.

    Returns
    -------
    int or None
        `SITRELAX_THREADS` as a positive integer, `DEFAULT_THREADS` when it is unset or empty,
        None (no limit: the library's own count) when it is ``all``.

    Raises
    ------
    ThreadsError
        If `SITRELAX_THREADS` is neither a positive integer nor ``all``.
    """
    value = os.environ.get(ENV, "").strip()
    if not value:
        return DEFAULT_THREADS
    if value.lower() == "all":
        return None
    try:
        count = int(value)
    except ValueError:
        count = 0
    if count < 1:
        raise ThreadsError(f"Expected {ENV} to be a positive integer or 'all', got {value!r}")
    return count


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # (not every platform has affinity)
        return os.cpu_count() or 1


def overlapped() -> bool:
    """Whether a fit overlaps its independent searches on a second thread.

    Returns
    -------
    bool
        True when this process may use at least two cores, `SITRELAX_THREADS` is unset, empty
        or ``all`` and the machine's cores are not all busy with other work (`cores_busy`), or
        when it is a count of two or more (as asked); False for a count of one.

    Raises
    ------
    ThreadsError
        If `SITRELAX_THREADS` is neither a positive integer nor ``all``.
    """
    count = blas_threads()
    if os.environ.get(ENV, "").strip() and count is not None:
        return count >= 2
    return _cores() >= 2 and not cores_busy()


LOADAVG = "/proc/loadavg"  # Linux: its fourth field is "runnable/all" tasks at this moment


def cores_busy(path: str | None = None) -> bool:
    """Whether other work holds every core of the machine at this moment: at least as many
    other tasks are runnable as the machine has cores (Linux's `/proc/loadavg`, which counts the
    machine's tasks, a container's host's included; False where it cannot be read). A fit's
    second thread then waits for its turn at every step: with both of two cores busy, 1.3-6.7 s
    a fit on two threads against 0.66-0.79 s on one (0.2 s idle). A process held to a few cores
    of a larger machine is not told apart from an idle one (its own cores' load is not read)."""
    try:
        with open(path or LOADAVG, encoding="ascii") as file:
            runnable = int(file.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return False
    return runnable - 1 >= (os.cpu_count() or 1)  # (this process's reading thread is one)


@functools.lru_cache(maxsize=1)
def _controller():
    # finding the loaded BLAS libraries takes milliseconds; the limit itself microseconds
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@contextmanager
def limited_threads(threads: int | None = -1) -> Iterator[None]:
    """A context in which BLAS uses at most `threads` threads (restored on exit).

    Parameters
    ----------
    threads : int or None, optional
        The count; None for no limit; by default `blas_threads()`.

    Returns
    -------
    context manager
        Limits the threads of every BLAS library loaded when it was first used.
    """
    count = blas_threads() if threads == -1 else threads
    if count is None:
        yield
        return
    with _controller().limit(limits=count, user_api="blas"):
        yield


def with_limited_threads(func: F) -> F:
    """`func` run inside `limited_threads()` (a decorator).

    Parameters
    ----------
    func : callable
        The function to wrap.

    Returns
    -------
    callable
        The same function, its BLAS threads limited while it runs.
    """
    @functools.wraps(func)
    def limited(*args, **kwargs):
        with limited_threads():
            return func(*args, **kwargs)
    return limited  # type: ignore[return-value]


def worker_environment(threads: int = 1) -> dict[str, str]:
    """Environment variables that give a new process `threads` BLAS and OpenMP threads.

    Parameters
    ----------
    threads : int, default 1
        Threads per process (batch workers run side by side: one each).

    Returns
    -------
    dict
        Variable name to value, `SITRELAX_THREADS` included.
    """
    value = str(int(threads))
    return {**{name: value for name in _WORKER_VARIABLES}, ENV: value}


def _set_library_threads() -> None:
    """libigl's thread count from `blas_threads()`, unless the environment sets it (or the
    count is ``all``, or bad: the fit says so when it runs)."""
    try:
        count = blas_threads()
    except ThreadsError:
        return
    if count is not None:
        os.environ.setdefault(IGL_ENV, str(count))


_set_library_threads()
