"""Batches of fits: scenario files, or library poses in a template, times a parameter grid,
run on a local Dask cluster (processes) or on an existing Dask scheduler.

Each job fits, evaluates and exports as `sitrelax fit` does, into `OUT/jobs/<job id>/`, whose
`result.json` marks it finished (a re-run skips it: a job's id covers its scenario, its grid
point and what the files it reads hold, and a result.json is trusted only when whole). A job that
raises is recorded with its
error and the batch goes on; a job whose worker dies is given to another worker by Dask. Workers
only read the pose library; the client alone writes (the results, as scenarios, in one commit).

Each job runs in a child process of its worker (kept from job to job, so the imports are paid
once), which is killed when the job passes its time limit: the job is recorded as timed out and
the worker goes on. Setting up a batch reads nothing that can block (scenario files must be
regular files; control mesh files are read by the job, under its time limit).

An interrupted batch (Ctrl-C) stops its running jobs before it writes its summary: a local
cluster's processes are killed; on a scheduler not started here, the batch sets a Dask event
that each worker running one of its jobs looks at every `STOP_POLL` seconds, killing the job's
child and answering `interrupted`. A worker also stops its job when the scheduler no longer
wants it (the client closed or was killed) or when the worker closes (it lost its scheduler).
"""

from __future__ import annotations

import copy
import csv
import difflib
import hashlib
import io
import itertools
import json
import logging
import math
import os
import select
import signal
import stat
import subprocess
import sys
import threading
import time
import tomllib
import uuid
from concurrent.futures import CancelledError
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from capture.files import sigint_handled, write_atomic

from solver.threads import worker_environment

SURFACE_SHORTCUTS = {"level", "sigma", "tau_max", "margin", "gamma", "max_iterations",
                     "tolerance"}
DEFAULT_JOB_TIME_LIMIT = 1800.0  # seconds
MAX_SCENARIO_BYTES = 64 * 1024 * 1024
SUMMARY_FIELDS = ("job", "scenario", "parameters", "status", "seconds", "coverage_min",
                  "max_penetration_m", "peak_pressure_kpa_max", "flat_peak_pressure_kpa_max",
                  "peak_of_flat_max", "all_rest", "iterations", "error")


class BatchError(ValueError):
    """A batch that cannot be set up as asked (its message names the problem)."""


@dataclass(frozen=True)
class Job:
    """One fit: a scenario (TOML data, paths resolved against `base`) and the grid point."""

    id: str
    scenario: str  # where it came from: a file, or template + pose
    data: dict
    base: str
    parameters: dict
    problem: str = ""  # why the scenario cannot run (the job then fails, the batch goes on)

    def as_dict(self) -> dict:
        return {"id": self.id, "scenario": self.scenario, "parameters": self.parameters}


def parse_grid(items: Sequence[str]) -> dict[str, list]:
    """`key=v1,v2,...` items -> {key: [values]}; numbers become floats (ints when whole)."""
    grid: dict[str, list] = {}
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            raise BatchError(f"Expected --grid KEY=V1,V2,..., got {item!r}")
        parsed = []
        for v in values.split(","):
            v = v.strip()
            try:
                if "_" in v:  # (float() reads 1_0 as 10: no one means that)
                    raise ValueError(v)
                number = float(v)
            except ValueError:
                raise BatchError(f"--grid {key}: expected numbers, got {v!r}") from None
            if not math.isfinite(number):
                raise BatchError(f"--grid {key}: expected finite numbers, got {v!r}")
            if number == 0.0 and any(c in "123456789" for c in v.lower().partition("e")[0]):
                raise BatchError(f"--grid {key}: expected a number a float can hold, got {v!r} "
                                 "(too small: it would be read as 0)")
            # (a whole number is one however written: level=3.0 is level 3)
            parsed.append(int(number) if number.is_integer() and abs(number) < 2 ** 53 else
                          number)
        _check_once(list(grid), key)
        repeated = sorted({v for v in parsed if parsed.count(v) > 1})
        if repeated:
            raise BatchError(f"--grid {key}: expected each value once, got "
                             f"{', '.join(f'{v:g}' for v in repeated)} more than once")
        grid[key] = parsed
    return grid


def _setting(key: str) -> str:
    """The setting a grid key names: `sigma` and `surface.sigma` are one."""
    key = key.strip()
    return f"surface.{key}" if key in SURFACE_SHORTCUTS else key


def _check_once(earlier: Sequence[str], key: str) -> None:
    """A BatchError when grid `key` names the setting one of the `earlier` keys names."""
    same = [k for k in earlier if _setting(k) == _setting(key)]
    if same:
        named = key if same[0] == key else f"{same[0]} and {key}"
        raise BatchError(f"--grid {named}: the same setting given twice; give its values "
                         f"once, as {_setting(key)}=V1,V2,...")


GRID_KEYS_EXPECTED = ("expected sigma, tau_max, margin, level, surface.KEY, evaluation.KEY, "
                      "relief.KEY, body.KEY or person.KEY")
MAX_JOBS = 100_000  # a batch larger than this is refused before its jobs are made


