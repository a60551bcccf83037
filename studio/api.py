"""`sitrelax serve`: the solver behind a JSON HTTP API (FastAPI), for Rhino/Grasshopper or any
tool. The OpenAPI description is at /openapi.json and the interactive docs at /docs.

A scenario request (/api/fit, /api/relax) is the scenario schema (`solver.scene.schema`, the
TOML format as JSON, with the same defaults), within the server's own bounds (`check_limits`).
Requests name nothing on the server's disk: control meshes come inline, poses from the
server's pose library (`db:NAME`) or the bundled recordings (`bvh:bundled:NAME#frame=N`).
Every request is validated (422 for a malformed one, naming the field and never echoing the
input; 400 for one the solver cannot run; 404 for an unknown pose or recording; 413 for a body
over the size limit or a fit over the compute budget; 415 for a body not sent as
application/json; 403 for a foreign Host or Origin): every error is a 4xx with a short JSON
body. The compute budget is a bound known before a fit runs
(control vertices x 4^level x iterations x people, MAX_WORK) and a wall-clock limit checked at
every iteration of the fit, which stops it. A client that closes its connection before its
answer (a fit, relaxation or evaluation) stops its work the same way, within a fit's iteration.

A fit answers with a `fit_id`; `/api/fit?warm=FIT_ID` refits a scenario of the same control
mesh (people moved, vertices edited) from that fit's result, as the studio does while a
designer drags, and stops once settled. The server keeps its last FITS_KEPT fits (404 for one
it no longer has, 400 for a scenario of another control mesh).
"""

from __future__ import annotations

import asyncio
import math
import os
import re
import secrets
import threading
import time
from collections import OrderedDict
from typing import Annotated

import numpy as np
from fastapi import FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import AfterValidator, BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from solver.scene import schema
from solver.surface.fit import FitParams

from .net import HEAD_TIMEOUT, BodyLimit, HostCheck, allowed_names, head_timeout_protocol

DEFAULT_LIMIT = 8 * 1024 * 1024  # bytes of request body
DEFAULT_TIME_LIMIT = 60.0  # seconds of computing a request may take
MAX_CONTROL_VERTICES = 2000
MAX_PEOPLE = 6
# control vertices x 4^level x max_iterations x people: ~15 us each on one core, so a fit at the
# bound takes about a minute (the wall-clock limit stops one that takes longer)
MAX_WORK = 3_000_000
MAX_EVAL_VERTICES = 200_000
MAX_EVAL_WORK = 600_000  # evaluated surface vertices x people
# an error body lists this many problems; a message is sent whole (the values it quotes
# shortened to MAX_QUOTED characters), and only one longer than MAX_MESSAGE even so is cut
MAX_ERRORS, MAX_MESSAGE = 10, 1000
MAX_QUOTED = 40  # characters of a quoted value an error may send back
COORD = 100.0  # metres: the largest coordinate a request may give
# the server's own ceilings on top of the scenario schema's bounds, so no request runs long
CEILINGS = {"level": 3, "max_iterations": 100, "sigma": 100.0, "gamma": 1e6, "anchor": 1e6,
            "margin": 0.2, "tolerance": 1.0, "pull_range": COORD, "step": COORD}
MAX_FOAM_STIFFNESS = 1e5
FITS_KEPT = 8  # the last fits a server keeps for warm refits (`/api/fit?warm=FIT_ID`)

# (NaN and infinity are refused as such, not as numbers past the bound)
Coord = Annotated[float, Field(ge=-COORD, le=COORD, allow_inf_nan=False)]
Point = Annotated[list[Coord], Field(min_length=3, max_length=3)]
Index = Annotated[int, Field(ge=0, le=MAX_EVAL_VERTICES - 1)]
Face = Annotated[list[Index], Field(min_length=3, max_length=4)]


