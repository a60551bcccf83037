"""Scenario files (TOML): the surface to fit, its parameters, and the people it supports.

    [surface]
    grid = { size = [1.2, 0.8], resolution = [8, 6], height = 0.45 }  # or control_mesh = "a.obj"
    level = 3          # subdivision level s
    sigma = 0.1        # Laplacian smoothing weight
    tau_max = 0.5      # tangent-distance blend ceiling
    margin = 0.03      # allowed body softness, metres
    fixed = [0, 7]     # control vertices held near their start
    gamma = 10.0       # how strongly
    creases = [[0, 1]] # control edges kept sharp

    [evaluation]
    foam_stiffness = 200.0  # kPa of pressure per metre the foam is pressed in

    [[person]]
    name = "reader"                   # optional
    pose = "db:relaxed_sit_01"        # or "bvh:path.bvh#frame=40"
    body = { gender = 0.0, weight = 0.5, height = 0.5 }
    position = [0.0, 0.0, 0.0]        # metres
    rotation_deg = [0.0, 90.0, 0.0]   # about the world x, then y, then z axes
    support = ["torso", "legs"]       # head, torso, arms, hands, legs (= thighs + calves), feet

A person is posed on its body with its lowest point on the floor (y = 0) and its pelvis over
the origin, then turned by `rotation_deg` and moved by `position`. Relative paths are relative
to the scenario file.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from solver.body.model import SUPPORT_PARTS, BodyShape, BodyShapeError
from solver.surface.fit import FitParams
from solver.mesh import faces_problem
from solver.surface.subdivision import grid_mesh

SURFACE_KEYS = {"grid", "control_mesh", "level", "sigma", "tau_max", "margin", "fixed", "gamma",
                "creases", "max_iterations", "tolerance"}
PERSON_KEYS = {"name", "pose", "body", "position", "rotation_deg", "support"}
EVALUATION_KEYS = {"foam_stiffness"}


class ScenarioError(ValueError):
    """A scenario that cannot be used; the message names the file and the field."""


@dataclass(frozen=True, eq=False)
class SurfaceSpec:
    """The control mesh (vertices (n, 3), quads (F, 4)) and the fit's parameters."""

    vertices: np.ndarray
    faces: np.ndarray
    params: FitParams = field(default_factory=FitParams)
    source: str = "grid"


@dataclass(frozen=True)
class PersonSpec:
    pose: str
    body: BodyShape = field(default_factory=BodyShape)
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    support: tuple[str, ...] = ("torso", "legs")
    name: str = ""


@dataclass(frozen=True)
class Scenario:
    surface: SurfaceSpec
    persons: tuple[PersonSpec, ...]
    foam_stiffness: float = 200.0  # kPa per metre
    path: str | None = None
    raw: dict = field(default_factory=dict, repr=False)


def _fail(where: str, field_name: str, message: str) -> ScenarioError:
    return ScenarioError(f"{where}: {field_name}: {message}")