def _grid_models() -> dict:
    """The scenario schema's model of each table a grid key can name."""
    from solver.scene import schema

    return {"surface": schema.Surface, "evaluation": schema.Evaluation,
            "relief": schema.Relief, "body": schema.BodyShape, "person": schema.Person}


def check_grid(grid: dict) -> None:
    """A BatchError when a grid key names no setting of a scenario, has no value, or has a
    value its setting never takes (the setting's type and bounds in the scenario schema):
    such a grid would fail every job it makes, so the batch is refused before any runs."""
    from typing import Annotated

    from pydantic import TypeAdapter, ValidationError

    models = _grid_models()
    for key, values in grid.items():
        table, _, name = _setting(key).partition(".")
        if table not in models or not name or "." in name:
            # a misspelt shortcut or table (`sigmaa`, `surfce.sigma`) gets a suggestion too
            known = sorted(SURFACE_SHORTCUTS) + [f"{t}.{n}" for t, model in models.items()
                                                 for n in model.model_fields]
            close = difflib.get_close_matches(key.strip(), known, n=1)
            hint = f"no such setting (did you mean {close[0]}?); " if close else ""
            raise BatchError(f"--grid {key}: {hint}{GRID_KEYS_EXPECTED}")
        fields = models[table].model_fields
        if name not in fields:
            close = difflib.get_close_matches(name, list(fields), n=1)
            hint = f"did you mean {table}.{close[0]}? " if close else ""
            raise BatchError(f"--grid {key}: {table} has no setting {name!r} ({hint}expected "
                             f"one of {sorted(fields)})")
        if not list(values):
            raise BatchError(f"--grid {key}: expected at least one value, got none")
        info = fields[name]
        adapter = TypeAdapter(Annotated[info.annotation, info])
        for value in values:
            try:
                adapter.validate_python(value)
            except ValidationError as exc:
                why = exc.errors(include_url=False)[0]["msg"]
                raise BatchError(f"--grid {key}: {table}.{name} cannot be {value!r} "
                                 f"({why[:1].lower()}{why[1:]})") from None


def _apply(data: dict, key: str, value) -> None:
    """Sets one grid key in scenario data: `sigma` (a surface shortcut), `surface.X`,
    `evaluation.X`, `relief.X` (rounds, target), or `body.X` / `person.X` for every
    person. A part of the scenario that is not a table (`surface = 3`, a `person` that is
    not a list of tables) is left as it is: the scenario's check then names it, and that job
    fails, not the batch."""
    parts = key.split(".")
    if len(parts) == 1 and parts[0] in SURFACE_SHORTCUTS:
        parts = ["surface", parts[0]]
    if parts[0] in ("surface", "evaluation", "relief") and len(parts) == 2:
        table = data.setdefault(parts[0], {})
        if isinstance(table, dict):
            table[parts[1]] = value
    elif parts[0] in ("body", "person") and len(parts) == 2:
        people = data.get("person", [])
        for person in people if isinstance(people, list) else []:
            if not isinstance(person, dict):
                continue
            if parts[0] == "person":
                person[parts[1]] = value
            elif isinstance(person.setdefault("body", {}), dict):
                person["body"][parts[1]] = value
    else:
        raise BatchError(f"--grid {key}: {GRID_KEYS_EXPECTED}")


def _job_id(scenario: str, data: dict, parameters: dict, inputs: dict | None = None) -> str:
    """`<scenario stem>-<hash>`: the hash of the scenario's data, the grid point and what the
    files the scenario reads hold (`_input_digests`), so a changed input is a new job."""
    stem = Path(scenario.split("#")[0]).stem or "job"
    digest = hashlib.sha1(json.dumps([scenario, data, parameters] + ([inputs] if inputs else []),
                                     sort_keys=True, default=str).encode()).hexdigest()[:10]
    return f"{stem}-{digest}"


def _file_digest(path: Path, cache: dict) -> str:
    """The SHA-1 of a regular file's bytes; for what is not one (missing, a FIFO, a folder),
    a word saying so: such a file is not read here, where it could block (its job reads it)."""
    key = str(path)
    if key not in cache:
        try:
            info = path.stat()
        except OSError:
            cache[key] = "missing"
        else:
            if not stat.S_ISREG(info.st_mode):
                cache[key] = "not a regular file"
            else:
                sha = hashlib.sha1()
                try:
                    with open(path, "rb") as fh:
                        for chunk in iter(lambda: fh.read(1 << 20), b""):
                            sha.update(chunk)
                    cache[key] = sha.hexdigest()
                except OSError as exc:
                    cache[key] = f"unreadable ({exc.strerror or exc})"
    return cache[key]