def _one_kind_of_face(faces: list[list[int]]) -> list[list[int]]:
    """Faces all triangles or all quads (one list type, so an error names the face at fault
    rather than a branch of a union of the two)."""
    sizes = {len(face) for face in faces}
    if len(sizes) > 1:
        first = next(k for k, face in enumerate(faces) if len(face) != len(faces[0]))
        raise ValueError(f"expected every face a triangle or every face a quad, got face 0 "
                         f"with {len(faces[0])} corners and face {first} with "
                         f"{len(faces[first])}")
    return faces


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class PersonRequest(_Model):
    person: schema.Person


class RelaxRequest(_Model):
    scenario: schema.Scenario
    index: Annotated[int, Field(ge=0, le=MAX_PEOPLE - 1)] = 0


class EvaluateRequest(_Model):
    vertices: Annotated[list[Point], Field(min_length=3, max_length=MAX_EVAL_VERTICES)]
    faces: Annotated[list[Face], Field(min_length=1, max_length=400_000),
                     AfterValidator(_one_kind_of_face)]
    person: Annotated[list[schema.Person], Field(min_length=1, max_length=MAX_PEOPLE)]
    margin: schema.FIT_FIELDS["margin"] = FitParams.margin  # type: ignore[valid-type]
    evaluation: schema.Evaluation = schema.Evaluation()


class Mesh(BaseModel):
    vertices: list[list[float]]
    faces: list[list[int]]


class FitResponse(BaseModel):
    control: Mesh
    surface: Mesh
    parameters: dict  # as report.json's "parameters"
    iterations: int
    stop_reason: str
    seconds: float
    energies: list[float]
    persons: list[dict]
    fit_id: str  # a later request may refit warm from this fit: /api/fit?warm=FIT_ID
    relief: dict | None = None  # as report.json's "relief" (the scenario's [relief] rounds)


ERRORS = {
    400: {"description": "A request the solver cannot run (the reason in `detail`)"},
    403: {"description": "A Host or Origin header naming another site"},
    404: {"description": "An unknown pose or bundled recording (the field in `detail`)"},
    409: {"description": "No pose library on this server, or it is gone, locked or "
                         "unreadable (not a pose library, damaged)"},
    413: {"description": "A body over the size limit, or a fit over the compute budget: "
                         f"control vertices x 4^level x max_iterations x people over "
                         f"{MAX_WORK:,}, or past the time limit (default "
                         f"{DEFAULT_TIME_LIMIT:g} s); the field in `detail`"},
    415: {"description": "A body sent without Content-Type: application/json"},
    422: {"description": "A malformed request or one beyond the server's bounds; `detail` "
                         "lists the fields (never the input)"},
}


class TimeLimit(Exception):
    """A request's computing went past the server's time limit."""


class ClientGone(Exception):
    """The client closed its connection before its answer: the work for it is stopped."""


CLIENT_GONE = 499  # (as nginx logs it: nobody reads the answer, the status only names why)


def _limit(loc: list, message: str, status: int = 422, kind: str = "limit") -> HTTPException:
    return HTTPException(status, [{"type": kind, "loc": ["body", *loc], "msg": message}])


def _check_person(p: schema.Person, loc: list) -> None:
    from capture.recordings import bundled_recordings
    from solver.scene.scenario import reads_no_file

    if max(abs(c) for c in p.position) > COORD:
        raise _limit([*loc, "position"], f"expected coordinates within {COORD:g} m here, got "
                                         f"{p.position}")
    if not reads_no_file(p.pose):
        # (a file of the server's disk, `bvh:` written or left out, or no reference at all:
        # refused as the malformed field it is here, without quoting it back, which would show
        # it cut where it names folders)
        text = p.pose.strip().lower()
        file = text.startswith("bvh:") or "/" in text or "\\" in text or \
            (".bvh" in text and not text.startswith("bundled:"))
        got = "a BVH file: this server reads no files" if file else \
            "no db: or bvh:bundled: reference (a library pose is db:NAME)"
        raise _limit([*loc, "pose"], f"Expected db:NAME or bvh:bundled:NAME#frame=N, got {got} "
                                     "(the bundled recordings are at /api/recordings)")
    if p.pose.startswith("bvh:bundled:"):
        name = p.pose[len("bvh:bundled:"):].split("#", 1)[0]
        if "/" in name or "\\" in name:
            raise _limit([*loc, "pose"], "Expected a bundled recording's name after "
                                         "bvh:bundled:, got a path (the bundled ones are at "
                                         "/api/recordings)")
        if name not in bundled_recordings():
            raise _limit([*loc, "pose"], f"No bundled recording {name[:100]!r} (the bundled "
                                         "ones are at /api/recordings)", 404, "not_found")
    _check_finite(p.model_dump(), loc)


