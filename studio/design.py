"""A design session: the people, the control mesh and the fit's parameters as a designer edits
them in the studio, and what can be done with them: fit, relax, save (library or TOML), export.

The session is plain data (scenario person tables, a control mesh, parameters) turned into a
`Scenario` by `parse_scenario` (the scenario schema: its defaults, its checks) whenever it
runs, so everything the studio does is what `sitrelax fit` would do with the same scenario
file. Posed people are cached by their table, so moving one person re-poses
that person only.
"""

from __future__ import annotations

import copy
import json
import os
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from capture.files import write_atomic
from solver.scene import schema
from solver.surface.fit import FitResult
from solver.scene.run import fit_scene, relax_person, relax_text, run_fit
from solver.scene.scenario import Scenario, parse_scenario, read_control_mesh, scenario_toml
from solver.scene.placement import PlacedPerson, place_person

PARAMETERS = ("level", "sigma", "tau_max", "margin")  # the ones the studio's panel sets
MAX_PEOPLE = 8
MAX_CONTROL_VERTICES = 2000


class DesignError(ValueError):
    """An edit or a run the session cannot make (the message says why)."""


NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_. ")
MAX_NAME = 80


def check_name(name: str) -> str:
    """A design's name (stripped): letters, digits, '-', '_', '.' and spaces, at most MAX_NAME
    characters, not starting with '.'; it names a file or a folder inside --out, never a path."""
    name = name.strip()
    if (not name or len(name) > MAX_NAME or name.startswith(".")
            or not set(name) <= NAME_CHARS):
        raise DesignError(f"Expected a name of letters, digits, '-', '_', '.' and spaces (at "
                          f"most {MAX_NAME}, not starting with '.'), got {name[:100]!r}")
    return name


@dataclass
class FitOutcome:
    """A fit of the session: the result, the people as posed for it, each person's figures
    (with the flat-seat baseline under `flat`) and pressure per body vertex (kPa)."""

    result: FitResult
    people: list[PlacedPerson]
    persons: list[dict]
    pressure: list[np.ndarray]
    seconds: float


@dataclass
class RelaxOutcome:
    person: int
    vertices: np.ndarray
    faces: np.ndarray
    before: dict
    after: dict
    seconds: float
    summary: str = ""  # what the relaxation accepted and why (`relax_text`)


