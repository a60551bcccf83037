"""Scenario files (TOML): the surface to fit, its parameters, and the people it supports.

    [surface]
    grid = { size = [1.2, 0.8], resolution = [8, 6], height = 0.45 }  # or control_mesh = "a.obj"
    # or template = { kind = "chair", seat_height = 0.44, arms = true }
    level = 3          # subdivision level s
    sigma = 0.003      # Laplacian smoothing weight
    tau_max = 0.5      # tangent-distance blend ceiling
    margin = 0.03      # allowed body softness, metres
    fixed = [0, 7]     # control vertices held near their start
    gamma = 10.0       # how strongly
    creases = [[0, 1]] # control edges kept sharp
    max_iterations = 50
    tolerance = 0.01   # stop when the best energy improves less than this in 5 iterations
    anchor = 0.001     # weak pull of every control vertex to its start
    pull_range = 0.25  # metres: farther body points do not pull yet
    step = 0.05        # metres a control vertex may move per iteration
    floor = 0.0        # metres: the surface stays above y = floor (JSON null: no floor)
    min_ridge_radius = 0.015  # metres: the tightest it may bend away from the bodies
    sink = 0.008       # metres into the skin the fit aims (the foam pressed at rest)

    [evaluation]
    foam_stiffness = 200.0  # kPa of pressure per metre the foam is pressed in
    foam_thickness = 0.1    # metres of foam (past it the foam is bottomed out)
    friction = 0.5          # Coulomb friction between the body and its supports
    floor = true            # the floor (y = 0) supports the body too (the feet)
    floor_stiffness = 30000.0  # kPa per metre under feet and shoes

    [relief]
    rounds = 0         # rounds of pressure relief after the fit (0: none)
    target = 0.5       # the pressure aimed at, as a share of the flat seat's peak

    [[person]]
    name = "reader"                   # optional
    pose = "db:relaxed_sit_01"        # or "bvh:path.bvh#frame=40"
    body = { gender = 0.0, weight = 0.5, height = 0.5 }
    position = [0.0, 0.0, 0.0]        # metres
    rotation_deg = [0.0, 90.0, 0.0]   # about the world x, then y, then z axes
    support = "seat"                  # a use, or a list of body regions (see below)

The surface starts from exactly one of: `grid`, a flat quad grid; `control_mesh`, a quad OBJ
file or an inline {vertices, faces}; `template`, a piece of furniture
(`solver.surface.templates`: kind = "chair", "bench", "stool", "floor_cushion", "lounger" or
"bed", and its parameters). A template's unset parameters (dimensions, position on the floor,
heading) are measured on the placed people (`solver.scene.furnish`: a chair's seat just under
the buttocks and thighs, a bench across all its sitters, a bed under the whole lying body, ...);
its creases join `creases`, and `fixed` and `creases` may name its vertices (the grid's, u
across the width, v along the profile: vertex u * rows + v). Its control mesh is built where
the people are placed (`solver.scene.placement.place_scene`).

A person is posed on its body with its lowest point on the floor (y = 0) and its pelvis over
the origin, then turned by `rotation_deg` and moved by `position`; a library pose stored by
`sitrelax relax --save` stands where its relaxation left it instead, unless the person says
``placement = "standard"`` (`solver.scene.placement.place_person`). Relative paths are relative
to the scenario file. The fields, their bounds and their defaults (the values above are the
defaults, but for fixed, creases, name, body and rotation_deg) are `solver.scene.schema`'s;
the fit parameters' defaults are `FitParams`'s.

`support` names the body regions the surface must carry (`posedb.regions`): a use (seat =
pelvis + thighs, stool, chair, lounger, bed, floor) or a list of regions (head, upper_back,
lower_back, pelvis, thighs, calves, feet, upper_arms, forearms, hands), coarse parts (torso,
arms, legs: the unions of their regions) and uses. `PersonSpec.support` holds the regions it
expands to.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from capture.jointmap import JointMapError, read_joint_map
from posedb.regions import support_regions

from solver.body.model import BodyShape, BodyShapeError
from solver.io.obj import MeshFileError, read_quad_obj
from solver.mesh import MeshOrientationError, boundary_edges, faces_problem
from solver.scene import schema
from solver.scene.schema import MAX_INLINE_VERTICES, ScenarioError  # noqa: F401 (re-exported)
from solver.surface.fit import FitParams
from solver.surface.subdivision import grid_mesh
from solver.surface.templates import TEMPLATE_PARAMS, TemplateError, make_template

_PERSON = schema.person_defaults()
_FRAME_PART = re.compile(r"^frame=\d+(&unit=[^&#]+)?$")  # after a BVH path's "#"


@dataclass(frozen=True, eq=False)
class TemplateRequest:
    """A template surface as the scenario asks for it: its kind, the parameters it sets (name
    -> value; the rest are measured on the people) and, once built around them, the template's
    full parameters (`solver.surface.templates.TEMPLATE_PARAMS[kind]`)."""

    kind: str
    given: dict
    built: Any = None


@dataclass(frozen=True, eq=False)
class SurfaceSpec:
    """The control mesh (vertices (n, 3), quads (F, 4)) and the fit's parameters. A template
    surface has its quads (and its creases among the parameters' creases) as soon as it is
    read, but its vertices (None until then) only once it is built around the placed people
    (`solver.scene.placement.place_scene`)."""

    vertices: np.ndarray | None
    faces: np.ndarray
    params: FitParams = field(default_factory=FitParams)
    source: str = "grid"
    template: TemplateRequest | None = None


@dataclass(frozen=True)
class PersonSpec:
    """A person of a scenario: the pose reference, the body shape, the placement (metres,
    degrees about x, then y, then z) and the body regions to support (BODY_REGIONS names, in
    that order)."""

    pose: str
    body: BodyShape = field(default_factory=BodyShape)
    position: tuple[float, float, float] = tuple(_PERSON["position"])
    rotation_deg: tuple[float, float, float] = tuple(_PERSON["rotation_deg"])
    support: tuple[str, ...] = support_regions(_PERSON["support"])  # body regions
    name: str = ""
    facing: str = _PERSON["facing"]
    placement: str = schema.default(schema.Person, "placement")  # "stored" or "standard"
    joint_map: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        # a use or coarse part given here too becomes its regions (SupportNameError otherwise)
        object.__setattr__(self, "support", support_regions(self.support))


@dataclass(frozen=True)
class Scenario:
    """A validated scenario: the surface to fit (`SurfaceSpec`: control mesh and parameters),
    the people (`PersonSpec`), how they settle on it (`schema.Evaluation`: foam, friction,
    floor), the file it came from and the data as read."""

    surface: SurfaceSpec
    persons: tuple[PersonSpec, ...]
    evaluation: schema.Evaluation = field(default_factory=schema.Evaluation)
    path: str | None = None
    raw: dict = field(default_factory=dict, repr=False)
    relief: schema.Relief = field(default_factory=schema.Relief)

    @property
    def foam_stiffness(self) -> float:
        """The seat foam's kPa per metre pressed in."""
        return self.evaluation.foam_stiffness


def _fail(where: str, field_name: str, message: str) -> ScenarioError:
    return ScenarioError(f"{where}: {field_name}: {message}")


def read_control_mesh(path: Path, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and quad faces of a scenario's OBJ control mesh (every face must be a quad);
    errors name the scenario's field."""
    try:
        verts, faces = read_quad_obj(path)
    except MeshFileError as exc:
        raise _fail(where, "surface.control_mesh", str(exc)) from None
    except OSError as exc:  # a folder, a file it may not read
        raise _fail(where, "surface.control_mesh", f"cannot read {path}: "
                    f"{exc.strerror or exc}") from None
    far = np.flatnonzero(~(np.abs(verts) <= schema.MAX_COORDINATE).all(axis=1))
    if len(far):  # (NaN fails the comparison too)
        raise _fail(where, "surface.control_mesh",
                    f"{path.name}: expected vertex coordinates within "
                    f"{schema.MAX_COORDINATE:g} m, got {verts[far[0]].tolist()} (vertex "
                    f"{far[0] + 1})" + (f" and {len(far) - 1} more" if len(far) > 1 else ""))
    problem = surface_problem(faces)
    if problem:
        raise _fail(where, "surface.control_mesh", f"{path.name}: {problem}")
    return verts, faces


def surface_problem(faces: np.ndarray) -> str | None:
    """What keeps quads (F, 4) from being a control mesh the fit can take (a surface: no
    edge of more than two faces, every shared edge run one way by one face and the other way
    by the other), or None. Checked when the scenario is read, so that the error names the
    field, not only once the people are posed."""
    try:
        boundary_edges(faces)
    except MeshOrientationError as exc:
        message = str(exc)
        return message[:1].lower() + message[1:] + (
            " (make every face list its corners the same way round, seen from the bodies)"
            if "oriented" in message else "")
    return None


def inline_control_mesh(mesh: schema.InlineMesh | dict,
                        where: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and quads of a control mesh given as {vertices = [[x, y, z], ...],
    faces = [[a, b, c, d], ...]} (indices from 0)."""
    if isinstance(mesh, dict):
        mesh = schema.validate({"surface": {"control_mesh": mesh}, "person": [{"pose": "-"}]},
                               where).surface.control_mesh
    v = np.array(mesh.vertices, dtype=float)
    f = np.array(mesh.faces, dtype=np.int64)
    at = "surface.control_mesh.faces"
    bad = np.argwhere(f >= len(v))
    if len(bad):
        k, i = bad[0]
        raise _fail(where, f"{at}[{k}]", f"expected a whole number in 0..{len(v) - 1}, "
                    f"got {f[k, i]}")
    problem = faces_problem(v, f) or surface_problem(f)
    if problem:
        raise _fail(where, at, problem)
    return v, f


def parse_scenario(data: dict, where: str = "<scenario>", base: Path | None = None, *,
                   files: bool = True) -> Scenario:
    """A validated scenario from TOML data (or the HTTP API's JSON).

    Parameters
    ----------
    data : the scenario as `tomllib` reads it (tables as dicts, arrays as lists).
    where : the name errors start with (the file, or "request").
    base : folder that relative paths (control meshes, BVH poses) are relative to.
    files : False for a server's requests: nothing may name a file, so the control mesh must
        be inline and poses come from the library or the bundled recordings.

    Returns
    -------
    Scenario, with the control mesh (metres), the fit's parameters and the people. Raises
    ScenarioError naming the field (`where: surface.sigma: expected ..., got ...`).
    """
    model = schema.validate(data, where)
    return scenario_from_model(model, where, base, files=files,
                               raw=data if isinstance(data, dict) else {})


def scenario_from_model(model: schema.Scenario, where: str = "<scenario>",
                        base: Path | None = None, *, files: bool = True,
                        raw: dict | None = None) -> Scenario:
    """The solver's `Scenario` of a schema model, with the checks that need the control mesh
    (fixed and crease indices) or know where the scenario came from (`files`, `base`)."""
    base = base or Path(".")
    surf = model.surface
    template = None
    if surf.template is not None:
        template, built = template_request(surf.template, len(model.person), where)
        faces, template_creases = built.quads, built.creases
        verts, source = None, f"{template.kind} template"
        n = int(faces.max()) + 1
    else:
        verts, faces, source = _control_mesh(surf, where, base, files)
        n = len(verts)
    for name in ("fixed", "creases"):
        for k, item in enumerate(getattr(surf, name)):
            for i in item if name == "creases" else [item]:
                if i >= n:
                    raise _fail(where, f"surface.{name}[{k}]",
                                f"expected a whole number in 0..{n - 1}, got {i}")
    values = {name: getattr(surf, name) for name in schema.FIT_FIELDS}
    values["fixed"] = tuple(values["fixed"])
    values["creases"] = tuple(tuple(c) for c in values["creases"])
    if template is not None:
        values["creases"] = tuple(map(tuple, template_creases.tolist())) + values["creases"]
    params = FitParams(**values)
    if params.creases:
        from solver.surface.subdivision import MeshError, subdivide_once

        try:
            subdivide_once(n, faces, np.array(params.creases))
        except MeshError as exc:
            raise _fail(where, "surface.creases", str(exc)) from None
    persons = tuple(_person(p, k, where, base, files) for k, p in enumerate(model.person))
    return Scenario(SurfaceSpec(verts, faces, params, source, template), persons,
                    model.evaluation, where,
                    raw if raw is not None else model.model_dump(exclude_none=True),
                    model.relief)


def template_error(exc: TemplateError, where: str, given: dict | None = None
                   ) -> ScenarioError:
    """A template's error as the scenario's: `where: surface.template.<parameter>: ...`.
    `given`: the parameters the scenario sets, once the others have been measured on the
    people: an error about one it does not set says so, and whether the people's pose made it
    (the error's `measured`, as `furnish` sets it) or it is the template's default."""
    message = str(exc)
    head, _, rest = message.partition(": ")
    kind, dot, name = head.partition(".")
    if dot and kind in TEMPLATE_PARAMS and " " not in head:
        parameter = _template_parameter(exc)
        if given is not None and parameter not in given:
            rest += (" (not set in the scenario: measured on the people as placed; set it "
                     "there, or move the people)" if parameter in getattr(exc, "measured", ())
                     else " (not set in the scenario: the template's default; set it there)")
        return _fail(where, f"surface.template.{name}", rest)
    return _fail(where, "surface.template", message)


def template_request(model, persons: int, where: str) -> tuple[TemplateRequest, Any]:
    """The request of a scenario's template (its schema `model`) and its control mesh built at
    the given parameters (a `TemplateMesh`, not yet placed around the people): its topology
    does not depend on them (a bench has a seat per person unless `seats` says otherwise), so
    it is built here to check the parameters (ScenarioError naming the one at fault)."""
    given = model.model_dump(exclude_none=True)
    kind = given.pop("kind")
    if kind == "bench":
        given.setdefault("seats", persons)
    try:
        mesh = make_template(kind, **given)
    except TemplateError as exc:
        # a parameter left unset is measured on the people once they are placed: its default
        # standing in for it here may clash with the ones given (a lounger's seat_height 0.9
        # with the default knee_height 0.45), which is no fault of the scenario's; the values
        # are checked together once measured (`solver.scene.placement.furnished`)
        name = _template_parameter(exc)
        mesh = _template_topology(kind, given) if name and name not in given else None
        if mesh is None:
            raise template_error(exc, where) from None
    return TemplateRequest(kind, given), mesh


def _template_parameter(exc: TemplateError) -> str | None:
    """The top-level parameter a template's error names (`kind.name...: ...`), or None."""
    head = str(exc).partition(": ")[0]
    kind, dot, name = head.partition(".")
    if not dot or kind not in TEMPLATE_PARAMS or " " in head:
        return None
    return re.split(r"[.\[]", name, maxsplit=1)[0]


def _template_topology(kind: str, given: dict):
    """A template of the given kind with the faces and creases the given parameters make
    (its counts of quads, its back, arms, seams and seats, whether its edges are rounded),
    every measure at its default; None if even that is no template."""
    cls = TEMPLATE_PARAMS[kind]
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    shape = {}
    for name, value in given.items():
        if name.endswith("_drop"):  # rounded or not makes other faces: a small rounding
            shape[name] = 0.001 if value else 0.0
        elif name == "seat_profiles":  # as many seats, each at the bench's measures
            shape[name] = [{} for _ in value]
        elif isinstance(defaults[name], (bool, int)) or name.endswith("_quads") or \
                name == "quads":  # (counts of quads, flags)
            shape[name] = value
    try:
        return make_template(kind, **shape)
    except TemplateError:
        return None


def _control_mesh(surf, where: str, base: Path,
                  files: bool) -> tuple[np.ndarray, np.ndarray, str]:
    if surf.grid is not None:
        size, res, height = surf.grid.size, surf.grid.resolution, surf.grid.height
        verts, faces = grid_mesh(size, res, height)
        return verts, faces, (f"grid {res[0]}x{res[1]}, {size[0]:g} x {size[1]:g} m at "
                              f"{height:g} m")
    if isinstance(surf.control_mesh, schema.InlineMesh):
        verts, faces = inline_control_mesh(surf.control_mesh, where)
        return verts, faces, f"inline control mesh, {len(verts)} vertices, {len(faces)} quads"
    if not files:
        raise _fail(where, "surface.control_mesh", "expected the control mesh inline "
                    "({vertices, faces}); files are not read here")
    path = (base / surf.control_mesh).resolve()
    verts, faces = read_control_mesh(path, where)
    return verts, faces, str(path)


def reads_no_file(pose: str) -> bool:
    """Whether a pose reference names no file (a library pose, `db:`, or a bundled recording,
    `bvh:bundled:`): the only ones a scenario read without files (an upload, a request) takes."""
    return pose.startswith(("db:", "bvh:bundled:"))


def _person(p: schema.Person, k: int, where: str, base: Path, files: bool) -> PersonSpec:
    at = f"person[{k}]"
    pose = p.pose
    if not files and not reads_no_file(pose):
        raise _fail(where, f"{at}.pose", "expected db:NAME or bvh:bundled:NAME#frame=N "
                    f"(files are not read here), got {pose!r}")
    if not pose.startswith("db:"):  # a BVH frame, `bvh:` written or left out
        text = pose[4:] if pose.startswith("bvh:") else pose
        file_part, _, frame = text.rpartition("#")
        if not file_part or not _FRAME_PART.match(frame):
            raise _fail(where, f"{at}.pose", "expected db:NAME or bvh:FILE#frame=N (N a "
                        f"whole number from 0; &unit=U after it if need be), got {p.pose!r}")
        if not file_part.startswith("bundled:"):  # relative to the scenario, not the cwd
            file_part = str((base / file_part).resolve())
        pose = f"bvh:{file_part}#{frame}"
    try:
        shape = BodyShape(**p.body.model_dump())
    except BodyShapeError as exc:  # the schema checks the same; kept for the message
        raise _fail(where, f"{at}.body", str(exc)) from None
    return PersonSpec(pose=pose, body=shape, position=tuple(p.position),
                      rotation_deg=tuple(p.rotation_deg), support=p.support,
                      name=p.name if p.name is not None else f"person {k + 1}",
                      facing=p.facing, placement=p.placement,
                      joint_map=_joint_map(p.joint_map, f"{at}.joint_map", where, base, files))


def _joint_map(value, at: str, where: str, base: Path, files: bool) -> tuple:
    """A person's joint map as sorted (role, joint) pairs: inline, or read from a file."""
    if value is None:
        return ()
    if isinstance(value, str):
        if not files:
            raise _fail(where, at, "expected the joint map inline (a table of role = "
                        "\"joint\"); files are not read here")
        try:
            value = read_joint_map(base / value)
        except JointMapError as exc:
            raise _fail(where, at, str(exc)) from None
    return tuple(sorted(value.items()))


def load_scenario(path: str | Path) -> Scenario:
    """Reads and validates a scenario file.

    Parameters
    ----------
    path : the TOML file; relative paths inside it are relative to its folder.

    Returns
    -------
    Scenario (see `parse_scenario`). Raises ScenarioError naming the file and the field.
    """
    path = Path(path)
    if not path.exists():
        raise ScenarioError(f"No scenario file {path}")
    if path.is_dir():
        raise ScenarioError(f"{path}: expected a scenario file (TOML), got a folder")
    try:
        content = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read it: {exc.strerror or exc}") from None
    return parse_scenario(scenario_content(content, str(path)), str(path), path.parent)


def scenario_content(content: bytes | str, where: str) -> dict:
    """The data of a scenario file's `content` (TOML, which is UTF-8): ScenarioError naming
    `where` when it is not UTF-8 or not TOML."""
    try:
        text = content.decode("utf-8") if isinstance(content, bytes) else content
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{where}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{where}: not a text file (expected UTF-8, got byte "
                            f"0x{exc.object[exc.start]:02x} at offset {exc.start})") from None


def scenario_toml(data: dict) -> str:
    """Scenario data (as `parse_scenario` takes it) written as TOML (tomli-w): what is
    written reads back equal."""
    import tomli_w

    try:
        return tomli_w.dumps(data)
    except TypeError as exc:
        raise ScenarioError(f"Expected numbers, strings, lists or tables in a scenario: "
                            f"{exc}") from None