def _check_finite(data, loc: list) -> None:
    """422 naming the first NaN or infinity in `data` (nested dicts and lists)."""
    if isinstance(data, float) and not math.isfinite(data):
        raise _limit(loc, f"expected a finite number, got {data}")
    if isinstance(data, dict):
        for key, value in data.items():
            _check_finite(value, [*loc, key])
    elif isinstance(data, (list, tuple)) and data and not isinstance(data[0], int):
        for k, value in enumerate(data):
            _check_finite(value, [*loc, k])


def _check_work(count: int, level: int, iterations: int, people: int, loc: list) -> None:
    work = count * 4 ** level * iterations * max(1, people)
    if work > MAX_WORK:
        raise _limit([*loc, "surface", "max_iterations"],
                     f"expected control vertices x 4^level x max_iterations x people at most "
                     f"{MAX_WORK:,} here (the server's compute budget), got {count} x 4^{level}"
                     f" x {iterations} x {people} = {work:,}: lower one of them", 413, "budget")


def check_limits(s: schema.Scenario, loc: tuple = ()) -> None:
    """The server's bounds on a scenario (the schema's, then these): at most
    MAX_CONTROL_VERTICES control vertices, MAX_PEOPLE people, CEILINGS on the parameters and
    coordinates within COORD metres; an HTTP 422 naming the field otherwise."""
    surf = s.surface
    if surf.grid is not None:
        nx, nz = surf.grid.resolution
        count, extent = (nx + 1) * (nz + 1), max(*surf.grid.size, abs(surf.grid.height))
    elif isinstance(surf.control_mesh, schema.InlineMesh):
        count = len(surf.control_mesh.vertices)
        vertices = np.asarray(surf.control_mesh.vertices, dtype=np.float64)
        if not np.isfinite(vertices).all():
            raise _limit([*loc, "surface", "control_mesh", "vertices"],
                         "expected finite coordinates, got NaN or infinity")
        extent = float(np.abs(vertices).max(initial=0.0))
    elif surf.template is not None:  # built at its given parameters (bounded, milliseconds):
        # its count does not change when it is placed around the people
        from solver.scene.scenario import ScenarioError, template_request

        try:
            _, mesh = template_request(surf.template, len(s.person), "request")
        except ScenarioError:
            count, extent = 0, 0.0  # refused, naming its parameter, by the parse
        else:
            count, extent = len(mesh.vertices), float(np.abs(mesh.vertices).max(initial=0.0))
    else:
        count, extent = 0, 0.0  # a file name: refused as such by the parse
    if count > MAX_CONTROL_VERTICES:
        raise _limit([*loc, "surface"], f"expected at most {MAX_CONTROL_VERTICES} control "
                                        f"vertices here, got {count}")
    if extent > COORD:
        raise _limit([*loc, "surface"], f"expected coordinates within {COORD:g} m here")
    _check_finite(s.model_dump(exclude={"surface": {"control_mesh"}}), list(loc))
    for name, ceiling in CEILINGS.items():
        if getattr(surf, name) > ceiling:
            raise _limit([*loc, "surface", name], f"expected at most {ceiling:g} here, got "
                                                  f"{getattr(surf, name):g}")
    if s.evaluation.foam_stiffness > MAX_FOAM_STIFFNESS:
        raise _limit([*loc, "evaluation", "foam_stiffness"],
                     f"expected at most {MAX_FOAM_STIFFNESS:g} here")
    if len(s.person) > MAX_PEOPLE:
        raise _limit([*loc, "person"], f"expected at most {MAX_PEOPLE} people here, got "
                                       f"{len(s.person)}")
    for k, p in enumerate(s.person):
        _check_person(p, [*loc, "person", k])
    _check_work(count, surf.level, surf.max_iterations, len(s.person), list(loc))


