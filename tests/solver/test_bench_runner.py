"""The benchmark runner's contract, on a cheap entry of its own: repeats refused at the boundary,
the medians and ratios as documented, and the BLAS threads the product runs with."""

import json
import math

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import solver.bench as bench
from capture.bench import BenchCase


def _blas_threads() -> list[int]:
    return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]


@pytest.fixture
def probe(monkeypatch):
    """An entry `probe` that records the BLAS threads it runs with and counts its runs, and a
    baseline `probe_base`, twice as slow by its own clock (self-timed)."""
    seen = {"threads": [], "runs": 0, "baseline_runs": 0}
    times = iter([1.0, 3.0, 2.0, 5.0, 4.0, 100.0])  # warm-up 1.0, then 3, 2, 5, 4: median 3.5

    def run(_):
        seen["threads"].append(_blas_threads())
        seen["runs"] += 1
        return next(times, 3.5)

    def baseline(_):
        seen["baseline_runs"] += 1
        return 7.0

    cases = [BenchCase("probe", "a cheap entry", lambda: None, run, baseline, "twice as slow",
                       repeats=4, baseline_repeats=2, self_timed=True)]
    monkeypatch.setattr(bench, "solver_cases", lambda: cases)
    monkeypatch.delenv("SITRELAX_THREADS", raising=False)
    return seen


@pytest.mark.parametrize("repeats", [0, -1, math.nan, math.inf, 1.5, True, "3"])
def test_repeats_that_are_not_a_whole_number_of_at_least_one_are_refused(probe, repeats):
    with pytest.raises(ValueError, match=r"Expected repeats as a whole number >= 1 \(or None\), "
                                         r"got"):
        bench.run_benchmarks(["probe"], repeats=repeats)
    assert probe["runs"] == 0  # (before anything ran)


def test_unknown_names_are_refused_with_the_known_ones(probe):
    with pytest.raises(bench.UnknownBenchmarkError, match=r"got \['nosuch'\]"):
        bench.run_benchmarks(["probe", "nosuch"])
    assert probe["runs"] == 0


def test_the_median_of_the_timed_runs_and_the_ratio_of_medians(probe):
    (row,) = bench.run_benchmarks(["probe"])
    assert row["repeats"] == 4 and probe["runs"] == 1 + 4  # a warm-up, then the timed runs
    assert row["median_s"] == 3.5  # of 3, 2, 5, 4 (the warm-up's 1.0 not counted)
    assert row["baseline_repeats"] == 2 and probe["baseline_runs"] == 1 + 2
    assert row["speedup"] == 7.0 / 3.5
    json.dumps(row, allow_nan=False)  # the --json output is valid JSON


def test_repeats_given_apply_to_the_entry_and_its_baseline(probe):
    (row,) = bench.run_benchmarks(["probe"], repeats=1)
    assert row["repeats"] == 1 and row["baseline_repeats"] == 1
    assert probe["runs"] == 2 and probe["baseline_runs"] == 2


def test_every_entry_runs_with_the_blas_threads_of_the_product(probe):
    """The fit and the evaluation run on one BLAS thread (`SITRELAX_THREADS` unset); an entry
    that calls a part of them directly (the settle, the pressure) is timed the same way, even
    where the process's BLAS would use more."""
    if not _blas_threads():
        pytest.skip("no BLAS library loaded that threadpoolctl can see")
    with threadpool_limits(limits=2, user_api="blas"):
        bench.run_benchmarks(["probe"])
        assert set(_blas_threads()) == {2}  # (restored afterwards)
    assert probe["threads"] and all(threads and set(threads) == {1}
                                    for threads in probe["threads"])
