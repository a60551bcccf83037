"""A design session: the people, the control mesh and the fit's parameters as a designer edits
them in the studio, and what can be done with them: fit, relax, save (library or TOML), export.

The session is plain data (scenario person tables, a control mesh, parameters) turned into a
`Scenario` by `parse_scenario` (the scenario schema: its defaults, its checks) whenever it
runs, so everything the studio does is what `sitrelax fit` would do with the same scenario
file. Posed people are cached by their table, and a person moved (nothing else changed) is
the posed body moved, not posed again, so a drag costs no posing.

Every edit is one step of the session's history (`undo`, `redo`): the people, the control mesh,
the fixed vertices, the creases, the parameters, and the fit and relaxed bodies that went with
them. Edits made inside one `edit(group)` block, or one after another in the same group (a
drag's many moves), are one step.

A scenario opened in the session (`Design.open_scenario`) keeps what the panel does not edit:
the other fit parameters, `[evaluation]`, `[relief]` and every field of each person are written
back as they were read, and its grid or template stays the scenario's start (written as such)
while the control mesh, its creases and (for a template, built around them) the people are
those it made.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import io
import json
import os
import tempfile
import time
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from capture.files import write_atomic
from solver.contact.pressure import reachable
from solver.mesh import split_quad
from solver.scene import schema
from solver.scene.quality import design_misses, surface_misses
from solver.surface.fit import FitResult
from solver.scene.run import (SURFACE_FORMATS, checked_guarantees, evaluate_fit,
                              fit_guarantees, fit_people, relax_person, relax_text, relieve_fit,
                              run_fit, save_relaxed)
from solver.scene.scenario import (PersonSpec, Scenario, ScenarioError, parse_scenario,
                                   read_control_mesh, reads_no_file, scenario_content,
                                   scenario_toml)
from solver.scene.design import RELIEF_ROUNDS, shared_given
from solver.scene.placement import (PlacedPerson, furnished, place_person, scene_posture,
                                    skin_support)
from solver.surface.subdivision import subdivision

PARAMETERS = ("level", "sigma", "tau_max", "margin")  # the ones the studio's panel sets
MAX_PEOPLE = 8
MAX_CONTROL_VERTICES = 2000
MAX_HISTORY = 200  # undo steps kept
# a seated capture: what a new person sits in until the designer picks another pose
DEFAULT_POSE = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
SEAT_REGIONS = frozenset({"pelvis", "thighs"})  # a person supported on these sits on the surface
# the templates a design may start from: name -> (kind, parameters, the use each person is then
# supported as, `posedb.regions.SUPPORT_USES`); `sitrelax design` gives seated people a chair or
# a bench with a back, supported as on a chair, and perched ones a stool or a backless bench,
# supported as on a stool (the studio's backless bench supports the thighs too: a seat); the
# chair and the bench with a back without seams, as `sitrelax design` makes them (a sharp
# seat-back seam folded back on itself into slits, up to 177 degrees across it)
TEMPLATES = {"chair": ("chair", {"seams": False}, "chair"),
             "bench with back": ("bench", {"back": True, "seat_each": True, "seams": False},
                                 "chair"),
             "bench": ("bench", {}, "seat"), "stool": ("stool", {}, "stool"),
             "floor cushion": ("floor_cushion", {}, "floor"), "lounger": ("lounger", {}, "lounger"),
             "bed": ("bed", {}, "bed")}
ONE_PERSON = ("chair", "stool")  # kinds for one person (several share a bench)


def template_name(table: dict) -> str:
    """The `TEMPLATES` name of a scenario's `[surface] template` table (its `kind`, and for a
    bench whether it has a back): what the studio's Template list calls it."""
    kind = table.get("kind")
    names = [name for name, (k, _, _) in TEMPLATES.items() if k == kind]
    if not names:
        raise DesignError(f"Expected a template kind of "
                          f"{', '.join(sorted({k for k, _, _ in TEMPLATES.values()}))}, "
                          f"got {kind!r}")
    back = bool(table.get("back", False))
    return next((name for name in names if bool(TEMPLATES[name][1].get("back", False)) == back),
                names[0])


def _template_problem(name: str, message: str) -> str:
    """A template's refusal (the scenario's `ScenarioError`) in the studio's terms: what no
    template fits, and what the designer can change here (the people's Position and Rotation)."""
    _, _, why = message.partition(": surface.template")
    field, _, why = why.partition(": ")
    why = why.replace(" or give its height", "").replace(
        "give the template's heading_deg", "turn them (Rotation) to face one way").replace(
        "each person's position y", "each person's Position y")
    if field:  # a dimension measured on the people that makes no such furniture
        why = (f"its {field.lstrip('.')} measured on the people makes none ({why}): place them "
               f"as one sits in a {name}")
    return f"No {name} can be built around the people as they are placed: {why}"


class DesignError(ValueError):
    """An edit or a run the session cannot make (the message says why)."""


NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_. ")
MAX_NAME = 80