def request_scenario(s: schema.Scenario, loc: tuple = ()):
    """The solver's scenario of a request (the server's bounds checked; nothing read from
    disk): what /api/fit and /api/relax run."""
    from solver.scene.scenario import scenario_from_model

    check_limits(s, loc)
    return scenario_from_model(s, "request", files=False, raw=s.model_dump(exclude_none=True))


def _mesh(vertices: np.ndarray, faces: np.ndarray, decimals: int = 5) -> dict:
    return {"vertices": np.round(vertices, decimals).tolist(), "faces": faces.tolist()}


def create_app(db: str | os.PathLike | None = None, limit: int = DEFAULT_LIMIT,
               time_limit: float = DEFAULT_TIME_LIMIT,
               hosts: frozenset[str] | None = None) -> FastAPI:
    """The API over the pose library `db` (or none), refusing request bodies over `limit`
    bytes, computing past `time_limit` seconds, and Host or Origin names not in `hosts`
    (default: the loopback names)."""
    db = str(db) if db is not None else None
    app = FastAPI(title="sitrelax", version="1", responses=ERRORS,
                  description="Fit supporting surfaces to captured poses: poses, posed bodies, "
                              "pressure fields, fits, relaxation and evaluation, in metres.")
    _error_handlers(app, db)
    place = _placer(db)
    _library_routes(app, db)
    _person_routes(app, place, time_limit)
    _fit_routes(app, place, time_limit)
    app.add_middleware(BodyLimit, limit=limit)
    app.add_middleware(HostCheck, names=hosts if hosts is not None else allowed_names(""))
    return app


def _short(text: str) -> str:
    text = str(text)
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 3] + "..."


# a path with at least one folder (POSIX or Windows): its last part is kept (not the API's own
# routes, which messages name)
_PATH = re.compile(r"(?:\b[A-Za-z]:)?(?!/api/)[/\\](?:[^\s'\",:;()/\\]+[/\\])+([^\s'\",:;()/\\]+)")
# a value quoted as Python quotes it ('...' or "..."), not the text between two apostrophes
# ("the people's lowest point ... each person's position"): a quote after no letter or digit
_QUOTED = re.compile(r"""(?<!\w)(?:'([^']{%d,})'|"([^"]{%d,})")(?!\w)"""
                     % (MAX_QUOTED + 1, MAX_QUOTED + 1))


def _scrubbed(text: str, db: str | None) -> str:
    """An error's text as a client may read it: no path on the server's disk (the pose library
    named as such, any other file by its name alone) and no long quoted value sent back."""
    text = str(text)
    if db is not None:
        for path in {os.path.abspath(db), db}:
            text = text.replace(path, "the server's pose library")
    text = _PATH.sub(lambda m: m.group(1), text)
    return _QUOTED.sub(lambda m: repr((m.group(1) or m.group(2))[:MAX_QUOTED - 3] + "..."),
                       text)


def _json_type(content_type: str | None) -> bool:
    """Whether a Content-Type is one FastAPI reads a body of as JSON (application/json or
    application/...+json, any parameters)."""
    media = (content_type or "").split(";", 1)[0].strip().lower()
    kind, _, sub = media.partition("/")
    return kind == "application" and (sub == "json" or sub.endswith("+json"))