def _input_digests(data: dict, base: Path, library, cache: dict) -> dict:
    """What the files a scenario reads hold, by what the scenario calls them: its control mesh
    file, its people's joint-map files and BVH files (a bundled recording's too), each as the
    SHA-1 of its bytes, and each `db:` pose as the SHA-1 of its data in the library (`library`,
    a `PoseLibrary` or None: then the pose is named only)."""
    from capture import resolve_path

    inputs = {}
    surface = data.get("surface")
    mesh = surface.get("control_mesh") if isinstance(surface, dict) else None
    if isinstance(mesh, str):
        inputs[f"control_mesh:{mesh}"] = _file_digest(base / mesh, cache)
    people = data.get("person")
    for person in people if isinstance(people, list) else []:
        if not isinstance(person, dict):
            continue
        joint_map = person.get("joint_map")
        if isinstance(joint_map, str):
            inputs[f"joint_map:{joint_map}"] = _file_digest(base / joint_map, cache)
        pose = person.get("pose")
        if not isinstance(pose, str):
            continue
        if pose.startswith("bvh:"):
            file_part = pose[4:].split("#", 1)[0]
            try:
                path = resolve_path(file_part)
            except (FileNotFoundError, ValueError):
                inputs[pose] = "missing"
                continue
            inputs[pose] = _file_digest(path if file_part.startswith("bundled:")
                                        else base / file_part, cache)
        elif pose.startswith("db:"):
            inputs[pose] = _pose_digest(library, pose[3:], cache)
    return inputs


def _pose_digest(library, name: str, cache: dict) -> str:
    """The SHA-1 of a library pose's data (skeleton, rotations, root position, and where it
    stands when it carries a placement: `posedb.PosePlacement`)."""
    key = f"db:{name}"
    if library is None:
        return "no library given"
    if key not in cache:
        try:
            info, skeleton, rotations, root = library.pose_data(name)
        except (KeyError, ValueError, OSError) as exc:
            cache[key] = f"unreadable ({type(exc).__name__})"
        else:
            import numpy as np

            sha = hashlib.sha1()
            sha.update(json.dumps([list(skeleton.names), np.asarray(skeleton.parents).tolist(),
                                   skeleton.unit_m, skeleton.joint_map], default=str).encode())
            for array in (skeleton.offsets, rotations, root):
                sha.update(np.ascontiguousarray(array, dtype=np.float64).tobytes())
            if info.placement is not None:  # (a pose without one keeps the digest it had)
                sha.update(np.array([*info.placement.offset, info.placement.heading],
                                    dtype=np.float64).tobytes())
            cache[key] = sha.hexdigest()
    return cache[key]


def expand_jobs(scenarios: Sequence[str | os.PathLike] = (), *, grid: dict | None = None,
                from_db: str | None = None, template: str | os.PathLike | None = None,
                db: str | os.PathLike | None = None) -> list[Job]:
    """The batch's jobs: every scenario (or every library pose matching `from_db`, put into
    each person of `template`) at every point of `grid`. A job's id covers the scenario, the
    grid point and what the files the scenario reads hold (its control mesh, joint maps and
    BVH files, and its `db:` poses' data in `db`), so a re-run runs again a job whose inputs
    changed."""
    grid = {key: list(values) for key, values in (grid or {}).items()}
    keys = list(grid)
    for k, key in enumerate(keys):
        _check_once(keys[:k], key)
    check_grid(grid)
    points = math.prod(len(grid[k]) for k in keys)
    if points > MAX_JOBS:  # (refused before a job is made: they would not fit in memory)
        raise BatchError(f"The grid has {points} points; a batch has at most {MAX_JOBS} jobs")
    sources: list[tuple[str, dict, Path]] = []
    if from_db is not None:
        if template is None or db is None:
            raise BatchError("--from-db needs --template and --db")
        from posedb import PoseLibrary

        names = PoseLibrary(db).search_poses(from_db)
        if not names:
            raise BatchError(f"No pose in {db} matches {from_db!r}")
        base_data = _read_toml(template)
        for name in names:
            data = copy.deepcopy(base_data)
            for person in data.get("person", []):
                person["pose"] = f"db:{name}"
            sources.append((f"{template}#pose={name}", data, Path(template).parent))
    for path in scenarios:
        try:
            sources.append((str(path), _read_toml(path), Path(path).parent))
        except BatchError as exc:  # a broken file is a failed job, not a failed batch
            sources.append((str(path), {"problem": str(exc)}, Path(path).parent))
    if not sources:
        raise BatchError("Expected scenario files, or --from-db with --template")
    if len(sources) * points > MAX_JOBS:
        raise BatchError(f"{len(sources)} scenarios times {points} grid points make "
                         f"{len(sources) * points} jobs; a batch has at most {MAX_JOBS}")
    library = None
    if db is not None and Path(db).is_file():
        from posedb import PoseLibrary

        try:
            library = PoseLibrary(db)
        except (OSError, ValueError):  # (its jobs fail, each with the library's reason)
            library = None
    digests: dict = {}
    jobs = []
    for scenario, data, base in sources:
        for values in itertools.product(*(grid[k] for k in keys)) if keys else [()]:
            point = dict(zip(keys, values))
            job_data = copy.deepcopy(data)
            problem = job_data.pop("problem", "") if set(job_data) == {"problem"} else ""
            if not problem:
                for k, v in point.items():
                    _apply(job_data, k, v)
                problem = _problem(job_data, scenario, base)  # checked before anything runs
            inputs = _input_digests(job_data, base, library, digests) if not problem else {}
            jobs.append(Job(_job_id(scenario, job_data, point, inputs), scenario, job_data,
                            str(base.resolve()), point, problem))
    seen: dict[str, Job] = {}
    for job in jobs:  # (one job twice would run once and count twice)
        if job.id in seen:
            raise BatchError(f"{job.scenario}: the same scenario given twice; give each "
                             f"scenario file once")
        seen[job.id] = job
    return jobs


