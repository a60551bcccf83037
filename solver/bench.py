"""The benchmark runner behind `sitrelax bench`.

Each entry is timed as the median of several runs after one warm-up run; an entry with a
baseline (an independent implementation of the same job) is timed in the same session so the
speed-up is a ratio measured under the same conditions.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Iterable

from capture.bench import BenchCase

EXAMPLES = Path(__file__).resolve().parent / "data" / "scenarios"  # the example scenarios


def _skinning_setup():
    from solver.body.model import make_body
    from solver.body.poses import load_pose, pose_body

    body = make_body()
    motion = pose_body(load_pose("bundled:cmu_75_18_high_sit.bvh#frame=39"), body)
    return body, motion.frame(0)


def _skinning(arg):
    from solver.body.skinning import skin

    body, pose = arg
    return skin(body, pose)


def _posed_setup():
    from solver.body.skinning import skin

    body, pose = _skinning_setup()
    return skin(body, pose, normals=False)[0], body.triangles


def _pressure(arg):
    from solver.contact.pressure import pressure_field

    return pressure_field(*arg)


def _pressure_equilibrium(arg):
    from solver.contact.pressure import pressure_field

    return pressure_field(*arg, model="equilibrium")


def _pressure_reference(arg):
    from solver.contact.rigid_mould import rigid_mould_contact

    return rigid_mould_contact(*arg)


def _grid_setup():
    from solver.surface.subdivision import grid_mesh

    return grid_mesh(resolution=(8, 6))


def _subdivide_fresh(arg):
    from solver.surface import subdivision as sd

    verts, quads = arg
    sd._CACHE.clear()  # built from scratch every time
    return sd.subdivision(len(verts), quads, 3).apply(verts)


def _example_path(name: str) -> Path:
    """An example scenario, as shipped in solver/data/scenarios (fixtures/scenarios links there)."""
    path = EXAMPLES / f"{name}.toml"
    if not path.exists():
        raise BenchUnavailable(f"the example scenario {path} is missing from this install")
    return path


def _example(name: str):
    """An example scenario loaded, its people placed, and its fit parameters."""
    from solver.scene.scenario import load_scenario
    from solver.scene.placement import place_person

    scenario = load_scenario(_example_path(name))
    people = [place_person(p, None, k) for k, p in enumerate(scenario.persons)]
    return scenario, people, scenario.surface.params


def _fit_setup():
    return _example("single_seated")


def _fit_six_setup():
    return _example("six_overlapping")


def _fit(arg):
    from solver.surface.fit import fit_surface

    scenario, targets, params = arg
    return fit_surface(scenario.surface.vertices, scenario.surface.faces, targets, params)


def _refit_setup():
    """single_seated fitted once, and its person moved 2 cm forward (the way they face)."""
    from dataclasses import replace

    import numpy as np

    from solver.scene.placement import place_person

    scenario, people, params = _fit_setup()
    first = _fit((scenario, people, params))
    spec = scenario.persons[0]
    moved = replace(spec, position=tuple(np.asarray(spec.position) + [0.0, 0.0, 0.02]))
    return scenario, [place_person(moved, None, 0)], params, first


def _refit_warm(arg):
    from solver.surface.fit import fit_surface

    scenario, targets, params, first = arg
    return fit_surface(scenario.surface.vertices, scenario.surface.faces, targets, params,
                       warm=first)


def _spin() -> None:
    while True:  # a busy core until terminated
        pass


class _BusyCores:
    """One busy process per core, started on first use and kept until `stop` (or exit): the
    load under which `fit_under_load` runs, while the idle baseline of the same session runs
    after `stop`."""

    def __init__(self):
        self.processes: list = []

    def start(self) -> None:
        import atexit
        import multiprocessing
        import os

        if self.processes:
            return
        context = multiprocessing.get_context("fork")
        self.processes = [context.Process(target=_spin, daemon=True)
                          for _ in range(os.cpu_count() or 1)]
        for process in self.processes:
            process.start()
        atexit.register(self.stop)

    def stop(self) -> None:
        for process in self.processes:
            process.terminate()
        for process in self.processes:
            process.join()
        self.processes = []


def _load_setup():
    return _fit_setup(), _BusyCores()


def _fit_loaded(arg):
    fit, load = arg
    load.start()  # the warm-up run pays for the start
    return _fit(fit)


def _fit_idle(arg):
    fit, load = arg
    load.stop()  # the baseline's warm-up run pays for the stop
    return _fit(fit)


def _relax_setup():
    """The overweight body on the seat fitted for the thin one (the paper's figure 8): the
    relaxation problem, the gate of the evaluation's figures and those figures before, as
    `relax_person` has them."""
    from solver.contact.evaluate import SupportGate
    from solver.mesh import quad_triangles
    from solver.scene.placement import place_person
    from solver.scene.run import fit_people, foams, relax_problem

    thin, targets, params = _example("seat_for_thin")
    heavy, _, _ = _example("seat_for_heavy")
    fit = fit_people(thin, targets)
    person = place_person(heavy.persons[0], None, 0)
    foam, _ = foams(heavy.evaluation)
    problem = relax_problem(person, fit.surface, quad_triangles(fit.surface_faces),
                            margin=params.margin, foam=foam, floor=0.0)
    gate = SupportGate(problem.surface_mesh(), person.importance, person.triangles,
                       params.margin, foam, 0.0)
    return problem, gate, gate.figures(person.vertices)


def _relax(arg):
    from solver.body.relax import relax

    problem, gate, before = arg
    return relax(problem, gate=gate, figures_before=before)


def _relax_numeric(arg):
    from solver.body.relax import relax

    problem, gate, before = arg
    return relax(problem, gate=gate, figures_before=before, numeric_jacobian=True)


def _relax_person_setup():
    """The same, as `sitrelax relax` runs it: the scenario, the person and the surface."""
    from solver.scene.placement import place_person
    from solver.scene.run import fit_people

    thin, targets, _ = _example("seat_for_thin")
    heavy, _, _ = _example("seat_for_heavy")
    fit = fit_people(thin, targets)
    return heavy, place_person(heavy.persons[0], None, 0), fit.surface, fit.surface_faces


def _relax_person(arg):
    from solver.scene.run import relax_person

    return relax_person(*arg)


def _settle_setup():
    """The seated person on its fitted seat (and the floor), with what the evaluation has
    already computed for the settle (every vertex's closest point on the seat, the vertices
    the seat cuts into, the supports)."""
    from solver.contact.evaluate import cut_vertices, surface_parts
    from solver.contact.settle import Support
    from solver.mesh import SurfaceMesh
    from solver.scene.run import foams
    from solver.surface.fit import fit_surface

    scenario, people, params = _fit_setup()
    fit = fit_surface(scenario.surface.vertices, scenario.surface.faces, people, params)
    mesh = SurfaceMesh.from_quads(fit.surface, fit.surface_faces)
    person = people[0]
    foam, floor = foams(scenario.evaluation)
    placed = mesh.closest(person.vertices)  # the evaluation has these for its coverage
    _, signed, _, _, closest = placed
    cut = cut_vertices(person.vertices, person.triangles, signed, closest, foam)
    supports = [Support("surface", foam, mesh, parts=surface_parts(person.regions)),
                Support("floor", floor)]
    return person, supports, cut, placed


def _settle(arg):
    from solver.contact.settle import settle

    person, supports, cut, placed = arg
    rest = settle(person.vertices, person.normals, person.areas, person.triangles,
                  person.mass_kg, supports, cut=cut, closest={0: placed})
    if not rest.stable:
        raise RuntimeError(f"settle bench: {rest.reason}")
    return rest


def _evaluate_setup():
    from solver.scene.run import foams
    from solver.surface.fit import fit_surface

    scenario, people, params = _fit_setup()
    fit = fit_surface(scenario.surface.vertices, scenario.surface.faces, people, params)
    return fit, people[0], params.margin, foams(scenario.evaluation)


def _evaluate(arg):
    from solver.contact.evaluate import evaluate_person
    from solver.mesh import SurfaceMesh

    fit, person, margin, (foam, floor) = arg
    mesh = SurfaceMesh.from_quads(fit.surface, fit.surface_faces)  # a fresh surface each time
    return evaluate_person(mesh, person, margin, foam, floor)


def _batch_setup():
    """24 fits (single_seated at 24 values of sigma), and two local clusters, of 2 workers and
    of 1, started and warmed (each worker's child process up, its imports and the body assets
    loaded) before any timing: what is timed is the jobs, not the start-up of either."""
    import atexit

    from distributed import Client

    from solver.scene.batch import expand_jobs, local_cluster, warm_workers

    sigmas = [round(0.001 * (k + 1), 4) for k in range(24)]
    jobs = expand_jobs([_example_path("single_seated")], grid={"sigma": sigmas})
    clusters = {}
    for workers in (2, 1):
        cluster = local_cluster(workers)
        with Client(cluster) as client:
            if warm_workers(client) != workers:
                raise RuntimeError(f"batch bench: not every one of {workers} workers started")
        clusters[workers] = cluster
        atexit.register(cluster.close)  # when the benchmarks are done
    return jobs, clusters


def _batch_on(workers: int):
    def run(arg):
        import tempfile

        from solver.scene.batch import run_batch

        jobs, clusters = arg
        with tempfile.TemporaryDirectory() as tmp:  # nothing finished before: all run
            result = run_batch(jobs, tmp, scheduler=clusters[workers].scheduler_address,
                               store=False)
        if result["counts"]["done"] != len(jobs):
            raise RuntimeError(f"batch bench: {result['counts']}")
        return result
    return run


def solver_cases() -> list[BenchCase]:
    return [
        BenchCase("skinning", "pose the 13,380-vertex body (vertices and normals), one frame",
                  _skinning_setup, _skinning, repeats=50),
        BenchCase("pressure", "pressure field of the seated 13,380-vertex body (areas, normals, "
                  "importance)", _posed_setup, _pressure, repeats=50),
        BenchCase("pressure_equilibrium", "equilibrium-aware importance (force and moment "
                  "balance, friction) on the same body", _posed_setup, _pressure_equilibrium,
                  _pressure, "the paper's model", repeats=30, baseline_repeats=30),
        BenchCase("pressure_reference", "rigid-mould reference on the same body",
                  _posed_setup, _pressure_reference, repeats=5),
        BenchCase("subdivision", "Catmull-Clark operator of an 8x6 grid to level 3, from "
                  "scratch, applied", _grid_setup, _subdivide_fresh, repeats=30),
        BenchCase("fit_single", "fit an 8x6 grid, level 3, to one seated person, to the "
                  "loop's stop", _fit_setup, _fit, repeats=5),
        BenchCase("fit_six", "fit a 52x6 grid, level 3, to six seated people, to the loop's "
                  "stop", _fit_six_setup, _fit, repeats=3),
        BenchCase("refit_warm", "refit single_seated from its fit after the person moved 2 "
                  "cm, to the loop's settling (warm: the last result, tau_max, reused rows)",
                  _refit_setup, _refit_warm, repeats=15),
        BenchCase("fit_under_load", "fit_single with one busy process per core running "
                  "(speedup: idle time over loaded time, so 0.4x is 2.5x slower)",
                  _load_setup, _fit_loaded, _fit_idle, "fit_single idle", repeats=5,
                  baseline_repeats=5),
        BenchCase("settle", "the seated 13,380-vertex body settling in equilibrium on its "
                  "fitted seat and the floor (given the vertices the seat cuts into)",
                  _settle_setup, _settle, repeats=15),
        BenchCase("evaluate", "the whole evaluation of that body on a fresh surface: coverage, "
                  "penetration, the settle, mat figures", _evaluate_setup, _evaluate,
                  repeats=7),
        BenchCase("relax", "relax one pose (the overweight body onto the thin body's seat) "
                  "with the analytic Jacobian, each round judged by the evaluation's figures "
                  "(those before given)", _relax_setup, _relax, _relax_numeric,
                  "finite-difference Jacobian", repeats=7, baseline_repeats=1),
        BenchCase("relax_person", "the same as `sitrelax relax` does it: the problem and its "
                  "guarded skin, the figures before, the relaxation, the figures after",
                  _relax_person_setup, _relax_person, repeats=5),
        BenchCase("batch_scaling", "24-job sigma sweep of single_seated (fit, evaluate, export, "
                  "pictures) on 2 local Dask workers, started and warmed before timing",
                  _batch_setup, _batch_on(2), _batch_on(1), "the same on 1 worker", repeats=3,
                  baseline_repeats=3, warmup=False),
    ]


_ABOVE: list[Callable[[], list]] = []


def register_cases(cases: Callable[[], list]) -> None:
    """Adds the entries of a package above the solver (its `cases` function), once."""
    if cases not in _ABOVE:
        _ABOVE.append(cases)


def all_cases() -> list[BenchCase]:
    """Every benchmark entry of every package, in layer order."""
    from capture import bench as capture_bench
    from posedb import bench as posedb_bench  # numpy: loaded when the benchmarks run

    above = [case for cases in _ABOVE for case in cases()]
    return list(capture_bench.cases()) + list(posedb_bench.cases()) + solver_cases() + above


class UnknownBenchmarkError(ValueError):
    """A benchmark name that no package declares."""


class BenchUnavailable(Exception):
    """An entry that cannot run here (its data is missing); reported, not fatal."""


def _median_time(fn: Callable[[object], object], arg: object, repeats: int,
                 warmup: bool = True, self_timed: bool = False) -> float:
    import statistics  # loaded when the benchmarks run

    if warmup:
        fn(arg)  # imports, caches, page cache
    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        seconds = fn(arg)
        times.append(float(seconds) if self_timed else time.perf_counter() - start)
    return statistics.median(times)


def run_benchmarks(
    names: Iterable[str] = (),
    repeats: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[dict]:
    """Runs the named entries (all when `names` is empty) and returns one dict per entry.

    Keys: name, description, median_s, repeats, and where a baseline exists baseline,
    baseline_median_s, speedup (baseline median / our median).

    `repeats` (timed runs per entry, each entry's own count when None) must be a whole number
    >= 1: ValueError otherwise, before anything runs. Each entry (its setup, warm-up and timed
    runs, and its baseline's) runs with the BLAS threads the product runs with
    (`solver.threads.limited_threads`, `SITRELAX_THREADS`), so that an entry calling a part of
    the fit or the evaluation directly is timed as the fit and the evaluation run it.
    """
    import numbers

    from solver.threads import limited_threads

    if repeats is not None and (isinstance(repeats, bool) or
                                not isinstance(repeats, numbers.Integral) or repeats < 1):
        raise ValueError(f"Expected repeats as a whole number >= 1 (or None), got {repeats!r}")
    cases = all_cases()
    known = {c.name: c for c in cases}
    names = list(names)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise UnknownBenchmarkError(
            f"Expected benchmark names from {sorted(known)}, got {unknown}"
        )
    chosen = [known[n] for n in names] if names else cases
    results = []
    for k, case in enumerate(chosen, start=1):
        if progress:
            progress(f"[{k}/{len(chosen)}] {case.name}: {case.description}")
        with limited_threads():
            row = _run_case(case, k, len(chosen), repeats, progress)
        results.append(row)
    return results


def _run_case(case: BenchCase, k: int, count: int, repeats: int | None,
              progress: Callable[[str], None] | None) -> dict:
    """One entry of `run_benchmarks`: its row (`skipped` when its data is missing)."""
    try:
        arg = case.setup()
    except BenchUnavailable as exc:
        return {"name": case.name, "description": case.description, "skipped": str(exc)}
    n = case.repeats if repeats is None else repeats
    row = {"name": case.name, "description": case.description,
           "median_s": _median_time(case.run, arg, n, case.warmup, case.self_timed),
           "repeats": n}
    if case.per_second is not None:
        row["per_second"] = case.per_second / row["median_s"]
    if case.baseline is not None:
        nb = case.baseline_repeats if repeats is None else repeats
        if progress:
            progress(f"[{k}/{count}] {case.name}: baseline {case.baseline_name}")
        base = _median_time(case.baseline, arg, nb, case.warmup, case.self_timed)
        row.update(baseline=case.baseline_name, baseline_median_s=base,
                   baseline_repeats=nb, speedup=base / row["median_s"])
    return row


def format_table(rows: list[dict]) -> str:
    """A plain-text table of benchmark results, its columns as wide as their widest entry."""
    width = max([len("name")] + [len(r["name"]) for r in rows])
    bwidth = max([len("baseline")] + [len(r.get("baseline") or "") for r in rows])
    head = (f"{'name':<{width}} {'median':>11} {'per second':>12} {'baseline':<{bwidth}} "
            f"{'baseline median':>16} {'speedup':>9}")
    lines = [head, "-" * len(head)]
    for r in rows:
        if "skipped" in r:
            lines.append(f"{r['name']:<{width}} skipped: {r['skipped']}")
            continue
        base = r.get("baseline") or ""
        bmed = f"{r['baseline_median_s'] * 1e3:.1f} ms" if "baseline_median_s" in r else ""
        speed = f"{r['speedup']:.1f}x" if "speedup" in r else ""
        rate = f"{r['per_second']:,.0f}" if "per_second" in r else ""
        lines.append(f"{r['name']:<{width}} {r['median_s'] * 1e3:>8.2f} ms {rate:>12} "
                     f"{base:<{bwidth}} {bmed:>16} {speed:>9}")
    return "\n".join(lines)