def _error_handlers(app: FastAPI, db: str | None = None) -> None:
    from posedb.schema import NotFoundError

    def reply(status: int, detail) -> JSONResponse:
        if isinstance(detail, list):
            detail = [{"type": e.get("type", "value"), "loc": list(e.get("loc", ()))[:12],
                       "msg": _short(_scrubbed(e.get("msg", ""), db))}
                      for e in detail[:MAX_ERRORS]]
        else:
            detail = _short(_scrubbed(detail, db))
        return JSONResponse({"detail": detail}, status_code=status)

    @app.exception_handler(RequestValidationError)
    async def malformed(request: Request, exc: RequestValidationError):
        errors = exc.errors()
        kind = request.headers.get("content-type")
        if not _json_type(kind) and any(e.get("type") == "model_attributes_type"
                                        and tuple(e.get("loc", ())) == ("body",)
                                        for e in errors):
            # a body sent as another type is not read as JSON (so no foreign page's form
            # posts one): say so, rather than that it is not an object
            got = "none" if kind is None else repr(kind[:100])
            return reply(415, f"Expected the body as Content-Type: application/json, got "
                              f"{got}")
        return reply(422, errors)  # the fields and what is wrong, never the input

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_: Request, exc: StarletteHTTPException):
        if exc.status_code == 400 and exc.detail == "There was an error parsing the body":
            # (FastAPI's own answer to a body its JSON reader gives up on, such as one nested
            # too deep): malformed, as the other malformed bodies
            return reply(422, [{"type": "json_invalid", "loc": ["body"],
                                "msg": "The body is not JSON this server can read (not "
                                       "UTF-8, nested too deep, or a number too long)"}])
        return reply(exc.status_code, exc.detail)

    @app.exception_handler(NotFoundError)
    async def not_found(_: Request, exc: NotFoundError):
        return reply(404, str(exc))

    @app.exception_handler(TimeLimit)
    async def too_long(_: Request, exc: TimeLimit):
        return reply(413, [{"type": "time_limit", "loc": ["body"], "msg": str(exc)}])

    @app.exception_handler(ClientGone)
    async def gone(_: Request, exc: ClientGone):
        return reply(CLIENT_GONE, str(exc))

    @app.exception_handler(ValueError)
    async def bad_value(_: Request, exc: ValueError):
        return reply(409 if _server_fault(exc) else 400, str(exc))

    @app.exception_handler(OSError)
    async def unreadable(_: Request, exc: OSError):
        return reply(409, f"The server could not read what this needs ({exc.strerror or exc})"
                          "; its pose library may have moved")


def _deadline(seconds: float, gone: threading.Event | None = None):
    """progress(iteration, energy, tau) for a fit: raises TimeLimit (stopping the fit) once
    `seconds` have passed since this was made, and ClientGone once `gone` is set (the client
    has closed its connection); `check()` does the same between stages."""
    end = time.monotonic() + seconds

    def progress(iteration: int = 0, energy: float = 0.0, tau: float = 0.0) -> None:
        if gone is not None and gone.is_set():
            raise ClientGone("The client closed its connection before its answer (stopped)")
        if time.monotonic() > end:
            raise TimeLimit(f"The request took over this server's time limit of {seconds:g} "
                            "s (stopped); lower the level, the iterations or the control mesh")

    def expired() -> bool:
        return time.monotonic() > end or (gone is not None and gone.is_set())

    # a fit polls this within its iterations too (a large programme's tries take seconds),
    # and stops a programme's solve running at the deadline
    expired.deadline = end
    progress.expired = expired
    return progress


async def _while_connected(request: Request, work):
    """`work(gone)` in a worker thread, where `gone` (a `threading.Event`) is set once the
    client closes its connection, so the work can stop rather than run on for nobody (the
    time limit's `_deadline(seconds, gone)` polls it)."""
    gone = threading.Event()

    async def watch() -> None:
        # the body has been read: the next message is the client leaving
        while (await request.receive())["type"] != "http.disconnect":
            pass
        gone.set()

    watcher = asyncio.ensure_future(watch())
    try:
        return await run_in_threadpool(work, gone)
    finally:
        watcher.cancel()