def _problem(data: dict, scenario: str, base: Path) -> str:
    """Why a job's scenario cannot run, as far as can be told without reading a file (a
    control mesh file could block: the job reads it, under its time limit); "" if none."""
    from solver.scene import schema
    from solver.scene.scenario import ScenarioError, parse_scenario

    try:
        model = schema.validate(copy.deepcopy(data), scenario)
        mesh = model.surface.control_mesh
        if isinstance(mesh, str):
            if not (base / mesh).exists():  # a stat: it does not block
                return f"{scenario}: surface.control_mesh: no file {base / mesh}"
            return ""
        parse_scenario(copy.deepcopy(data), scenario, base)
    except ScenarioError as exc:
        return str(exc)
    return ""


def _read_toml(path: str | os.PathLike) -> dict:
    path = Path(path)
    try:
        info = path.stat()
    except OSError:
        raise BatchError(f"No scenario file {path}") from None
    if not stat.S_ISREG(info.st_mode):  # a FIFO or a device could block the batch
        raise BatchError(f"{path}: a scenario must be a regular file")
    if info.st_size > MAX_SCENARIO_BYTES:
        raise BatchError(f"{path}: {info.st_size} bytes; a scenario file has at most "
                         f"{MAX_SCENARIO_BYTES}")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise BatchError(f"{path}: not a valid TOML scenario: {exc}") from None


def _full_row(row: dict) -> dict:
    """A summary row with every field of `SUMMARY_FIELDS` (None where it has no value: a failed
    job has no coverage), in that order, then any others it has."""
    return {**{field: row.get(field) for field in SUMMARY_FIELDS}, **row}


def _run_here(job: Job, db: str | None, out_root: str) -> dict:
    """Runs one job in this process; returns its summary row (a failure is a row too)."""
    from solver.scene.run import run_fit
    from solver.scene.scenario import parse_scenario

    folder = Path(out_root) / "jobs" / job.id
    folder.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    row = {"job": job.id, "scenario": job.scenario, "parameters": job.parameters}
    try:
        if job.problem:
            raise BatchError(job.problem)
        scenario = parse_scenario(copy.deepcopy(job.data), job.scenario, Path(job.base))
        report = run_fit(scenario, folder, db=db, beside=False)  # (a worker per core)
    except Exception as exc:  # recorded; the batch goes on
        row.update(status="failed", seconds=time.perf_counter() - start,
                   error=f"{type(exc).__name__}: {exc}")
    else:
        row.update(status="ok", seconds=time.perf_counter() - start, error="",
                   iterations=report["iterations"], **summary_figures(report["persons"]))
    row = _full_row(row)
    write_atomic(folder / "result.json", json.dumps(row, indent=2).encode())
    return row