class Design:
    def __init__(self, db: str | os.PathLike | None = None):
        self.db = str(db) if db is not None else None
        self.people: list[dict] = []
        self.params = {name: schema.default(schema.Surface, name) for name in PARAMETERS}
        self.fixed: set[int] = set()
        self.vertices = np.zeros((0, 3))
        self.faces = np.zeros((0, 4), dtype=np.int64)
        self.last: FitOutcome | None = None
        self._placed: dict[str, PlacedPerson] = {}
        self.new_grid(**schema.Grid().model_dump())  # the scenario's default start

    # the control mesh -------------------------------------------------------------------
    def new_grid(self, size, resolution, height: float) -> None:
        data = {"surface": {"grid": {"size": list(size), "resolution": list(resolution),
                                     "height": height}},
                "person": [{"pose": "db:any"}]}
        scenario = parse_scenario(data, "grid")  # the scenario's own checks
        self._set_mesh(scenario.surface.vertices, scenario.surface.faces)

    def load_control_mesh(self, path: str | os.PathLike) -> None:
        v, f = read_control_mesh(Path(path), str(path))
        self._set_mesh(v, f)

    def _set_mesh(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        if len(vertices) > MAX_CONTROL_VERTICES:
            raise DesignError(f"A studio control mesh has at most {MAX_CONTROL_VERTICES} "
                              f"vertices (a fit stays interactive), got {len(vertices)}")
        self.vertices = np.asarray(vertices, dtype=np.float64).copy()
        self.faces = np.asarray(faces, dtype=np.int64).copy()
        self.fixed = set()
        self.last = None

    def move_vertex(self, j: int, position) -> None:
        self._vertex(j)
        p = np.asarray(position, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise DesignError(f"Expected a finite [x, y, z] for control vertex {j}, got "
                              f"{position!r}")
        self.vertices[j] = p

    def set_fixed(self, j: int, fixed: bool) -> None:
        self._vertex(j)
        (self.fixed.add if fixed else self.fixed.discard)(j)

    def _vertex(self, j: int) -> None:
        if not 0 <= j < len(self.vertices):
            raise DesignError(f"Expected a control vertex in 0..{len(self.vertices) - 1}, "
                              f"got {j}")

    def adopt_fit(self) -> None:
        """Makes the last fit's control mesh the start of the next (fixed vertices kept)."""
        if self.last is None:
            raise DesignError("Nothing fitted yet: press Fit first")
        fixed = set(self.fixed)
        self.vertices = self.last.result.control.copy()
        self.fixed = fixed

    def set_parameter(self, name: str, value: float) -> None:
        if name not in PARAMETERS:
            raise DesignError(f"Expected a parameter from {PARAMETERS}, got {name!r}")
        if name == "level" and float(value).is_integer():
            value = int(value)  # sliders send whole numbers as floats
        trial = dict(self.params, **{name: value})
        self._parse(self._data(params=trial, people=[{"pose": "db:any"}]))
        self.params = trial

    # the people -------------------------------------------------------------------------
    def add_person(self, pose: str, **fields) -> int:
        if len(self.people) >= MAX_PEOPLE:
            raise DesignError(f"A studio scene holds at most {MAX_PEOPLE} people")
        person = {"name": f"person {len(self.people) + 1}", "pose": pose,
                  **schema.person_defaults(), **fields}
        self._check_person(person)
        self.people.append(person)
        return len(self.people) - 1

    def update_person(self, k: int, **fields) -> None:
        person = dict(self._person(k), **fields)
        # a move or a turn only needs the fields checked; a new pose or body is made now
        self._check_person(person, make=bool({"pose", "body"} & set(fields)))
        self.people[k] = person

    def remove_person(self, k: int) -> None:
        self._person(k)
        del self.people[k]
        self.last = None

    def _person(self, k: int) -> dict:
        if not 0 <= k < len(self.people):
            raise DesignError(f"Expected a person in 0..{len(self.people) - 1}, got {k}")
        return self.people[k]

    def _check_person(self, person: dict, make: bool = True) -> None:
        self._parse(self._data(people=[person]))
        if make:  # the pose must exist and the body must be made
            self.place(dict(person, position=[0.0, 0.0, 0.0], rotation_deg=[0.0, 0.0, 0.0]))

    def place(self, person: dict) -> PlacedPerson:
        key = json.dumps(person, sort_keys=True)
        if key not in self._placed:
            spec = self._parse(self._data(people=[person])).persons[0]
            if len(self._placed) > 64:
                self._placed.clear()
            self._placed[key] = place_person(spec, self.db)
        return self._placed[key]

    # scenarios ----------------------------------------------------------------------------
    def _data(self, *, params: dict | None = None, people: list | None = None) -> dict:
        surface = {"control_mesh": {"vertices": self.vertices.tolist(),
                                    "faces": self.faces.tolist()},
                   **(params or self.params)}
        if self.fixed:
            surface["fixed"] = sorted(self.fixed)
        return {"surface": surface,
                "person": copy.deepcopy(people if people is not None else self.people)}

    def _parse(self, data: dict) -> Scenario:
        return parse_scenario(data, "studio", files=False)

    def scenario_data(self) -> dict:
        """The session as scenario data (the control mesh inline)."""
        if not self.people:
            raise DesignError("Add a person first: the scene is empty")
        return self._data()

    def scenario(self) -> Scenario:
        return self._parse(self.scenario_data())

    def fit(self, progress: Callable[[int, float, float], None] | None = None, *,
            warm: bool = False, cancel: Callable[[], bool] | None = None) -> FitOutcome:
        """Fits the session's scene. `warm`: refit from the last fit's result when the control
        mesh has the same vertices and quads (a cold fit otherwise); `cancel`: polled between
        iterations, ends the fit early with the best surface so far."""
        start = time.perf_counter()
        scenario = self.scenario()
        people = [self.place(p) for p in self.people]
        last = self.last.result if warm and self.last is not None else None
        if last is not None and (last.control.shape != self.vertices.shape or
                                 not np.array_equal(last.faces, self.faces)):
            last = None  # another control mesh: nothing to start from
        result, persons, settles = fit_scene(scenario, people, progress, warm=last,
                                             cancel=cancel)
        self.last = FitOutcome(result, people, persons, [m.pressure_kpa for m in settles],
                               time.perf_counter() - start)
        return self.last

    def relax(self, k: int) -> RelaxOutcome:
        self._person(k)
        if self.last is None:
            raise DesignError("Fit first: a person relaxes onto the fitted surface")
        start = time.perf_counter()
        person = self.place(self.people[k])
        res, before, after, _ = relax_person(self.scenario(), person, self.last.result.surface,
                                             self.last.result.surface_faces)
        return RelaxOutcome(k, res.vertices, person.body.triangles, before, after,
                            time.perf_counter() - start, relax_text(res))

    def save_toml(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        if path.suffix.lower() != ".toml":
            raise DesignError(f"Expected a .toml file name, got {path.name!r}")
        text = scenario_toml(self.scenario_data())
        self._parse(tomllib.loads(text))  # what is written reads back
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, text.encode())
        return path

    def save_to_library(self, name: str) -> str:
        from posedb import PoseLibrary

        if self.db is None:
            raise DesignError("Saving to the library needs one: start the studio with --db")
        name = check_name(name)
        result = {}
        if self.last is not None:
            result = {"iterations": self.last.result.iterations,
                      "stop_reason": self.last.result.stop_reason,
                      "persons": self.last.persons,
                      "control": self.last.result.control.tolist()}
        with PoseLibrary(self.db).edit() as ed:
            ed.put_scenario(name, json.dumps(self.scenario_data(), sort_keys=True),
                            json.dumps(result, sort_keys=True), source="studio")
        return name

    def export(self, out_dir: str | os.PathLike,
               progress: Callable[[str], None] | None = None) -> dict:
        """Fits and writes everything as `sitrelax fit` does (surface, control mesh, bodies,
        pictures, report.json, and the scenario as scenario.toml)."""
        out = Path(out_dir)
        report = run_fit(self.scenario(), out, db=self.db, progress=progress)
        self.save_toml(out / "scenario.toml")
        return report