def _placer(db: str | None):
    """place(spec, index, loc): a posed person, reused while the same person (and library file)
    comes again. A pose that cannot be loaded (an unknown library pose: 404; a frame out of
    range: 400) is refused naming the request's field `loc` + ["pose"] (default
    ["person", index])."""
    from posedb.schema import LibraryError, NotFoundError
    from solver.body.poses import PoseSourceError
    from solver.scene.placement import place_person

    cache: dict[tuple, object] = {}
    lock = threading.Lock()

    def place(spec, index: int, loc: list | None = None):
        stamp = _library_stamp(db) if spec.pose.startswith("db:") else 0
        key = (spec, index, stamp)
        with lock:
            hit = cache.get(key)
        if hit is None:
            at = [*(loc if loc is not None else ["person", index]), "pose"]
            try:
                hit = place_person(spec, db, index)
            except NotFoundError as exc:
                if spec.pose.startswith("db:"):
                    _library_stamp(db)  # (409 for a library gone since, not the pose)
                raise _limit(at, str(exc), 404, "not_found") from None
            except (PoseSourceError, LibraryError) as exc:
                if _server_fault(exc):
                    raise  # (409, as any request's)
                raise _limit(at, str(exc), 400, "value") from None
            with lock:
                if len(cache) >= 32:
                    cache.pop(next(iter(cache)))
                cache[key] = hit
        return hit

    return place


def _server_fault(exc: Exception) -> bool:
    """Whether a library's error is the server's, not the request's: its library locked by
    another program, damaged, or not a pose library at all (409 rather than 400)."""
    from posedb.schema import LibraryError, SchemaError, StorageError

    return isinstance(exc, (SchemaError, StorageError)) or (
        isinstance(exc, LibraryError) and "locked" in str(exc).lower())


_READABLE: dict[tuple, str | None] = {}  # (path, stamp) -> why that file cannot be read
_READABLE_LOCK = threading.Lock()


def _library_stamp(db: str | None) -> int:
    """The library file's modification time; 409 when the server has none, it is gone, or it
    cannot be opened as a pose library (not HDF5, damaged, another schema: checked once per
    version of the file)."""
    from posedb.schema import LibraryError, open_checked

    if db is None:
        raise HTTPException(409, "This server has no pose library (start it with --db)")
    try:
        info = os.stat(db)
    except OSError:
        raise HTTPException(409, "This server's pose library is gone (moved or deleted); "
                                 "restart the server with its new --db") from None
    key = (db, info.st_mtime_ns, info.st_size, info.st_ino)
    with _READABLE_LOCK:
        known = key in _READABLE
        problem = _READABLE.get(key)
    if not known:
        try:
            with open_checked(db):
                problem = None
        except (LibraryError, OSError) as exc:
            problem = str(exc)
        with _READABLE_LOCK:
            if len(_READABLE) >= 32:
                _READABLE.pop(next(iter(_READABLE)))
            _READABLE[key] = problem
    if problem is not None:
        raise HTTPException(409, f"This server's pose library cannot be read ({problem}); "
                                 "restart the server with a working --db")
    return info.st_mtime_ns


def library_state(db: str | None) -> bool:
    """Whether the server's pose library is there and readable as a pose library."""
    try:
        _library_stamp(db)
    except HTTPException:
        return False
    return True


def _library_routes(app: FastAPI, db: str | None) -> None:
    def library():
        from posedb import PoseLibrary

        _library_stamp(db)
        return PoseLibrary(db)

    @app.get("/api/health", summary="Whether the server runs, and whether its pose library "
                                    "is there and readable")
    def health() -> dict:
        return {"status": "ok", "library": library_state(db)}

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