class _Runner:
    """A child process running jobs one at a time (JSON lines in and out), so that a job
    past its time limit can be killed without the worker."""

    def __init__(self):
        root = str(Path(__file__).resolve().parents[2])  # where `solver` is importable from
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        env.update(worker_environment(1))  # jobs run side by side: one BLAS thread each
        self.proc = subprocess.Popen(
            [sys.executable, "-c", "from solver.scene.batch import _serve_jobs; _serve_jobs()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        # the imports are not a job's time: the child says when it is ready
        self.ready = self.proc.stdout.readline() == b"ready\n"

    def run(self, job: Job, db: str | None, out_root: str, time_limit: float,
            stop: Callable[[], str] | None = None) -> dict | str:
        """The job's row, or why there is none: "timeout", STOPPED (`stop`, asked every
        `STOP_POLL` seconds while the job runs, gave a reason to stop it: the child is
        killed), or the child's end."""
        message = {"job": {**job.__dict__}, "db": db, "out_root": out_root}
        try:
            self.proc.stdin.write(json.dumps(message).encode() + b"\n")
            self.proc.stdin.flush()
        except OSError:
            return f"its process ended (exit code {self.proc.poll()})"
        deadline = time.monotonic() + time_limit
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                self.kill()
                return "timeout"
            wait = left if stop is None else min(left, STOP_POLL)
            ready, _, _ = select.select([self.proc.stdout], [], [], wait)
            if ready:
                break
            if stop is not None and stop():
                self.kill()
                return STOPPED
        line = self.proc.stdout.readline()
        if not line:
            return f"its process ended (exit code {self.proc.wait()})"
        return json.loads(line)

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait()


def _load_job_modules() -> None:
    """What a job uses, loaded before the first job's clock starts: the modules (the lazy ones
    too), the body assets (which every job's first body would otherwise decompress), the colour
    map, and threadpoolctl's list of the loaded BLAS libraries."""
    import igl  # noqa: F401
    import osqp  # noqa: F401 (the fit's programme; ~17 ms)
    import PIL.Image  # noqa: F401 (the pictures)
    import PIL.ImageDraw  # noqa: F401
    import scipy.optimize  # noqa: F401 (the settle's fallback)
    import scipy.sparse.csgraph  # noqa: F401 (the fit's guarantees)

    import solver.body.posture  # noqa: F401 (the report's posture)
    import solver.io.export  # noqa: F401
    import solver.io.render  # noqa: F401
    import solver.io.sheet  # noqa: F401
    import solver.io.solid  # noqa: F401
    import solver.scene.cad  # noqa: F401
    import solver.scene.run  # noqa: F401
    import solver.scene.sheet  # noqa: F401
    import solver.surface.limit  # noqa: F401
    from solver.body.model import make_body
    from solver.io.raster import viridis_table
    from solver.threads import limited_threads

    make_body()
    viridis_table()
    with limited_threads():  # threadpoolctl finds the loaded BLAS libraries once
        pass


def _serve_jobs() -> None:
    """The child's loop: a job a line on stdin, its row a line on stdout. It ends with its
    worker (`_orphaned`), mid-job too."""
    parent = os.getppid()
    threading.Thread(target=_orphaned, args=(parent,), daemon=True).start()
    out = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)  # whatever the job prints goes to stderr, not into the answers
    _load_job_modules()

    out.write("ready\n")
    out.flush()
    for line in sys.stdin:
        m = json.loads(line)
        row = _run_here(Job(**m["job"]), m["db"], m["out_root"])
        out.write(json.dumps(row) + "\n")
        out.flush()


def _orphaned(parent: int) -> None:
    """Ends this process once its parent (the worker) has gone: a batch stopped (Ctrl-C) leaves
    no job running on; an unfinished job's files are as a failed run leaves them (its results
    folder as it was, `capture.files.results_folder`)."""
    while os.getppid() == parent:
        time.sleep(ORPHAN_POLL)
    os._exit(1)


ORPHAN_POLL = 0.5  # s: how often a job's child looks whether its worker is still there
STOP_POLL = 0.5  # s: how often a worker looks whether its running job is to be stopped
STOP_WAIT = 10.0  # s: how long an interrupted client waits for its workers to stop their jobs
STOPPED = "stopped"  # (what `_Runner.run` returns for a job it was asked to stop)

_runners = threading.local()


def _runner() -> _Runner:
    """This worker's child process, started when there is none (or it ended)."""
    runner = getattr(_runners, "runner", None)
    if runner is None or runner.proc.poll() is not None:
        runner = _runners.runner = _Runner()
    return runner


def start_runner() -> bool:
    """Starts the worker's child process (its imports and the body assets loaded) before any
    job is given to it; whether it is ready. Run on each worker by `warm_workers`."""
    return _runner().ready


def warm_workers(client) -> int:
    """Starts every worker's child process, all at once, and waits until they are ready, so
    that the jobs that follow pay no start-up. Returns how many workers are ready."""
    workers = list(client.scheduler_info()["workers"])
    futures = [client.submit(start_runner, key=f"sitrelax-warm-{k}", workers=[w],
                             allow_other_workers=False, pure=False)
               for k, w in enumerate(workers)]
    return sum(bool(f.result()) for f in futures)


# Dask's housekeeping on a local cluster, made rarer: a batch's cores are its jobs'. By default
# every process (the scheduler and nannies in the client's, each worker) checks its event loop
# every 20 ms, each nanny and worker measures the worker's memory every 100 ms, and each process
# samples its CPU and memory every 500 ms: idle, a 2-worker cluster takes ~10 % of a core, taken
# from the jobs when every core runs one. Jobs last seconds and run in child processes whose
# memory Dask does not see, so coarser intervals lose nothing. The scheduler gives a worker one
# job at a time (not 2 of 1.1 x 1 thread, rounded up), so no job waits queued behind a long one
# on one worker while the other worker has nothing left to do at the end of a batch.
LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,  # a stack sample every 10 ms, for the dashboard
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.scheduler.worker-saturation": 1.0,
}


