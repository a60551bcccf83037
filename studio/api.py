"""`sitrelax serve`: the solver behind a JSON HTTP API (FastAPI), for Rhino/Grasshopper or any
tool. The OpenAPI description is at /openapi.json and the interactive docs at /docs.

Requests name nothing on the server's disk: control meshes come inline, poses from the
server's pose library (`db:NAME`) or the bundled recordings (`bvh:bundled:NAME#frame=N`).
Every request is validated (422 for a malformed one, 400 for one the solver cannot run, 404
for an unknown pose, 413 for a body over the size limit); sizes are bounded so that no request
runs for long.
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from typing import Annotated, Literal

import numpy as np
from fastapi import FastAPI, HTTPException, Query, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field, create_model

from solver.body import model as solver_body
from solver.body.model import SUPPORT_PARTS

from .net import BodyLimit

DEFAULT_LIMIT = 8 * 1024 * 1024  # bytes of request body
MAX_CONTROL_VERTICES = 2000
MAX_PEOPLE = 6
COORD = 100.0  # metres: the largest coordinate a request may give

Coord = Annotated[float, Field(ge=-COORD, le=COORD)]
Point = Annotated[list[Coord], Field(min_length=3, max_length=3)]
Index = Annotated[int, Field(ge=0, le=10 * MAX_CONTROL_VERTICES)]
Quad = Annotated[list[Index], Field(min_length=4, max_length=4)]
Triangle = Annotated[list[Index], Field(min_length=3, max_length=3)]
Unit = Annotated[float, Field(ge=0.0, le=1.0)]
Part = Literal["head", "torso", "arms", "hands", "legs", "feet", "thighs", "calves"]
assert set(Part.__args__) == set(SUPPORT_PARTS)  # type: ignore[attr-defined]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Grid(_Model):
    size: Annotated[list[Annotated[float, Field(ge=0.05, le=20.0)]],
                    Field(min_length=2, max_length=2)] = [0.5, 0.6]
    resolution: Annotated[list[Annotated[int, Field(ge=1, le=40)]],
                          Field(min_length=2, max_length=2)] = [8, 6]
    height: Coord = 0.42


class ControlMesh(_Model):
    vertices: Annotated[list[Point], Field(min_length=4, max_length=MAX_CONTROL_VERTICES)]
    faces: Annotated[list[Quad], Field(min_length=1, max_length=2 * MAX_CONTROL_VERTICES)]


class Surface(_Model):
    grid: Grid | None = None
    control_mesh: ControlMesh | None = None
    level: Annotated[int, Field(ge=1, le=3)] = 3
    sigma: Annotated[float, Field(ge=0.0, le=100.0)] = 0.003
    tau_max: Unit = 0.5
    margin: Annotated[float, Field(ge=0.0, le=0.2)] = 0.03
    fixed: Annotated[list[Index], Field(max_length=MAX_CONTROL_VERTICES)] = []
    gamma: Annotated[float, Field(ge=0.0, le=1e6)] = 10.0
    max_iterations: Annotated[int, Field(ge=1, le=100)] = 50
    tolerance: Annotated[float, Field(ge=0.0, le=1.0)] = 0.01


# the body's shape parameters, each in [0, 1], as the solver's BodyShape declares them
BodyShape = create_model(
    "BodyShape", __config__=ConfigDict(extra="forbid"),
    **{f.name: (Unit, f.default) for f in dataclasses.fields(solver_body.BodyShape)})


class Person(_Model):
    pose: Annotated[str, Field(min_length=4, max_length=300,
                               examples=["bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"])]
    name: Annotated[str, Field(max_length=100)] = ""
    body: BodyShape = BodyShape()
    position: Point = [0.0, 0.0, -0.1]
    rotation_deg: Annotated[list[Annotated[float, Field(ge=-360.0, le=360.0)]],
                            Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.0]
    support: Annotated[list[Part], Field(min_length=1, max_length=len(SUPPORT_PARTS))] = ["legs"]


class Evaluation(_Model):
    foam_stiffness: Annotated[float, Field(ge=1.0, le=1e5)] = 200.0


class Scenario(_Model):
    surface: Surface
    person: Annotated[list[Person], Field(min_length=1, max_length=MAX_PEOPLE)]
    evaluation: Evaluation = Evaluation()


class PersonRequest(_Model):
    person: Person


class RelaxRequest(_Model):
    scenario: Scenario
    index: Annotated[int, Field(ge=0, le=MAX_PEOPLE - 1)] = 0


class EvaluateRequest(_Model):
    vertices: Annotated[list[Point], Field(min_length=3, max_length=200_000)]
    faces: Annotated[list[Quad] | list[Triangle], Field(min_length=1, max_length=400_000)]
    person: Annotated[list[Person], Field(min_length=1, max_length=MAX_PEOPLE)]
    margin: Annotated[float, Field(ge=0.0, le=0.2)] = 0.03
    evaluation: Evaluation = Evaluation()


class Mesh(BaseModel):
    vertices: list[list[float]]
    faces: list[list[int]]


class FitResponse(BaseModel):
    control: Mesh
    surface: Mesh
    iterations: int
    stop_reason: str
    seconds: float
    energies: list[float]
    persons: list[dict]


def _scenario_data(s: Scenario) -> dict:
    data = s.model_dump(exclude_none=True)
    if not data["surface"]["fixed"]:
        del data["surface"]["fixed"]
    for p in data["person"]:
        if not p["name"]:
            del p["name"]
    return data


def _mesh(vertices: np.ndarray, faces: np.ndarray, decimals: int = 5) -> dict:
    return {"vertices": np.round(vertices, decimals).tolist(), "faces": faces.tolist()}


def create_app(db: str | os.PathLike | None = None, limit: int = DEFAULT_LIMIT) -> FastAPI:
    """The API over the pose library `db` (or none), refusing request bodies over `limit`."""
    from posedb.schema import LibraryError, NotFoundError
    from solver.scene.scenario import parse_scenario

    db = str(db) if db is not None else None
    app = FastAPI(title="sitrelax", version="1",
                  description="Fit supporting surfaces to captured poses: poses, posed bodies, "
                              "pressure fields, fits, relaxation and evaluation, in metres.")

    @app.exception_handler(NotFoundError)
    async def not_found(_: Request, exc: NotFoundError):
        return JSONResponse({"detail": str(exc)}, status_code=404)

    @app.exception_handler(ValueError)
    async def bad_value(_: Request, exc: ValueError):
        status = 409 if isinstance(exc, LibraryError) and "locked" in str(exc).lower() else 400
        return JSONResponse({"detail": str(exc)}, status_code=status)

    def library():
        from posedb import PoseLibrary

        if db is None:
            raise HTTPException(409, "This server has no pose library (start it with --db)")
        return PoseLibrary(db)

    def parse(s: Scenario):
        return parse_scenario(_scenario_data(s), "request", files=False)

    cache: dict[tuple, object] = {}
    lock = threading.Lock()

    def place(spec, index: int):
        """A posed person, reused while the same person (and library file) comes again."""
        from solver.scene.placement import place_person

        stamp = os.stat(db).st_mtime_ns if db is not None else 0
        key = (spec, index, stamp)
        with lock:
            hit = cache.get(key)
        if hit is None:
            hit = place_person(spec, db, index)
            with lock:
                if len(cache) >= 32:
                    cache.pop(next(iter(cache)))
                cache[key] = hit
        return hit

    def placed(person: Person):
        data = {"surface": {"grid": {}}, "person": [person.model_dump()]}
        return place(parse_scenario(data, "request", files=False).persons[0], 0)

    @app.get("/api/health", summary="Whether the server runs, and its library")
    def health() -> dict:
        return {"status": "ok", "library": db is not None}

    @app.get("/api/recordings", summary="The bundled recordings (bvh:bundled:NAME#frame=N)")
    def recordings() -> dict:
        from capture.recordings import bundled_recordings

        return {"recordings": bundled_recordings()}

    @app.get("/api/poses", summary="Poses of the library, optionally matching a tag expression")
    def poses(tags: Annotated[str | None, Query(max_length=500)] = None,
              limit: Annotated[int, Query(ge=1, le=1000)] = 100,
              offset: Annotated[int, Query(ge=0)] = 0) -> dict:
        lib = library()
        found = lib.find_poses(tags or None)
        takes = {t.id: t.name for t in lib.takes()}
        return {"total": len(found),
                "poses": [p.as_dict(takes.get(p.take)) for p in found[offset:offset + limit]]}

    @app.get("/api/poses/{name}", summary="One pose of the library, by name or id")
    def pose(name: Annotated[str, Field(max_length=300)]) -> dict:
        lib = library()
        info = lib.pose(name)
        return info.as_dict(lib.take(info.take).name)

    @app.post("/api/body", summary="A person's posed body mesh, placed in the scene")
    def body(req: PersonRequest) -> dict:
        p = placed(req.person)
        return {"label": p.label, "mass_kg": p.body.mass_kg, "height_m": p.body.height_m,
                **_mesh(p.vertices, p.body.triangles)}

    @app.post("/api/pressure", summary="A person's pressure field: where the body needs support")
    def pressure(req: PersonRequest) -> dict:
        p = placed(req.person)
        return {"label": p.label, "importance": np.round(p.importance, 5).tolist(),
                "supported_area_m2": float(p.areas[p.importance > 0].sum()),
                "vertices": int(len(p.vertices))}

    @app.post("/api/fit", summary="Fit a surface to a scenario, with each person's evaluation")
    def fit(s: Scenario) -> FitResponse:
        from solver.scene.run import fit_scene

        start = time.perf_counter()
        scenario = parse(s)
        result, persons, _ = fit_scene(scenario, [place(p, k) for k, p in
                                                  enumerate(scenario.persons)])
        return FitResponse(control=_mesh(result.control, result.faces),
                           surface=_mesh(result.surface, result.surface_faces),
                           iterations=result.iterations, stop_reason=result.stop_reason,
                           seconds=time.perf_counter() - start, energies=result.energies,
                           persons=persons)

    @app.post("/api/relax", summary="Fit, then relax one person onto the surface")
    def relax(req: RelaxRequest) -> dict:
        from solver.scene.run import fit_people, relax_person

        scenario = parse(req.scenario)
        if req.index >= len(scenario.persons):
            raise HTTPException(400, f"Expected index in 0..{len(scenario.persons) - 1}, got "
                                     f"{req.index}")
        people = [place(p, k) for k, p in enumerate(scenario.persons)]
        result = fit_people(scenario, people)
        person = people[req.index]
        res, before, after, seconds = relax_person(scenario, person, result.surface,
                                                   result.surface_faces)
        return {"label": person.label, "evaluations": res.evaluations,
                "parameters_at_limit": res.at_limit, "seconds": seconds,
                "before": before, "after": after,
                "surface": _mesh(result.surface, result.surface_faces),
                "body": _mesh(res.vertices, person.body.triangles)}

    @app.post("/api/evaluate", summary="Evaluate any surface mesh against posed people")
    def evaluate(req: EvaluateRequest) -> dict:
        from solver.contact.evaluate import evaluate_person
        from solver.mesh import SurfaceMesh, faces_problem

        v = np.asarray(req.vertices, dtype=np.float64)
        f = np.asarray(req.faces, dtype=np.int64)
        problem = faces_problem(v, f)
        if problem:
            raise HTTPException(400, problem)
        mesh = SurfaceMesh.from_faces(v, f)
        out = []
        for person in req.person:
            p = placed(person)
            figures, _ = evaluate_person(mesh, p, req.margin, req.evaluation.foam_stiffness)
            out.append({"name": p.label, **figures})
        return {"persons": out}

    app.add_middleware(BodyLimit, limit=limit)
    return app


class ApiThread:
    """The API served from a background thread (for benchmarks, tests and embedding):
    `url` once started; `stop()` ends it."""

    def __init__(self, db: str | os.PathLike | None = None, host: str = "127.0.0.1",
                 port: int = 0, limit: int = DEFAULT_LIMIT):
        import threading

        import uvicorn

        config = uvicorn.Config(create_app(db, limit), host=host, port=port,
                                log_level="warning", timeout_keep_alive=5)
        self.server = uvicorn.Server(config)
        self.server.install_signal_handlers = lambda: None  # not the main thread
        self.thread = threading.Thread(target=self.server.run, name="sitrelax-api", daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"The API server did not start on {host}:{port}")
            time.sleep(0.01)
        self.host, self.port = self.server.servers[0].sockets[0].getsockname()[:2]
        self.url = f"http://{self.host}:{self.port}"

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)