def _person_routes(app: FastAPI, place, time_limit: float) -> None:
    from solver.scene.scenario import parse_scenario

    def placed(person: schema.Person, loc: list):
        _check_person(person, loc)
        data = {"surface": {"grid": {}}, "person": [person.model_dump(exclude_none=True)]}
        return place(parse_scenario(data, "request", files=False).persons[0], 0, loc)

    @app.post("/api/body", summary="A person's posed body mesh, placed in the scene")
    def body(req: PersonRequest) -> dict:
        p = placed(req.person, ["person"])
        return {"label": p.label, "mass_kg": p.body.mass_kg, "height_m": p.body.height_m,
                **_mesh(p.vertices, p.body.triangles)}

    @app.post("/api/pressure", summary="A person's pressure field: where the body needs support")
    def pressure(req: PersonRequest) -> dict:
        p = placed(req.person, ["person"])
        return {"label": p.label, "importance": np.round(p.importance, 5).tolist(),
                "supported_area_m2": float(p.areas[p.importance > 0].sum()),
                "vertices": int(len(p.vertices))}

    @app.post("/api/evaluate", summary="Evaluate any surface mesh against posed people")
    async def evaluate(req: EvaluateRequest, request: Request) -> dict:
        return await _while_connected(request, lambda gone: _evaluate(req, gone))

    def _evaluate(req: EvaluateRequest, gone: threading.Event) -> dict:
        from solver.contact.evaluate import evaluate_person, facing_away_share
        from solver.scene.run import foams
        from solver.mesh import SurfaceMesh, faces_problem

        check = _deadline(time_limit, gone)
        _check_finite({"margin": req.margin, "evaluation": req.evaluation.model_dump()}, [])
        if req.margin > CEILINGS["margin"] or (req.evaluation.foam_stiffness
                                               > MAX_FOAM_STIFFNESS):
            raise _limit(["margin"], f"expected margin <= {CEILINGS['margin']:g} and "
                                     f"foam_stiffness <= {MAX_FOAM_STIFFNESS:g} here")
        if len(req.vertices) * len(req.person) > MAX_EVAL_WORK:
            raise _limit(["vertices"], f"expected vertices x people at most {MAX_EVAL_WORK:,} "
                                       f"here (the server's compute budget), got "
                                       f"{len(req.vertices)} x {len(req.person)}", 413, "budget")
        v = np.asarray(req.vertices, dtype=np.float64)
        f = np.asarray(req.faces, dtype=np.int64)
        problem = faces_problem(v, f)
        if problem:
            raise HTTPException(400, problem)
        mesh = SurfaceMesh.from_faces(v, f)
        out = []
        for k, person in enumerate(req.person):
            check()
            p = placed(person, ["person", k])
            away = facing_away_share(mesh, p)
            if away is not None and away > 0.5:  # (as a fit refuses such a control mesh)
                raise HTTPException(400, f"person {k + 1}: the surface's faces point away from "
                                         f"the body ({away:.0%} of the supported skin near it "
                                         f"faces the same way as the surface); flip the mesh "
                                         f"(reverse each face's vertex order)")
            figures, _ = evaluate_person(mesh, p, req.margin, *foams(req.evaluation))
            out.append({"name": p.label, **figures})
        return {"persons": out}


class _Fits:
    """The last FITS_KEPT fits by id, for warm refits (two refits from one fit at once do not
    share its programme: `solver.surface.programme.Programme.claim`)."""

    def __init__(self):
        self._fits: OrderedDict[str, object] = OrderedDict()
        self._lock = threading.Lock()

    def keep(self, result) -> str:
        fit_id = secrets.token_hex(8)
        with self._lock:
            self._fits[fit_id] = result
            while len(self._fits) > FITS_KEPT:
                self._fits.popitem(last=False)
        return fit_id

    def get(self, fit_id: str):
        with self._lock:
            result = self._fits.get(fit_id)
            if result is not None:
                self._fits.move_to_end(fit_id)
        if result is None:
            raise HTTPException(404, f"No fit {fit_id} here to refit from (the server keeps its "
                                     f"last {FITS_KEPT}): fit without `warm`")
        return result