def local_cluster(workers: int = 2):
    """A local Dask cluster for batches: `workers` processes of one thread each, on the
    loopback interface, with `LOCAL_CLUSTER_CONFIG` (no statistical profiler, rarer
    housekeeping, a job at a time per worker)."""
    import dask
    from distributed import LocalCluster

    with dask.config.set(LOCAL_CLUSTER_CONFIG), sigint_handled(signal.SIG_IGN):
        # (its processes, and the jobs' children they start, ignore the terminal's Ctrl-C:
        # the batch stops them itself, without a traceback from each)
        return LocalCluster(n_workers=max(1, int(workers)), threads_per_worker=1,
                            processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0")


def run_job(job: Job, db: str | None, out_root: str,
            time_limit: float = DEFAULT_JOB_TIME_LIMIT, stop_event: str | None = None) -> dict:
    """Runs one job on a worker, in its child process, for at most `time_limit` seconds;
    returns its summary row (a failure or a timeout is a row too). The job is stopped (its
    child killed, within `STOP_POLL` seconds, and the row says `interrupted`; no result is
    written) when the batch sets the Dask event named `stop_event`, when the batch no longer
    wants the job (its client closed, or went away), or when the worker closes (it lost its
    scheduler)."""
    start = time.perf_counter()
    # (a job cancelled as the batch stops, Ctrl-C, is no news for this worker to log: the
    # batch says it was interrupted)
    logging.getLogger("distributed.worker.state_machine").setLevel(logging.ERROR)
    stop = _stop_reason(stop_event)
    why = stop() if stop is not None else ""
    ran = not why
    if ran:
        runner = _runner()
        got = (runner.run(job, db, out_root, time_limit, stop) if runner.ready
               else "it did not start")
        if isinstance(got, dict):
            return got
        _runners.runner = None
        why = stop() if got == STOPPED else ""
    if why:  # (cut short, the job leaves its earlier result as it was)
        return _full_row(_interrupted(job, f"the job was {'stopped' if ran else 'not started'}: "
                                           f"{why}", seconds=time.perf_counter() - start))
    if got == "timeout":
        status, error = "timeout", (f"TimeoutError: the job ran over the batch's time limit "
                                    f"of {time_limit:g} s and was stopped")
    else:
        status, error = "failed", f"ChildProcessError: {got}"
    row = _full_row({"job": job.id, "scenario": job.scenario, "parameters": job.parameters,
                     "status": status, "seconds": time.perf_counter() - start, "error": error})
    folder = Path(out_root) / "jobs" / job.id
    folder.mkdir(parents=True, exist_ok=True)
    write_atomic(folder / "result.json", json.dumps(row, indent=2).encode())
    return row


def _stop_reason(stop_event: str | None) -> Callable[[], str] | None:
    """On a Dask worker, in the thread of the task running a job: a function saying why the
    job is to be stopped now ("" while it is not); None elsewhere. The reasons: the batch set
    the event named `stop_event` (Ctrl-C), the scheduler no longer wants the task (cancelled,
    or its client closed or went away: the scheduler releases a lost client's tasks), or the
    worker is closing (a worker that loses its scheduler closes). A scheduler that does not
    answer within `STOP_POLL` is asked again at the next look; the job's time limit bounds
    the rest."""
    from distributed import get_client, get_worker
    from distributed.core import Status

    try:
        worker = get_worker()
    except ValueError:  # (not in a task on a worker)
        return None
    key = worker.get_current_task()
    client = get_client() if stop_event else None
    said: list[str] = []  # (a job to be stopped stays so, for the reason first given)

    def reason() -> str:
        if not said:
            if worker.status in (Status.closing, Status.closed, Status.failed):
                said.append("its worker closed (it lost its scheduler)")
            elif getattr(worker.state.tasks.get(key), "state", "released") in (
                    "cancelled", "released", "forgotten"):
                said.append("the batch no longer wants it (its client closed or went away)")
            elif client is not None and _event_is_set(client, stop_event):
                said.append("the batch was interrupted")
        return said[0] if said else ""

    return reason


def _event_is_set(client, name: str) -> bool:
    """Whether the Dask event `name` is set; False when the scheduler does not answer within
    `STOP_POLL` seconds (`distributed.Event.is_set` has no time limit)."""
    try:
        return bool(client.sync(client.scheduler.event_is_set, name=name,
                                callback_timeout=STOP_POLL))
    except (OSError, TimeoutError):
        return False


# what a finished job's result.json must hold to be trusted: every field of a summary row,
# with these of these types (a record cut short, or edited by hand, is run again)
_OK_RECORD_TYPES = {"job": str, "scenario": str, "parameters": dict, "seconds": (int, float),
                    "coverage_min": (int, float), "max_penetration_m": (int, float),
                    "iterations": int, "all_rest": bool}


def _finished(out: Path, job: Job) -> dict | None:
    """The row of a job that finished before (`ok`, its record whole, and its report there,
    whole, with the record's figures), or None: then the job runs (again)."""
    folder = out / "jobs" / job.id
    try:
        row = json.loads((folder / "result.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(row, dict) or row.get("status") != "ok" or row.get("job") != job.id:
        return None
    if any(field not in row for field in SUMMARY_FIELDS):
        return None
    if any(not isinstance(row[field], kind) or (kind is not bool and isinstance(row[field], bool))
           for field, kind in _OK_RECORD_TYPES.items()):
        return None
    # its report must be there, whole, and the one the record was made from: the library
    # stores the report's people, and the summary's figures are the report's
    try:
        report = json.loads((folder / "report.json").read_text())
        figures = summary_figures(report["persons"])
        same = report["iterations"] == row["iterations"] and all(
            row[field] == value for field, value in figures.items())
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return _full_row(row) if same else None


def run_batch(jobs: Sequence[Job], out_dir: str | os.PathLike, *,
              db: str | os.PathLike | None = None, workers: int = 2,
              scheduler: str | None = None, store: bool = True,
              progress: Callable[[dict], None] | None = None,
              time_limit: float = DEFAULT_JOB_TIME_LIMIT) -> dict:
    """Runs the jobs not finished before, each for at most `time_limit` seconds (then it is
    stopped and counted as failed and as timed out); writes summary.csv and summary.json;
    stores the finished jobs' scenarios and results in the library (when `db` and `store`)."""
    from distributed import Client, as_completed

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    db_path = str(Path(db).resolve()) if db is not None else None
    rows: dict[str, dict] = {}
    todo = []
    for job in jobs:
        done = _finished(out, job)
        if done is not None:
            rows[job.id] = done
        else:
            todo.append(job)
    start = time.perf_counter()
    counts = {"total": len(jobs), "skipped": len(rows), "done": 0, "failed": 0,
              "timed_out": 0, "running": len(todo)}
    cluster = None
    if todo:
        if scheduler is None:
            cluster = local_cluster(min(workers, len(todo)))  # (an idle worker costs a start)
            client = Client(cluster)
        else:
            client = Client(scheduler)
        quieted: dict[str, int] = {}
        # (the event the jobs of this batch look at, set when it is interrupted)
        stop_event = f"sitrelax-stop-{uuid.uuid4().hex}"
        futures = []
        try:
            for job in todo:
                futures.append(client.submit(run_job, job, db_path, str(out.resolve()),
                                             time_limit, stop_event,
                                             key=f"sitrelax-job-{job.id}", pure=False,
                                             retries=2))
            for future in as_completed(futures):
                row = future.result()
                rows[row["job"]] = row = _full_row(row)
                counts["done" if row["status"] == "ok" else "failed"] += 1
                counts["timed_out"] += row["status"] == "timeout"
                counts["running"] -= 1
                if progress is not None:
                    finished = counts["done"] + counts["failed"]
                    elapsed = time.perf_counter() - start
                    progress({**counts, "elapsed_s": elapsed,
                              "left_s": elapsed / finished * counts["running"]})
        except KeyboardInterrupt:
            # Ctrl-C: the running jobs are stopped first, so that the summary (the jobs
            # finished so far, the others interrupted) says what the disk holds; a job that
            # finished while the batch stopped counts as finished
            if cluster is not None:
                for name in QUIET_WHEN_STOPPED:  # (the workers' end is no news: it is meant)
                    quieted[name] = logging.getLogger(name).level
                    logging.getLogger(name).setLevel(logging.CRITICAL)
                _stop_local_jobs(cluster)
            else:
                rows.update(_stop_remote_jobs(client, futures, stop_event))
            _write_summary(out, [_row_after_interrupt(out, job, rows.get(job.id))
                                 for job in jobs])
            raise
        except CancelledError as exc:
            # the jobs were lost under the batch: its scheduler went away (a worker that loses
            # its scheduler closes, and stops its job as it does: `_stop_reason`)
            why = getattr(exc, "reason", None) or "cancelled"
            # (the client's failed reconnection, logged as it closes, is no news: the batch
            # says it)
            quieted["distributed.client"] = logging.getLogger("distributed.client").level
            logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
            _write_summary(out, [_row_after_interrupt(
                out, job, rows.get(job.id),
                f"the batch lost its jobs ({why}) before this one finished") for job in jobs])
            raise BatchError(f"The batch lost its jobs ({why}); the summary in {out} holds the "
                             f"jobs finished so far and the others as interrupted (a re-run "
                             f"runs those)") from None
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
            for name, level in quieted.items():
                logging.getLogger(name).setLevel(level)
    ordered = [rows[job.id] for job in jobs]
    _write_summary(out, ordered)
    stored = _store(db_path, jobs, ordered, out) if (db_path and store) else []
    return {"out": str(out), "jobs": ordered, "counts": counts, "stored": stored,
            "seconds": time.perf_counter() - start}


# the loggers of a local cluster that say, as the batch stops it, that its workers went
QUIET_WHEN_STOPPED = ("distributed.scheduler", "distributed.nanny", "distributed.core",
                      "distributed.worker")


def _row_after_interrupt(out: Path, job: Job, row: dict | None,
                         why: str = "the batch was interrupted before it finished") -> dict:
    """A job's summary row once the batch is interrupted and its running jobs stopped: its row
    when it finished, else what the disk holds (a job that finished as the batch stopped is
    finished), else `interrupted`, with the worker's reason when it sent one, else `why`."""
    if row is not None and row.get("status") != "interrupted":
        return row
    return _finished(out, job) or {**_interrupted(job, why), **(row or {})}


def _interrupted(job: Job, error: str, **more) -> dict:
    """An `interrupted` row of a job, saying why (`more`: its other fields)."""
    return {"job": job.id, "scenario": job.scenario, "parameters": job.parameters,
            "status": "interrupted", "error": error, **more}


def _stop_remote_jobs(client, futures: Sequence, stop_event: str,
                      timeout: float = STOP_WAIT) -> dict[str, dict]:
    """Stops the jobs of a batch on a scheduler not started here: sets the batch's event
    (each worker running one of its jobs then kills the job's process within `STOP_POLL`
    seconds and answers `interrupted`; a job that starts later does not run), cancels the
    jobs no worker has started, and waits up to `timeout` seconds for the others' answers.
    Returns the rows received, by job id; a job whose worker did not answer in time has an
    `interrupted` row saying it may still finish. A second Ctrl-C does not cut this short."""
    left = [f for f in futures if not f.done()]
    rows: dict[str, dict] = {}
    with sigint_handled(signal.SIG_IGN):
        try:
            client.sync(client.scheduler.event_set, name=stop_event, callback_timeout=timeout)
            started = {key for keys in client.sync(client.scheduler.processing,
                                                   callback_timeout=timeout).values()
                       for key in keys}
        except (OSError, TimeoutError):  # (the scheduler is gone: its workers close)
            return rows
        client.cancel([f for f in left if f.key not in started])
        running = [f for f in left if f.key in started]
        deadline = time.monotonic() + timeout
        while not all(f.done() for f in running) and time.monotonic() < deadline:
            time.sleep(0.05)
        for future in running:
            if future.status == "finished":
                row = future.result()
                rows[row["job"]] = row
        not_done = [f for f in running if not f.done()]
        for future in not_done:
            job_id = future.key.removeprefix("sitrelax-job-")
            rows[job_id] = {"job": job_id, "status": "interrupted",
                            "error": f"the batch was interrupted; the job's worker did not say "
                                     f"within {timeout:g} s that it stopped it: it may still "
                                     f"finish (or stop at its time limit)"}
        client.cancel(not_done)
        try:
            client.sync(client.scheduler.event_clear, name=stop_event, callback_timeout=timeout)
        except (OSError, TimeoutError):
            pass
    return rows


def _stop_local_jobs(cluster, timeout: float = 10.0) -> None:
    """Kills a local cluster's worker processes and their jobs' processes, and waits until
    they have ended: a job cut short writes no result (its results folder stays as it was, a
    hidden folder of partial files aside), and no worker is started in a killed one's place.
    (The workers of a scheduler not started here are not the batch's to kill:
    `_stop_remote_jobs` asks them to stop its jobs.)"""
    import psutil

    processes = []
    for nanny in list(cluster.workers.values()):
        nanny.close_gracefully(reason="the batch was interrupted")  # (not restarted)
        pid = getattr(nanny, "pid", None)
        if not pid:
            continue
        try:
            worker = psutil.Process(pid)
            processes += [worker, *worker.children(recursive=True)]
        except psutil.NoSuchProcess:
            continue
    for process in processes:  # (the worker first: it could record its job as failed)
        try:
            process.kill()
        except psutil.NoSuchProcess:
            pass
    psutil.wait_procs(processes, timeout=timeout)


def _write_summary(out: Path, rows: list[dict]) -> None:
    rows = [_full_row(row) for row in rows]
    write_atomic(out / "summary.json", json.dumps(rows, indent=2).encode())
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=SUMMARY_FIELDS, extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow({**row, "parameters": json.dumps(row.get("parameters", {}),
                                                         sort_keys=True)})
    write_atomic(out / "summary.csv", text.getvalue().encode())


def _store(db: str, jobs: Sequence[Job], rows: list[dict], out: Path) -> list[str]:
    """The finished jobs as scenarios of the library (replacing a job's earlier entry)."""
    from posedb import PoseLibrary

    lib = PoseLibrary(db)
    stored = []
    with lib.edit() as ed:
        for job, row in zip(jobs, rows):
            if row.get("status") != "ok":
                continue
            report = json.loads((out / "jobs" / job.id / "report.json").read_text())
            ed.put_scenario(job.id, json.dumps(job.data, sort_keys=True),
                            json.dumps({"summary": row, "persons": report["persons"]},
                                       sort_keys=True),
                            source=job.scenario)
            stored.append(job.id)
    return stored


def summary_figures(persons: Sequence[dict]) -> dict:
    """A job's figures in the summary, from its report's `persons`: the smallest coverage, the
    deepest cut, the highest peak (None when someone finds no rest), and over the people a seat
    carries at rest (a stander leaning on a wall has no flat seat to be judged against; None
    when there is none) the highest same-load flat seat's peak and the highest ratio of a
    surface's peak on the regions that flat seat presses to it (`peak_of_flat`)."""
    return {"coverage_min": min(p["coverage"] for p in persons),
            "max_penetration_m": max(p["max_penetration_m"] for p in persons),
            "peak_pressure_kpa_max": _max_or_none(p["peak_pressure_kpa"] for p in persons),
            "flat_peak_pressure_kpa_max": _max_of_known(
                (p["flat"].get("same_load") or {}).get("peak_pressure_kpa") for p in persons),
            "peak_of_flat_max": _max_of_known(p.get("peak_of_flat") for p in persons),
            "all_rest": all(p["equilibrium"]["stable"] for p in persons)}


def _max_of_known(values) -> float | None:
    """The largest of the values that are not None (None when none is)."""
    known = [v for v in values if v is not None]
    return max(known) if known else None


def _max_or_none(values) -> float | None:
    """The largest value, or None when any is None (a person that does not rest has no peak)."""
    values = list(values)
    return None if any(v is None for v in values) else max(values)