def _number(value: Any, where: str, name: str, low: float | None = None,
            high: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(where, name, f"expected a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise _fail(where, name, f"expected a finite number, got {value!r}")
    if low is not None and value < low:
        raise _fail(where, name, f"expected a number >= {low:g}, got {value:g}")
    if high is not None and value > high:
        raise _fail(where, name, f"expected a number <= {high:g}, got {value:g}")
    return value


def _vector(value: Any, where: str, name: str, size: int) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != size:
        raise _fail(where, name, f"expected a list of {size} numbers, got {value!r}")
    return tuple(_number(v, where, f"{name}[{k}]") for k, v in enumerate(value))


def _int(value: Any, where: str, name: str, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _fail(where, name, f"expected a whole number, got {value!r}")
    if value < low or (high is not None and value > high):
        raise _fail(where, name, f"expected a whole number in {low}..{high if high is not None else ''}"
                    f", got {value}")
    return value


def read_control_mesh(path: Path, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and quad faces of an OBJ control mesh (every face must be a quad)."""
    if not path.exists():
        raise _fail(where, "surface.control_mesh", f"no such file {path}")
    verts, faces = [], []
    for no, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            try:
                verts.append([float(x) for x in parts[1:4]])
            except ValueError:
                raise _fail(where, "surface.control_mesh",
                            f"{path}:{no}: expected 'v x y z', got {line.strip()!r}") from None
        elif parts[0] == "f":
            idx = [int(p.split("/")[0]) for p in parts[1:]]
            if len(idx) != 4:
                raise _fail(where, "surface.control_mesh",
                            f"{path}:{no}: expected a quad control mesh, got a face of "
                            f"{len(idx)} vertices")
            faces.append([i - 1 if i > 0 else len(verts) + i for i in idx])
    if not faces:
        raise _fail(where, "surface.control_mesh", f"{path}: expected quad faces, found none")
    v, f = np.array(verts, dtype=float), np.array(faces, dtype=np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise _fail(where, "surface.control_mesh", f"{path}: face indices out of range")
    return v, f


MAX_INLINE_VERTICES = 20_000


def inline_control_mesh(table: Any, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and quads of a control mesh given as {vertices = [[x, y, z], ...],
    faces = [[a, b, c, d], ...]} (indices from 0)."""
    at = "surface.control_mesh"
    if set(table) != {"vertices", "faces"}:
        raise _fail(where, at, f"expected exactly the keys vertices and faces, got "
                    f"{sorted(table)}")
    verts, faces = table["vertices"], table["faces"]
    if not isinstance(verts, list) or not 4 <= len(verts) <= MAX_INLINE_VERTICES:
        raise _fail(where, f"{at}.vertices", f"expected a list of 4 to {MAX_INLINE_VERTICES} "
                    "[x, y, z] points")
    if not isinstance(faces, list) or not faces or len(faces) > 2 * MAX_INLINE_VERTICES:
        raise _fail(where, f"{at}.faces", "expected a non-empty list of [a, b, c, d] quads")
    v = np.array([_vector(p, where, f"{at}.vertices[{k}]", 3) for k, p in enumerate(verts)])
    rows = []
    for k, f in enumerate(faces):
        if not isinstance(f, list) or len(f) != 4:
            raise _fail(where, f"{at}.faces[{k}]", f"expected a quad [a, b, c, d], got {f!r}")
        rows.append([_int(i, where, f"{at}.faces[{k}]", 0, len(v) - 1) for i in f])
    f = np.array(rows, dtype=np.int64)
    problem = faces_problem(v, f)
    if problem:
        raise _fail(where, f"{at}.faces", problem)
    return v, f


def parse_scenario(data: dict, where: str = "<scenario>", base: Path | None = None, *,
                   files: bool = True) -> Scenario:
    """A validated scenario from TOML data; `base` resolves relative paths. With `files`
    False (a server's requests) nothing names a file: the control mesh is inline and poses come
    from the library or the bundled recordings."""
    base = base or Path(".")
    unknown = sorted(set(data) - {"surface", "person", "evaluation"})
    if unknown:
        raise _fail(where, unknown[0], "unknown section (expected surface, person, evaluation)")
    surf = data.get("surface")
    if not isinstance(surf, dict):
        raise _fail(where, "surface", "expected a [surface] table")
    unknown = sorted(set(surf) - SURFACE_KEYS)
    if unknown:
        raise _fail(where, f"surface.{unknown[0]}", f"unknown field (expected one of "
                    f"{sorted(SURFACE_KEYS)})")
    if ("grid" in surf) == ("control_mesh" in surf):
        raise _fail(where, "surface", "expected exactly one of grid or control_mesh")
    if "grid" in surf:
        g = surf["grid"]
        if not isinstance(g, dict):
            raise _fail(where, "surface.grid", "expected a table {size, resolution, height}")
        size = _vector(g.get("size", [1.2, 0.8]), where, "surface.grid.size", 2)
        if min(size) <= 0:
            raise _fail(where, "surface.grid.size", f"expected positive sizes, got {list(size)}")
        res = g.get("resolution", [8, 6])
        if not isinstance(res, list) or len(res) != 2:
            raise _fail(where, "surface.grid.resolution", f"expected [nx, nz], got {res!r}")
        res = [_int(r, where, f"surface.grid.resolution[{k}]", 1, 200) for k, r in enumerate(res)]
        height = _number(g.get("height", 0.45), where, "surface.grid.height")
        verts, faces = grid_mesh(size, res, height)
        source = f"grid {res[0]}x{res[1]}, {size[0]:g} x {size[1]:g} m at {height:g} m"
    elif isinstance(surf["control_mesh"], dict):
        verts, faces = inline_control_mesh(surf["control_mesh"], where)
        source = f"inline control mesh, {len(verts)} vertices, {len(faces)} quads"
    else:
        mesh_path = surf["control_mesh"]
        if not isinstance(mesh_path, str):
            raise _fail(where, "surface.control_mesh", "expected a file name or a table "
                        f"{{vertices, faces}}, got {mesh_path!r}")
        if not files:
            raise _fail(where, "surface.control_mesh", "expected the control mesh inline "
                        "({vertices, faces}); files are not read here")
        path = (base / mesh_path).resolve()
        verts, faces = read_control_mesh(path, where)
        source = str(path)
    n = len(verts)
    fixed = surf.get("fixed", [])
    if not isinstance(fixed, list):
        raise _fail(where, "surface.fixed", f"expected a list of vertex indices, got {fixed!r}")
    fixed = tuple(_int(i, where, f"surface.fixed[{k}]", 0, n - 1) for k, i in enumerate(fixed))
    creases = surf.get("creases", [])
    if not isinstance(creases, list) or not all(isinstance(c, list) and len(c) == 2
                                                for c in creases):
        raise _fail(where, "surface.creases", f"expected a list of [i, j] pairs, got {creases!r}")
    creases = tuple((_int(a, where, "surface.creases", 0, n - 1),
                     _int(b, where, "surface.creases", 0, n - 1)) for a, b in creases)
    spec = SurfaceSpec(verts, faces, FitParams(
        level=_int(surf.get("level", 3), where, "surface.level", 1, 5),
        sigma=_number(surf.get("sigma", 0.1), where, "surface.sigma", 0.0),
        tau_max=_number(surf.get("tau_max", 0.5), where, "surface.tau_max", 0.0, 1.0),
        margin=_number(surf.get("margin", 0.03), where, "surface.margin", 0.0, 0.5),
        fixed=fixed,
        gamma=_number(surf.get("gamma", 10.0), where, "surface.gamma", 0.0),
        creases=creases,
        max_iterations=_int(surf.get("max_iterations", 50), where, "surface.max_iterations", 1,
                            10_000),
        tolerance=_number(surf.get("tolerance", 0.01), where, "surface.tolerance", 0.0),
    ), source)
    if creases:
        from solver.surface.subdivision import MeshError, subdivide_once

        try:
            subdivide_once(n, faces, np.array(creases))
        except MeshError as exc:
            raise _fail(where, "surface.creases", str(exc)) from None
    people = data.get("person", [])
    if not isinstance(people, list) or not people:
        raise _fail(where, "person", "expected at least one [[person]]")
    persons = []
    for k, p in enumerate(people):
        at = f"person[{k}]"
        if not isinstance(p, dict):
            raise _fail(where, at, "expected a table")
        unknown = sorted(set(p) - PERSON_KEYS)
        if unknown:
            raise _fail(where, f"{at}.{unknown[0]}", f"unknown field (expected one of "
                        f"{sorted(PERSON_KEYS)})")
        pose = p.get("pose")
        if not isinstance(pose, str) or not pose:
            raise _fail(where, f"{at}.pose", f"expected db:NAME or bvh:FILE#frame=N, got {pose!r}")
        if not files and not (pose.startswith("db:") or pose.startswith("bvh:bundled:")):
            raise _fail(where, f"{at}.pose", "expected db:NAME or bvh:bundled:NAME#frame=N "
                        f"(files are not read here), got {pose!r}")
        if pose.startswith("bvh:") and "#" in pose:
            file_part, frame = pose[4:].split("#", 1)
            if not file_part.startswith("bundled:"):
                file_part = str((base / file_part).resolve())
            pose = f"bvh:{file_part}#{frame}"
        body = p.get("body", {})
        if not isinstance(body, dict):
            raise _fail(where, f"{at}.body", f"expected a table of shape parameters, got {body!r}")
        try:
            shape = BodyShape.from_mapping(body)
        except BodyShapeError as exc:
            raise _fail(where, f"{at}.body", str(exc)) from None
        support = p.get("support", ["torso", "legs"])
        if not isinstance(support, list) or not support or any(s not in SUPPORT_PARTS
                                                                for s in support):
            raise _fail(where, f"{at}.support", f"expected body parts from {SUPPORT_PARTS}, "
                        f"got {support!r}")
        persons.append(PersonSpec(
            pose=pose, body=shape,
            position=_vector(p.get("position", [0, 0, 0]), where, f"{at}.position", 3),
            rotation_deg=_vector(p.get("rotation_deg", [0, 0, 0]), where, f"{at}.rotation_deg",
                                 3),
            support=tuple(support), name=str(p.get("name", f"person {k + 1}")),
        ))
    evaluation = data.get("evaluation", {})
    if not isinstance(evaluation, dict):
        raise _fail(where, "evaluation", "expected a table")
    unknown = sorted(set(evaluation) - EVALUATION_KEYS)
    if unknown:
        raise _fail(where, f"evaluation.{unknown[0]}", "unknown field (expected foam_stiffness)")
    stiffness = _number(evaluation.get("foam_stiffness", 200.0), where,
                        "evaluation.foam_stiffness", 1e-3)
    return Scenario(spec, tuple(persons), stiffness, where, data)


def load_scenario(path: str | Path) -> Scenario:
    """Reads and validates a scenario file."""
    path = Path(path)
    if not path.exists():
        raise ScenarioError(f"No scenario file {path}")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise ScenarioError(f"{path}: not a text file") from None
    return parse_scenario(data, str(path), path.parent)


def scenario_toml(data: dict) -> str:
    """Scenario data (as `parse_scenario` takes it) written as TOML: top-level tables as
    [sections], lists of tables as [[arrays]], anything deeper inline."""
    head, tables, arrays = [], [], []
    for key, value in data.items():
        if isinstance(value, dict):
            tables.append(f"\n[{key}]\n" + "".join(f"{k} = {_toml_value(v)}\n"
                                                    for k, v in value.items()))
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            for item in value:
                arrays.append(f"\n[[{key}]]\n" + "".join(f"{k} = {_toml_value(v)}\n"
                                                         for k, v in item.items()))
        else:
            head.append(f"{key} = {_toml_value(value)}\n")
    return "".join(head) + "".join(tables) + "".join(arrays)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            raise ScenarioError(f"Expected finite numbers in a scenario, got {value!r}")
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string takes JSON's escapes
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise ScenarioError(f"Expected numbers, strings, lists or tables in a scenario, got "
                        f"{type(value).__name__}")