def _fit_routes(app: FastAPI, place, time_limit: float) -> None:
    fits = _Fits()

    @app.post("/api/fit", summary="Fit a surface to a scenario, with each person's evaluation")
    async def fit(s: schema.Scenario, request: Request,
                  warm: Annotated[str | None, Query(
                      pattern="^[0-9a-f]{16}$",
                      description="The fit_id of an earlier fit of the same control mesh (the "
                                  "same grid, template or mesh, people moved or vertices edited "
                                  "since): refit from its result, stopping once settled")] = None
                  ) -> FitResponse:
        return await _while_connected(request, lambda gone: _fit(s, warm, gone))

    def _fit(s: schema.Scenario, warm: str | None, gone: threading.Event) -> FitResponse:
        from solver.scene.placement import place_scene
        from solver.scene.run import evaluate_fit, fit_people, relieve_fit, report_parameters

        start = time.perf_counter()
        check = _deadline(time_limit, gone)
        scenario = request_scenario(s)
        last = fits.get(warm) if warm is not None else None
        scenario, people = place_scene(scenario, place=place)
        check()
        result = fit_people(scenario, people, check, cancel=check.expired, warm=last)
        check()  # a fit cancelled at the deadline is refused, not evaluated
        _, persons, maps = evaluate_fit(scenario, people, result)
        relief = None
        if scenario.relief.rounds:  # (stopped at the deadline with the rounds kept so far)
            result, persons, _, relief = relieve_fit(scenario, people, result, persons, maps,
                                                     cancel=check.expired)
        return FitResponse(control=_mesh(result.control, result.faces),
                           surface=_mesh(result.surface, result.surface_faces),
                           parameters=report_parameters(scenario),
                           iterations=result.iterations, stop_reason=result.stop_reason,
                           seconds=time.perf_counter() - start, energies=result.energies,
                           persons=persons, fit_id=fits.keep(result),
                           relief=None if relief is None else relief.record())

    @app.post("/api/relax", summary="Fit, then relax one person onto the surface")
    async def relax(req: RelaxRequest, request: Request) -> dict:
        return await _while_connected(request, lambda gone: _relax(req, gone))

    def _relax(req: RelaxRequest, gone: threading.Event) -> dict:
        from solver.scene.placement import place_scene
        from solver.scene.run import fit_people, relax_person, relax_record, relieved

        scenario = request_scenario(req.scenario, ("scenario",))
        if req.index >= len(scenario.persons):
            raise HTTPException(400, f"Expected index in 0..{len(scenario.persons) - 1}, got "
                                     f"{req.index}")
        check = _deadline(time_limit, gone)
        scenario, people = place_scene(  # (an error names the field under "scenario")
            scenario, place=lambda spec, k: place(spec, k, ["scenario", "person", k]))
        check()
        result = fit_people(scenario, people, check, cancel=check.expired)
        check()  # a fit cancelled at the deadline is refused, not relaxed on
        # the surface /api/fit answers with (relieved, stopped at the deadline as it is)
        result = relieved(scenario, people, result, cancel=check.expired)
        check()
        person = people[req.index]
        res, before, after, seconds = relax_person(  # onto the limit surface, as evaluated
            scenario, person, result.limit_surface(scenario.surface.params.creases),
            result.surface_faces, check=check)
        return {"label": person.label, "evaluations": res.evaluations,
                "parameters_at_limit": res.at_limit, "seconds": seconds,
                "before": before, "after": after, "relaxation": relax_record(res),
                "surface": _mesh(result.surface, result.surface_faces),
                "body": _mesh(res.vertices, person.body.triangles)}


def server_config(app: FastAPI, host: str, port: int, head_timeout: float = HEAD_TIMEOUT):
    """uvicorn's configuration for the API: a request head must arrive within `head_timeout`
    seconds and an idle kept-alive connection closes after 5, so idle connections cannot hold
    the server; past 512 open connections a new one gets 503."""
    import uvicorn

    return uvicorn.Config(app, host=host, port=port, log_level="warning", timeout_keep_alive=5,
                          limit_concurrency=512, http=head_timeout_protocol(head_timeout),
                          ws="none")


class ApiThread:
    """The API served from a background thread (for benchmarks, tests and embedding):
    `url` once started; `stop()` ends it."""

    def __init__(self, db: str | os.PathLike | None = None, host: str = "127.0.0.1",
                 port: int = 0, limit: int = DEFAULT_LIMIT, head_timeout: float = HEAD_TIMEOUT,
                 **app_options):
        import uvicorn

        self.server = uvicorn.Server(server_config(create_app(db, limit, **app_options),
                                                   host, port, head_timeout))
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