def control_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) int: the edges of control quads `faces` (F, 4), each once, smaller index first."""
    f = np.asarray(faces)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 3]], f[:, [3, 0]]])
    return np.unique(np.sort(edges, axis=1), axis=0)


def moved_to(placed: PlacedPerson, spec: PersonSpec, clear: np.ndarray) -> PlacedPerson:
    """`placed`, posed at position (0, 0, 0), moved to `spec.position` (metres), `spec` its
    scenario person at that position (nothing else changed): the body `place_person(spec)`
    makes there, bit for bit, without posing it again.

    The skin vertices and the placement are moved by the same vector (added to zeros: exact),
    and what `place_person` measures on the placed skin (areas, normals, the parts asked for,
    the importance) is measured again on the moved one: a body differing by rounding alone
    (normals of 1e-14) settled otherwise than the one `sitrelax fit` places (one tipped over,
    the other found no rest). `clear` (V,) bool, of `reach_everywhere(placed)`: the vertices
    whose outward normal does not run back into the body, which the reach is taken from: its
    inside tests, the costly part (a winding-number tree of the skin), are made once at the
    origin (the same wherever the body stands, but for a probe within rounding of the skin)."""
    if any(placed.spec.position):
        raise ValueError(f"Expected a body posed at position (0, 0, 0), got one at "
                         f"{list(placed.spec.position)}")
    shift = np.asarray(spec.position, dtype=np.float64)
    transform = placed.transform.copy()
    transform[:3, 3] += shift
    vertices = placed.vertices + shift
    areas, normals, importance = skin_support(placed.body, spec.support, vertices, clear)
    return dataclasses.replace(placed, vertices=vertices, normals=normals, areas=areas,
                               importance=importance, spec=spec, transform=transform)


def reach_everywhere(placed: PlacedPerson) -> np.ndarray:
    """(V,) bool: `reachable` asked of every skin vertex of `placed` (for `moved_to`)."""
    return reachable(placed.vertices, placed.body.triangles, placed.normals,
                     np.ones(len(placed.vertices), dtype=bool))


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
    limit: np.ndarray | None = None  # (ns, 3) m: the level-s vertices' limit points (exported)
    data: dict | None = None  # the scenario data (`Design.scenario_data`) it is the fit of
    relief: dict | None = None  # the `[relief]` asked (rounds, target) when rounds were kept
    params: object = None  # the fit's `FitParams` (margin, floor, creases): what it is judged by
    # the surface's guarantees as the export's report.json holds them (`fit_guarantees`), once
    # judged (`Design.judge`), and the seconds the check took
    guarantees: dict | None = None
    judge_seconds: float | None = None


@dataclass(frozen=True)
class Iterate:
    """One accepted iterate of a running fit, to show the fit as it goes (`Design.fit`).

    iteration : the fit's iteration that accepted it (1, 2, ...).
    control : (n0, 3) float, metres: its control vertices; faces : (F0, 4) int, the control
        quads.
    surface : (ns, 3) float, metres: its level-s surface vertices (not their limit points);
        surface_faces : (Fs, 4) int, the level-s quads (those of the finished fit's surface).
    """

    iteration: int
    control: np.ndarray
    faces: np.ndarray
    surface: np.ndarray
    surface_faces: np.ndarray


@dataclass
class RelaxOutcome:
    person: int
    vertices: np.ndarray
    faces: np.ndarray
    before: dict
    after: dict
    seconds: float
    summary: str = ""  # what the relaxation accepted and why (`relax_text`)
    placed: PlacedPerson | None = None  # the person as posed for it
    result: object = None  # the solver's `RelaxResult` (what `save_relaxed` stores)


_STATE = ("people", "vertices", "faces", "fixed", "creases", "params", "last", "relaxed",
          "kept", "start")
# a scenario's [surface] fields of the session's control mesh and panel; the others are kept
_SURFACE_EDITED = frozenset({"grid", "control_mesh", "template", "fixed", "creases",
                             *PARAMETERS})
_STARTS = ("grid", "template")  # the surfaces a scenario starts from that it may keep


class Design:
    def __init__(self, db: str | os.PathLike | None = None):
        self.db = str(db) if db is not None else None
        self.people: list[dict] = []
        self.params = {name: schema.default(schema.Surface, name) for name in PARAMETERS}
        self.fixed: set[int] = set()
        self.creases: set[tuple[int, int]] = set()  # control edges (i < j) kept sharp
        self.vertices = np.zeros((0, 3))
        self.faces = np.zeros((0, 4), dtype=np.int64)
        self.last: FitOutcome | None = None
        # what an opened scenario sets that the session does not edit (`open_scenario`): the
        # other [surface] fields under "surface", and [evaluation] and [relief] as read
        self.kept: dict = {}
        # an opened scenario's grid or template: {"key", "table", "creases" (its own),
        # "vertices", "faces", "built" (the creases made), "people"} (`_start_holds`)
        self.start: dict | None = None
        # the newest accepted iterate of a fit a newer edit cancelled, while it is newer than
        # `last`: the next warm fit goes on from it (what the tabs show), no step of the history
        self.resume: FitResult | None = None
        self._resumable = 0  # counts the edits after which no running fit may become `resume`
        self.relaxed: dict[int, RelaxOutcome] = {}  # person -> its relaxed body
        self._placed: dict[str, PlacedPerson] = {}
        # by the table at position (0, 0, 0): the body there and `reach_everywhere` of it
        self._posed: dict[str, tuple] = {}
        self._undo: list[dict] = []
        self._redo: list[dict] = []
        self._group: str | None = None  # the group of the last step (its edits coalesce)
        self._depth = 0
        self.new_grid(**schema.Grid().model_dump())  # the scenario's default start
        self._undo.clear()  # the start is no step

    # history ----------------------------------------------------------------------------
    def _state(self) -> dict:
        return {"people": copy.deepcopy(self.people), "vertices": self.vertices.copy(),
                "faces": self.faces.copy(), "fixed": set(self.fixed),
                "creases": set(self.creases), "params": dict(self.params),
                "last": self.last, "relaxed": dict(self.relaxed),
                "kept": copy.deepcopy(self.kept), "start": self.start}

    def snapshot(self) -> dict:
        """The session's state (people, control mesh, parameters, the last fit), to start
        another session from (`restore`): its history stays behind."""
        return self._state()

    def restore(self, state: dict) -> None:
        """Takes a `snapshot`'s state as one step of the history."""
        with self.edit():
            self._restore(copy.copy(state))

    def _restore(self, state: dict) -> None:
        for name in _STATE:
            setattr(self, name, state[name])
        self._forget_resume()  # a warm fit goes on from the fit restored with the state

    @contextlib.contextmanager
    def edit(self, group: str | None = None):
        """One step of the history around the edits made inside (nested edits join it). A
        step of the same `group` as the step before joins that one (None: never joins). If an
        edit inside fails, the session is left as it was before the block."""
        if self._depth:
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
            return
        before = self._state()
        self._depth = 1
        try:
            yield
        except BaseException:
            self._restore(before)
            raise
        finally:
            self._depth = 0
        if group is None or group != self._group:
            self._undo.append(before)
            del self._undo[:-MAX_HISTORY]
        self._group = group
        self._redo.clear()

    def end_group(self) -> None:
        """The next edit starts a step of its own (a drag ended)."""
        self._group = None

    def undo(self) -> None:
        """Back to the state before the last step (fit and relaxed bodies included)."""
        self._step(self._undo, self._redo, "undo")

    def redo(self) -> None:
        """The step undone last, again."""
        self._step(self._redo, self._undo, "redo")

    def _step(self, source: list, target: list, what: str) -> None:
        if not source:
            raise DesignError(f"Nothing to {what}")
        target.append(self._state())
        self._restore(source.pop())
        self._group = None

    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    # the control mesh -------------------------------------------------------------------
    def new_grid(self, size, resolution, height: float) -> None:
        data = {"surface": {"grid": {"size": list(size), "resolution": list(resolution),
                                     "height": height}},
                "person": [{"pose": "db:any"}]}
        scenario = parse_scenario(data, "grid")  # the scenario's own checks
        with self.edit():
            self._set_mesh(scenario.surface.vertices, scenario.surface.faces)

    def load_control_mesh(self, path: str | os.PathLike) -> None:
        v, f = read_control_mesh(Path(path), str(path))
        with self.edit():
            self._set_mesh(v, f)

    def build_template(self, name: str) -> str:
        """The control mesh of a template (`TEMPLATES`: chair, bench with back, bench, stool,
        floor cushion, lounger, bed) built around the people as they are placed now, every
        dimension measured on them as `sitrelax design` does (`solver.scene.furnish`; a bed as
        many quads across each sleeper as a bed for one), its creases kept sharp, and each
        person supported as the template's use (a chair's back carries the back): one step.
        Returns the use."""
        if name not in TEMPLATES:
            raise DesignError(f"Expected a template of {', '.join(TEMPLATES)}, got {name!r}")
        if not self.people:
            raise DesignError("Add a person first: a template is built around the people")
        kind, given, use = TEMPLATES[name]
        if kind in ONE_PERSON and len(self.people) > 1:
            raise DesignError(f"A {name} is for one person: {len(self.people)} people share a "
                              f"bench (with a back for a chair's support)")
        given = {**given, **shared_given(kind, len(self.people))}
        people = [dict(p, support=use) for p in self.people]
        data = self._data(people=people)
        data["surface"] = {"template": {"kind": kind, **given}, **self.params,
                           **self.kept.get("surface", {})}
        try:
            built = furnished(self._parse(data), [self.place(p) for p in people])
        except ScenarioError as exc:
            raise DesignError(_template_problem(name, str(exc))) from None
        with self.edit():
            self._set_mesh(built.surface.vertices, built.surface.faces)
            self.creases = {(min(a, b), max(a, b)) for a, b in built.surface.params.creases}
            self.people = people
            self.relaxed = {}  # (relaxed as they were supported)
        return use

    def _set_mesh(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        if len(vertices) > MAX_CONTROL_VERTICES:
            raise DesignError(f"A studio control mesh has at most {MAX_CONTROL_VERTICES} "
                              f"vertices (a fit stays interactive), got {len(vertices)}")
        self.vertices = np.asarray(vertices, dtype=np.float64).copy()
        self.faces = np.asarray(faces, dtype=np.int64).copy()
        self.fixed = set()
        self.creases = set()
        self.last = None
        self._forget_resume()

    def move_vertex(self, j: int, position, group: str | None = None) -> None:
        self.move_vertices([j], np.asarray(position, dtype=np.float64)[None], group)

    def move_vertices(self, indices: Iterable[int], positions, group: str | None = None) -> None:
        """Puts control vertices `indices` at `positions` ((k, 3) metres): one step."""
        js = [int(j) for j in indices]
        for j in js:
            self._vertex(j)
        p = np.asarray(positions, dtype=np.float64)
        # (the scenario's own bound: a control mesh beyond it would fail every fit after)
        if p.shape != (len(js), 3) or not np.all(np.abs(p) <= schema.MAX_COORDINATE):
            raise DesignError(f"Expected a finite [x, y, z] (each from -{schema.MAX_COORDINATE:g} "
                              f"to {schema.MAX_COORDINATE:g} m) for each of control vertices {js}, "
                              f"got {np.asarray(positions).tolist()!r}")
        moved = self.vertices.copy()  # the history holds the old array; a fit reads either
        moved[js] = p
        with self.edit(group):
            self.vertices = moved

    def set_fixed(self, j: int | Iterable[int], fixed: bool) -> None:
        """Fixes (or frees) control vertex `j`, or each of several: one step."""
        js = [int(j)] if np.isscalar(j) else [int(i) for i in j]
        for i in js:
            self._vertex(i)
        with self.edit():
            self.fixed = (self.fixed | set(js)) if fixed else (self.fixed - set(js))

    def control_edges(self) -> np.ndarray:
        """(E, 2) int: the control mesh's edges, each once, smaller index first."""
        return control_edges(self.faces)

    def set_crease(self, i: int, j: int, sharp: bool = True) -> None:
        """Makes the control edge between vertices i and j a crease (or smooth again)."""
        self._vertex(i)
        self._vertex(j)
        edge = (min(int(i), int(j)), max(int(i), int(j)))
        if not (self.control_edges() == edge).all(axis=1).any():
            raise DesignError(f"Expected two vertices sharing a control edge for a crease, got "
                              f"{i} and {j}")
        with self.edit():
            self.creases = (self.creases | {edge}) if sharp else (self.creases - {edge})

    def split_face(self, face: int) -> list[int]:
        """Splits control quad `face` into four (its row and column halved, `split_quad`, so
        the mesh stays all quads); returns the new vertices' indices."""
        if not 0 <= face < len(self.faces):
            raise DesignError(f"Expected a control face in 0..{len(self.faces) - 1}, got {face}")
        v, f, creases = split_quad(self.vertices, self.faces, face, sorted(self.creases))
        if len(v) > MAX_CONTROL_VERTICES:
            raise DesignError(f"A studio control mesh has at most {MAX_CONTROL_VERTICES} "
                              f"vertices (a fit stays interactive), the split makes {len(v)}")
        n = len(self.vertices)
        with self.edit():
            self.vertices, self.faces = v, f
            self.creases = {(min(a, b), max(a, b)) for a, b in creases}
            self.last = None  # its control mesh is another's now
            self._forget_resume()
        return list(range(n, len(v)))

    def face_of(self, vertices: Iterable[int]) -> int:
        """The one control quad whose corners include all the given vertices."""
        js = {int(j) for j in vertices}
        found = [k for k, quad in enumerate(self.faces.tolist()) if js and js <= set(quad)]
        if len(found) != 1:
            raise DesignError(f"Expected corners of exactly one control face (three or four of "
                              f"them pick one), got vertices {sorted(js)}, corners of "
                              f"{len(found)} faces")
        return found[0]

    def _vertex(self, j: int) -> None:
        if not 0 <= j < len(self.vertices):
            raise DesignError(f"Expected a control vertex in 0..{len(self.vertices) - 1}, "
                              f"got {j}")

    def adopt_fit(self) -> None:
        """Makes the last fit's control mesh the start of the next (fixed vertices kept)."""
        if self.last is None:
            raise DesignError("Nothing fitted yet: press Fit first")
        with self.edit():
            self.vertices = self.last.result.control.copy()

    def set_parameter(self, name: str, value: float) -> None:
        if name not in PARAMETERS:
            raise DesignError(f"Expected a parameter from {PARAMETERS}, got {name!r}")
        if name == "level" and float(value).is_integer():
            value = int(value)  # sliders send whole numbers as floats
        trial = dict(self.params, **{name: value})
        self._parse(self._data(params=trial, people=[{"pose": "db:any"}]))
        with self.edit(f"parameter {name}"):
            self.params = trial

    # the people -------------------------------------------------------------------------
    def add_person(self, pose: str, **fields) -> int:
        if len(self.people) >= MAX_PEOPLE:
            raise DesignError(f"A studio scene holds at most {MAX_PEOPLE} people")
        person = {"name": f"person {len(self.people) + 1}", "pose": pose,
                  **schema.person_defaults(), **fields}
        self._check_person(person)
        with self.edit():
            self.people = self.people + [person]
        return len(self.people) - 1

    def update_person(self, k: int, group: str | None = None, **fields) -> None:
        person = dict(self._person(k), **fields)
        # a move or a turn only needs the fields checked; a new pose or body is made now
        self._check_person(person, make=bool({"pose", "body"} & set(fields)))
        with self.edit(group):
            self.people = [person if i == k else p for i, p in enumerate(self.people)]
            # its relaxed body was relaxed where it was, as it was
            self.relaxed = {i: r for i, r in self.relaxed.items() if i != k}

    def remove_person(self, k: int) -> None:
        self._person(k)
        with self.edit():
            self.people = [p for i, p in enumerate(self.people) if i != k]
            self.relaxed = {i - (i > k): r for i, r in self.relaxed.items() if i != k}
            self.last = None
        self._forget_resume()

    def _person(self, k: int) -> dict:
        if not 0 <= k < len(self.people):
            raise DesignError(f"Expected a person in 0..{len(self.people) - 1}, got {k}")
        return self.people[k]

    def _check_person(self, person: dict, make: bool = True) -> None:
        self._parse(self._data(people=[person]))
        if make:  # the pose must exist and the body must be made
            self.place(dict(person, position=[0.0, 0.0, 0.0], rotation_deg=[0.0, 0.0, 0.0]))

    def place(self, person: dict) -> PlacedPerson:
        """The person (a table of the session) posed and placed (`place_person`), cached by its
        table. Each pose and body is posed once, at position (0, 0, 0), and moved from there to
        where the person stands (`moved_to`: the body `place_person` makes there, bit for bit,
        so the figures are those `sitrelax fit` finds), so a drag does not pose the body again
        at every step."""
        key = json.dumps(person, sort_keys=True)
        if key not in self._placed:
            spec = self._parse(self._data(people=[person])).persons[0]
            if len(self._placed) > 64:
                self._placed.clear()
                self._posed.clear()
            # posed at the origin once, moved from there (bit for bit `place_person`'s)
            origin = dict(person, position=[0.0, 0.0, 0.0])
            anywhere = json.dumps(origin, sort_keys=True)
            if anywhere not in self._posed:
                self._posed[anywhere] = (place_person(
                    self._parse(self._data(people=[origin])).persons[0], self.db), None)
            posed, clear = self._posed[anywhere]
            if spec.position != posed.spec.position and clear is None:
                clear = reach_everywhere(posed)
                self._posed[anywhere] = (posed, clear)
            self._placed[key] = posed if spec.position == posed.spec.position else \
                moved_to(posed, spec, clear)
        return self._placed[key]

    # scenarios ----------------------------------------------------------------------------
    def _data(self, *, params: dict | None = None, people: list | None = None) -> dict:
        surface = {"control_mesh": {"vertices": self.vertices.tolist(),
                                    "faces": self.faces.tolist()},
                   **(params or self.params), **copy.deepcopy(self.kept.get("surface", {}))}
        if self.fixed:
            surface["fixed"] = sorted(self.fixed)
        if self.creases:
            surface["creases"] = [list(c) for c in sorted(self.creases)]
        tables = {key: copy.deepcopy(self.kept[key]) for key in ("evaluation", "relief")
                  if key in self.kept}
        return {"surface": surface, **tables,
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

    def open_scenario(self, text: bytes | str, name: str = "<scenario>",
                      base: str | os.PathLike | None = None) -> Scenario:
        """Replaces the session by the scenario in `text` (a scenario file's TOML): one step.

        Parameters
        ----------
        text : the file's content (UTF-8 bytes, or its text).
        name : what the problems start with (the file's name).
        base : the folder its relative paths are relative to, when the scenario was read from
            one the studio may read: its OBJ control mesh (or a joint map's file) is then read
            from there into the session; None (an upload, which comes alone): the scenario
            must name no file.

        Everything the session does not edit is kept as read (`kept`, each person's table),
        and a grid or template stays the start that "Save TOML" writes (`start`): saved at
        once, the scenario parses to what was opened. A template is built around the people
        as `sitrelax fit` builds it (its unset dimensions measured on them). People pose from
        the library (`db:`) or the bundled recordings (`bvh:bundled:`) only.

        Returns
        -------
        Scenario: the opened one (`parse_scenario` of the file). Raises DesignError (or the
        scenario's ScenarioError, naming the field) and leaves the session as it was when the
        file is not UTF-8, not TOML, no valid scenario, or names a file the studio cannot read.
        """
        data = scenario_content(text, name)
        schema.validate(data, name)  # unknown keys, bounds: the field named
        surface = copy.deepcopy(data["surface"])
        base_dir = Path(base) if base is not None else None
        people = [self._opened_person(p, k, name, base_dir)
                  for k, p in enumerate(data["person"])]
        if len(people) > MAX_PEOPLE:
            raise DesignError(f"{name}: a studio scene holds at most {MAX_PEOPLE} people, the "
                              f"scenario has {len(people)}")
        if isinstance(surface.get("control_mesh"), str):
            mesh = surface["control_mesh"]
            if base_dir is None:
                raise DesignError(f"{name}: surface.control_mesh names the file {mesh!r} beside "
                                  f"it, which the studio was not given (an uploaded scenario "
                                  f"comes alone): give the control mesh inline ({{vertices, "
                                  f"faces}}), or open the scenario with a grid and load "
                                  f"{Path(mesh).name} with Load control mesh (OBJ)")
            v, f = read_control_mesh((base_dir / mesh).resolve(), name)
            surface["control_mesh"] = {"vertices": v.tolist(), "faces": f.tolist()}
        inline = {**data, "surface": surface, "person": people}
        opened = parse_scenario(inline, name, files=False)  # the checks that need the mesh
        params = {key: surface.get(key, schema.default(schema.Surface, key))
                  for key in PARAMETERS}
        kept = {"surface": {k: v for k, v in surface.items() if k not in _SURFACE_EDITED}}
        kept.update({key: copy.deepcopy(data[key]) for key in ("evaluation", "relief")
                     if key in data})
        placed = []
        for k, person in enumerate(people):  # each pose found, each body made
            try:
                placed.append(self.place(person))
            except (ValueError, OSError) as exc:  # a library pose, a bundled recording missing
                raise DesignError(f"{name}: person[{k}]: {exc}") from None
        given = [tuple(c) for c in surface.get("creases", [])]
        start = None
        if opened.surface.template is not None:
            try:
                built = furnished(opened, placed).surface
            except ScenarioError as exc:
                raise DesignError(str(exc)) from None
            vertices, faces, creases = built.vertices, built.faces, built.params.creases
        else:
            vertices, faces, creases = (opened.surface.vertices, opened.surface.faces,
                                        opened.surface.params.creases)
        creases = {(min(a, b), max(a, b)) for a, b in creases}
        key = next((k for k in _STARTS if k in surface), None)
        if key is not None:
            start = {"key": key, "table": copy.deepcopy(surface[key]),
                     "creases": [list(c) for c in given], "vertices": np.array(vertices),
                     "faces": np.array(faces), "built": frozenset(creases),
                     "people": copy.deepcopy(people)}
        with self.edit():
            self._set_mesh(vertices, faces)
            self.fixed = {int(j) for j in surface.get("fixed", [])}
            self.creases = creases
            self.params = params
            self.people = people
            self.kept = kept
            self.start = start
            self.relaxed = {}
        return opened

    def _opened_person(self, table: dict, k: int, name: str, base: Path | None) -> dict:
        """Person `k` of an opened scenario as the session holds people (a name and the
        placement and support filled in where the file leaves them to their defaults), its
        pose one the studio can pose and its joint map inline."""
        at = f"{name}: person[{k}]"
        pose = table["pose"]
        if not reads_no_file(pose):
            raise DesignError(f"{at}.pose names the BVH file of {pose!r}, which the studio "
                              f"does not read: pose the people from the library (db:NAME) or "
                              f"a bundled recording (bvh:bundled:NAME#frame=N)")
        person = {"name": f"person {k + 1}", **schema.person_defaults(),
                  **copy.deepcopy(table)}
        if isinstance(person.get("joint_map"), str):
            if base is None:
                raise DesignError(f"{at}.joint_map names the file {person['joint_map']!r} "
                                  f"beside it, which the studio was not given (an uploaded "
                                  f"scenario comes alone): give the joint map inline")
            from capture.jointmap import JointMapError, read_joint_map

            try:
                person["joint_map"] = read_joint_map(base / person["joint_map"])
            except JointMapError as exc:
                raise DesignError(f"{at}.joint_map: {exc}") from None
        return person

    def _start_holds(self) -> bool:
        """Whether the opened scenario's grid or template is the session's start still: its
        control mesh and creases unedited and (a template's, built around them) its people
        as they were."""
        start = self.start
        return start is not None and np.array_equal(start["vertices"], self.vertices) and \
            np.array_equal(start["faces"], self.faces) and start["built"] == self.creases \
            and (start["key"] != "template" or start["people"] == self.people)

    def saved_data(self, as_fitted: bool = False) -> dict:
        """The scenario "Save TOML" writes: `scenario_data`, with an opened scenario's grid or
        template (and its own creases) in place of the control mesh while it holds, and the
        relief rounds of the fit on screen when it was relieved. `as_fitted` (an export's,
        beside the fit on screen): the relief that fit had, none when it had none (an opened
        scenario's `[relief]`, which the studio's fit does not run, is left out)."""
        data = self.scenario_data()
        if as_fitted:
            data.pop("relief", None)
        if self._start_holds():
            surface = data["surface"]
            del surface["control_mesh"]
            surface.pop("creases", None)
            surface = {self.start["key"]: copy.deepcopy(self.start["table"]), **surface}
            if self.start["creases"]:
                surface["creases"] = copy.deepcopy(self.start["creases"])
            data["surface"] = surface
        if self.fitted and self.last.relief is not None:  # (the fit on screen was relieved)
            data["relief"] = self.last.relief
        return data

    def fit(self, progress: Callable[[int, float, float], None] | None = None, *,
            warm: bool = False, cancel: Callable[[], bool] | None = None,
            iterates: Callable[[Iterate], None] | None = None) -> FitOutcome | None:
        """Fits the session as it is now and evaluates the fit (what `fit_scene` does), and
        keeps the outcome as `last`.

        Parameters
        ----------
        progress : optional callback (iteration, energy, tau) after each accepted iteration.
        warm : refit from the newest fit of a control mesh with the same vertices and quads:
            the last fit's result, or the last accepted iterate of a fit cancelled since
            (`resume`); a cold fit when there is none.
        cancel : optional callable, asked between iterations and before the evaluation: True
            stops the fit, which then returns None and leaves `last` as it was (a newer edit
            outdated it); its last accepted iterate becomes `resume`.
        iterates : optional callback given every accepted iterate (`Iterate`: its control and
            level-s vertices with their faces) as the fit goes, on the fitting thread.
        """
        start, resumable = time.perf_counter(), self._resumable
        if cancel is not None and cancel():
            return None
        data = self.scenario_data()
        scenario = self._parse(data)
        people = [self.place(p) for p in self.people]
        params, faces = scenario.surface.params, scenario.surface.faces
        each = None
        if iterates is not None:  # the fit's own subdivision (cached by topology): its faces
            surface_faces = subdivision(len(scenario.surface.vertices), faces, params.level,
                                        params.creases or None).faces

            def shown(iteration: int, control: np.ndarray, surface: np.ndarray) -> None:
                iterates(Iterate(iteration, control, faces, surface, surface_faces))
            each = shown
        result = fit_people(scenario, people, progress, warm=self._warm_start() if warm else None,
                            cancel=cancel, iterates=each)
        if result.stop_reason.startswith("cancelled") or (cancel is not None and cancel()):
            self._keep_resume(result, resumable)
            return None  # no evaluation: a newer edit wants another fit
        limit, persons, settles = evaluate_fit(scenario, people, result)
        if cancel is not None and cancel():
            self._keep_resume(result, resumable)
            return None
        self.last = FitOutcome(result, people, persons, [m.pressure_kpa for m in settles],
                               time.perf_counter() - start, limit, data,
                               params=scenario.surface.params)
        self.resume = None
        self.relaxed = {}  # relaxed onto the surface before
        return self.last

    def relieve(self, rounds: int = RELIEF_ROUNDS, target: float | None = None,
                say: Callable[[str], None] | None = None) -> dict:
        """Rounds of pressure relief (`solver.scene.relief`, as a scenario's `[relief]` asks
        `sitrelax fit` for them) after the last fit, which must be of the session as it is
        now: the fit kept becomes `last` (the relaxed poses, relaxed onto the surface before,
        go), and the scenario saved of it asks for the same rounds (`save_toml`). Returns
        report.json's `relief` (`Relief.record`)."""
        if not self.fitted:
            raise DesignError("Fit first: relief eases the fitted surface where it presses "
                              "hardest (the session has no fit, or was edited since)")
        if self.last.relief is not None:  # (a scenario saved of it must give it again)
            raise DesignError("The fit on screen is relieved already: press Fit to start over")
        start = time.perf_counter()
        relief = schema.Relief(rounds=rounds, **({} if target is None else {"target": target}))
        scenario = dataclasses.replace(self._parse(self.last.data), relief=relief)
        people, result = self.last.people, self.last.result
        _, persons, maps = evaluate_fit(scenario, people, result)  # (the settles again)
        # (fit, guarantees, seconds) of the fits whose guarantees are known: the first's when
        # judged already, and those relief checks
        checked = [] if self.last.guarantees is None else \
            [(result, self.last.guarantees, self.last.judge_seconds)]
        result, persons, maps, done = relieve_fit(scenario, people, result, persons, maps, say,
                                                  checked=checked)
        if done.kept:
            self.last = FitOutcome(result, people, persons, [m.pressure_kpa for m in maps],
                                   time.perf_counter() - start,
                                   result.limit_surface(scenario.surface.params.creases),
                                   self.last.data, relief.model_dump(),
                                   params=scenario.surface.params)
            # the kept fit was checked against the bars the first met: judged already
            known = checked_guarantees(checked, result)
            if known is not None:
                self.last.guarantees, self.last.judge_seconds = known
            self.resume = None
            self.relaxed = {}
        return done.record()

    def _keep_resume(self, result: FitResult, resumable: int) -> None:
        """A cancelled fit's result for the next warm fit to go on from, if it got somewhere
        and nothing since its start dropped the fits (another control mesh, a person removed,
        an undo)."""
        if result.energy_terms.get("best_iteration", 0) > 0 and resumable == self._resumable:
            self.resume = result

    def _forget_resume(self) -> None:
        self.resume = None
        self._resumable += 1

    def _warm_start(self) -> FitResult | None:
        """The newest fit to refit from (`resume`, else `last`'s) when its control mesh has the
        session's vertices and quads."""
        newest = self.resume or (self.last.result if self.last is not None else None)
        if newest is None or newest.control.shape != self.vertices.shape or \
                not np.array_equal(newest.faces, self.faces):
            return None  # another control mesh: nothing to start from
        return newest

    def pose_warnings(self) -> list[str]:
        """Why a person cannot sit on the surface, before any fit: a pose the posture
        classifier (`solver.body.posture`) reads as standing, supported as on a seat."""
        from posedb.regions import support_regions

        warnings = []
        for person in self.people:
            # (the posture is the same wherever the person stands: the body posed at the
            # origin, kept, is read; a drag then measures no body at every step)
            at_origin = dict(person, position=[0.0, 0.0, 0.0])
            if SEAT_REGIONS & set(support_regions(person["support"])) and \
                    scene_posture(self.place(at_origin)) == "standing":
                warnings.append(f"{person['name']} stands ({person['pose']}): a standing pose "
                                f"cannot sit on the surface; pick a seated one")
        return warnings

    def judge(self, outcome: FitOutcome | None = None) -> dict:
        """The surface guarantees of a fit (`outcome`, default the last) as the export's
        report.json holds them (`fit_guarantees`: self-crossings, folds over 60 degrees, slits
        across a crease, the floor, and the deepest cut on a dense sampling against the margin
        plus 1 mm), checked once and kept with the fit (`FitOutcome.guarantees`).

        The check is no part of `fit`: it takes far longer than a warm refit (0.11 s for one
        seated person on an 8 x 6 grid at level 3, 1.3 s for six, the dense sampling most of
        it), so the studio asks for it once a fit has settled. It reads the fit alone (its
        result, its people, its parameters), never the session, so it may run beside edits."""
        outcome = self.last if outcome is None else outcome
        if outcome is None:
            raise DesignError("Fit first: the guarantees are those of a fitted surface")
        if outcome.guarantees is None:
            start = time.perf_counter()
            guarantees = fit_guarantees(outcome.result, outcome.people, outcome.params)
            outcome.judge_seconds = time.perf_counter() - start
            outcome.guarantees = guarantees
        return outcome.guarantees

    def surface_warnings(self) -> list[str]:
        """What the last fit's surface misses of its guarantees, in report.json's words
        (`solver.scene.quality.surface_misses`); none before it is judged (`judge`)."""
        if self.last is None or self.last.guarantees is None:
            return []
        return surface_misses(self.last.guarantees)

    def result_warnings(self) -> list[str]:
        """What the last fit misses of the bars: its surface's guarantees once judged
        (`surface_warnings`), then each person's (`solver.scene.quality.design_misses`)."""
        if self.last is None:
            return []
        # the margin the fit on screen was made with (the panel's may have changed since)
        margin = (self.last.data or {}).get("surface", {}).get("margin", self.params["margin"])
        return self.surface_warnings() + [m for p in self.last.persons
                                          for m in design_misses(p, margin)]

    def relax(self, k: int) -> RelaxOutcome:
        self._person(k)
        if self.last is None:
            raise DesignError("Fit first: a person relaxes onto the fitted surface")
        start = time.perf_counter()
        person = self.place(self.people[k])
        scenario = self.scenario()  # (onto the limit surface, as the fit is evaluated)
        res, before, after, _ = relax_person(
            scenario, person, self.last.result.limit_surface(scenario.surface.params.creases),
            self.last.result.surface_faces)
        outcome = RelaxOutcome(k, res.vertices, person.body.triangles, before, after,
                               time.perf_counter() - start, relax_text(res), person, res)
        with self.edit():
            self.relaxed = {**self.relaxed, k: outcome}
        return outcome

    def save_relaxed(self, k: int) -> dict:
        """Stores person k's relaxed pose in the library, one commit (`save_relaxed`): a
        one-frame take of origin "relaxed" and a pose "<origin>-relaxed"; returns its id and
        name."""
        if self.db is None:
            raise DesignError("Saving a pose needs a library: start the studio with --db")
        self._person(k)
        outcome = self.relaxed.get(k)
        if outcome is None:
            raise DesignError(f"Relax {self.people[k]['name']} first")
        # as `sitrelax relax --save` does: a relaxation that kept the captured pose stores it
        return save_relaxed(self.db, [(outcome.placed, outcome.result)], "studio")[0]

    def save_toml(self, path: str | os.PathLike, as_fitted: bool = False) -> Path:
        """Writes `saved_data` (`as_fitted` as it takes it) as a scenario file."""
        path = Path(path)
        if path.suffix.lower() != ".toml":
            raise DesignError(f"Expected a .toml file name, got {path.name!r}")
        text = scenario_toml(self.saved_data(as_fitted))
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

    @property
    def fitted(self) -> bool:
        """Whether the last fit is of the session as it is now (nothing edited since)."""
        return self.last is not None and self.last.data is not None and \
            bool(self.people) and self.last.data == self.scenario_data()

    def export(self, out_dir: str | os.PathLike,
               progress: Callable[[str], None] | None = None,
               formats: tuple[str, ...] = SURFACE_FORMATS, title: str | None = None) -> dict:
        """Writes everything as `sitrelax fit` does (surface in `formats`, control mesh,
        bodies, pictures, report.json, and the scenario as scenario.toml) of the last fit, the
        one on screen; a DesignError when there is none of the session as it is now (`fitted`:
        fit first)."""
        if not self.fitted:
            raise DesignError("Fit first: the session was edited since its last fit (or has "
                              "none), and the export writes the fit on screen")
        out, outcome = Path(out_dir), self.last  # (a refit may replace `last` meanwhile)
        # the relief the fit on screen had (an opened scenario's rounds are not run here)
        relief = schema.Relief(**(outcome.relief or {}))
        report = run_fit(dataclasses.replace(self.scenario(), relief=relief), out, db=self.db,
                         progress=progress, formats=formats, fitted=outcome.result,
                         title=title, judged=None if outcome.guarantees is None else
                         (outcome.guarantees, outcome.judge_seconds))
        self.save_toml(out / "scenario.toml", as_fitted=True)
        if outcome.guarantees is None:  # the export judged the fit it wrote: kept with it
            outcome.guarantees = report["guarantees"]
            outcome.judge_seconds = report["timing"].get("guarantees_s")
        return report

    def export_zip(self, name: str, progress: Callable[[str], None] | None = None,
                   formats: tuple[str, ...] = SURFACE_FORMATS) -> tuple[bytes, dict]:
        """`export` into a temporary folder, packed as one zip (its files under `name`/):
        the zip's bytes and the report. Nothing is left on disk."""
        name = check_name(name)
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / name
            report = self.export(folder, progress, formats, title=name)
            buffer = io.BytesIO()
            with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as pack:
                for path in sorted(folder.rglob("*")):
                    if path.is_file():
                        pack.write(path, f"{name}/{path.relative_to(folder).as_posix()}")
        return buffer.getvalue(), report

