"""Batches of fits: scenario files, or library poses in a template, times a parameter grid,
run on a local Dask cluster (processes) or on an existing Dask scheduler.

Each job fits, evaluates and exports as `sitrelax fit` does, into `OUT/jobs/<job id>/`, whose
`result.json` marks it finished (a re-run skips it). A job that raises is recorded with its
error and the batch goes on; a job whose worker dies is given to another worker by Dask. Workers
only read the pose library; the client alone writes (the results, as scenarios, in one commit).
"""

from __future__ import annotations

import copy
import csv
import hashlib
import io
import itertools
import json
import os
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from capture.files import write_atomic

SURFACE_SHORTCUTS = {"level", "sigma", "tau_max", "margin", "gamma", "max_iterations",
                     "tolerance"}
SUMMARY_FIELDS = ("job", "scenario", "parameters", "status", "seconds", "coverage_min",
                  "max_penetration_m", "peak_pressure_kpa_max", "flat_peak_pressure_kpa_max",
                  "iterations", "error")


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
                number = float(v)
            except ValueError:
                raise BatchError(f"--grid {key}: expected numbers, got {v!r}") from None
            parsed.append(int(number) if number.is_integer() and "." not in v else number)
        grid[key] = parsed
    return grid


def _apply(data: dict, key: str, value) -> None:
    """Sets one grid key in scenario data: `sigma` (a surface shortcut), `surface.X`,
    `evaluation.X`, or `body.X` / `person.X` for every person."""
    parts = key.split(".")
    if len(parts) == 1 and parts[0] in SURFACE_SHORTCUTS:
        parts = ["surface", parts[0]]
    if parts[0] in ("surface", "evaluation") and len(parts) == 2:
        data.setdefault(parts[0], {})[parts[1]] = value
    elif parts[0] == "body" and len(parts) == 2:
        for person in data.get("person", []):
            person.setdefault("body", {})[parts[1]] = value
    elif parts[0] == "person" and len(parts) == 2:
        for person in data.get("person", []):
            person[parts[1]] = value
    else:
        raise BatchError(f"--grid {key}: expected sigma, tau_max, margin, level, surface.KEY, "
                         "evaluation.KEY, body.KEY or person.KEY")


def _job_id(scenario: str, data: dict, parameters: dict) -> str:
    stem = Path(scenario.split("#")[0]).stem or "job"
    digest = hashlib.sha1(json.dumps([scenario, data, parameters], sort_keys=True,
                                     default=str).encode()).hexdigest()[:10]
    return f"{stem}-{digest}"


def expand_jobs(scenarios: Sequence[str | os.PathLike] = (), *, grid: dict | None = None,
                from_db: str | None = None, template: str | os.PathLike | None = None,
                db: str | os.PathLike | None = None) -> list[Job]:
    """The batch's jobs: every scenario (or every library pose matching `from_db`, put into
    each person of `template`) at every point of `grid`."""
    from solver.scene.scenario import ScenarioError, parse_scenario

    grid = grid or {}
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
    keys = list(grid)
    jobs = []
    for scenario, data, base in sources:
        for values in itertools.product(*(grid[k] for k in keys)) if keys else [()]:
            point = dict(zip(keys, values))
            job_data = copy.deepcopy(data)
            problem = job_data.pop("problem", "") if set(job_data) == {"problem"} else ""
            if not problem:
                for k, v in point.items():
                    _apply(job_data, k, v)
                try:  # each grid point is checked here, before anything runs
                    parse_scenario(copy.deepcopy(job_data), scenario, base)
                except ScenarioError as exc:
                    problem = str(exc)
            jobs.append(Job(_job_id(scenario, job_data, point), scenario, job_data,
                            str(base.resolve()), point, problem))
    return jobs


def _read_toml(path: str | os.PathLike) -> dict:
    path = Path(path)
    if not path.exists():
        raise BatchError(f"No scenario file {path}")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise BatchError(f"{path}: not a valid TOML scenario: {exc}") from None


def run_job(job: Job, db: str | None, out_root: str) -> dict:
    """Runs one job on a worker; returns its summary row (a failure is a row too)."""
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
        report = run_fit(scenario, folder, db=db)
    except Exception as exc:  # recorded; the batch goes on
        row.update(status="failed", seconds=time.perf_counter() - start,
                   error=f"{type(exc).__name__}: {exc}")
    else:
        persons = report["persons"]
        row.update(status="ok", seconds=time.perf_counter() - start, error="",
                   iterations=report["iterations"],
                   coverage_min=min(p["coverage"] for p in persons),
                   max_penetration_m=max(p["max_penetration_m"] for p in persons),
                   peak_pressure_kpa_max=max(p["peak_pressure_kpa"] for p in persons),
                   flat_peak_pressure_kpa_max=max(p["flat"]["peak_pressure_kpa"]
                                                  for p in persons))
    write_atomic(folder / "result.json", json.dumps(row, indent=2).encode())
    return row


def _finished(out: Path, job: Job) -> dict | None:
    path = out / "jobs" / job.id / "result.json"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def run_batch(jobs: Sequence[Job], out_dir: str | os.PathLike, *,
              db: str | os.PathLike | None = None, workers: int = 2,
              scheduler: str | None = None, store: bool = True,
              progress: Callable[[dict], None] | None = None) -> dict:
    """Runs the jobs not finished before; writes summary.csv and summary.json; stores the
    finished jobs' scenarios and results in the library (when `db` and `store`)."""
    from distributed import Client, LocalCluster, as_completed

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    db_path = str(Path(db).resolve()) if db is not None else None
    rows: dict[str, dict] = {}
    todo = []
    for job in jobs:
        done = _finished(out, job)
        if done is not None and done.get("status") == "ok":
            rows[job.id] = done
        else:
            todo.append(job)
    start = time.perf_counter()
    counts = {"total": len(jobs), "skipped": len(rows), "done": 0, "failed": 0,
              "running": len(todo)}
    cluster = None
    if todo:
        if scheduler is None:
            import dask

            # the workers' statistical profiler (a stack sample every 10 ms, for the dashboard)
            # costs a batch a few per cent of its time: our workers go without it
            with dask.config.set({"distributed.worker.profile.enabled": False}):
                cluster = LocalCluster(n_workers=max(1, int(workers)), threads_per_worker=1,
                                       processes=True, host="127.0.0.1",
                                       dashboard_address="127.0.0.1:0")
            client = Client(cluster)
        else:
            client = Client(scheduler)
        try:
            futures = [client.submit(run_job, job, db_path, str(out.resolve()),
                                     key=f"sitrelax-job-{job.id}", pure=False, retries=2)
                       for job in todo]
            for future in as_completed(futures):
                row = future.result()
                rows[row["job"]] = row
                counts["done" if row["status"] == "ok" else "failed"] += 1
                counts["running"] -= 1
                if progress is not None:
                    finished = counts["done"] + counts["failed"]
                    elapsed = time.perf_counter() - start
                    progress({**counts, "elapsed_s": elapsed,
                              "left_s": elapsed / finished * counts["running"]})
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    ordered = [rows[job.id] for job in jobs]
    _write_summary(out, ordered)
    stored = _store(db_path, jobs, ordered, out) if (db_path and store) else []
    return {"out": str(out), "jobs": ordered, "counts": counts, "stored": stored,
            "seconds": time.perf_counter() - start}


def _write_summary(out: Path, rows: list[dict]) -> None:
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
