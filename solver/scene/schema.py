"""The scenario schema: one set of pydantic models for the TOML reader (`parse_scenario`), the
HTTP API's requests and the studio, and the one place every scenario default comes from.

    Scenario
      surface: Surface      exactly one of grid {size, resolution, height}, control_mesh (a
                            file name, or inline {vertices, faces}) or template {kind, ...}
                            (a `solver.surface.templates` kind and its parameters, each
                            unset one measured on the people, `solver.scene.furnish`), and one
                            field per `FitParams` field, its default taken from `FitParams`
      evaluation: Evaluation  foam_stiffness (kPa per metre), foam_thickness (m), friction,
                            floor (bool), floor_stiffness (kPa per metre)
      person: [Person]      pose, name, body (the `BodyShape` fields, each in [0, 1]),
                            position (m), rotation_deg (about x, then y, then z), support (a
                            use, default "seat", or a list of body regions; as written:
                            `solver.scene.scenario` expands it to regions)

The models check types and bounds only. What depends on the control mesh (fixed and crease
indices, creases the subdivision can take, an inline mesh's faces) and on where the scenario
comes from (files or not) is checked by `parse_scenario` right after them. `error_message`
turns pydantic's errors into this project's shape: `surface.sigma: expected a number >= 0,
got -1`, unknown keys with "did you mean".
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
from typing import Annotated, Any, Literal, Union

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, Tag,
                      ValidationError, create_model, model_validator)
from pydantic_core import PydanticCustomError

from posedb.regions import DEFAULT_SUPPORT, SUPPORT_NAMES, SupportNameError, support_regions

from solver.body import model as body_model
from solver.surface.fit import FitParams
from solver.surface.templates import SEAT_PROFILE_KEYS, TEMPLATE_PARAMS

MAX_INLINE_VERTICES = 20_000


class ScenarioError(ValueError):
    """A scenario that cannot be used; the message names the file and the field."""

Number = Annotated[float, Field(strict=True, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.0)]
Positive = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0.0)]
Unit = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.0, le=1.0)]
Index = Annotated[int, Field(strict=True, ge=0)]
MAX_COORDINATE = 1000.0  # metres: no furniture or room is larger
Coordinate = Annotated[Number, Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]
Vector3 = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]


def _support_names(value: Any) -> Any:
    """A support as written (a use name, or a list of region, part or use names), checked."""
    if not isinstance(value, (str, list)):
        raise PydanticCustomError("support", "expected a use name or a list of body regions, "
                                  "got {got}", {"got": repr(value)})
    try:
        support_regions(value)
    except SupportNameError as exc:
        message = str(exc)
        raise PydanticCustomError("support", "{message}",
                                  {"message": message[:1].lower() + message[1:]}) from None
    return value


Support = Annotated[Union[str, list[str]], BeforeValidator(_support_names), Field(
    description="the body regions to support: a use (seat, chair, ...) or a list of regions "
                "(head, pelvis, thighs, ...), coarse parts (torso, arms, legs) or uses",
    examples=[DEFAULT_SUPPORT, ["pelvis", "thighs", "lower_back"]],
    json_schema_extra={"x-names": list(SUPPORT_NAMES)})]

# each fit parameter's type and bounds; its default is FitParams's
FIT_FIELDS: dict[str, Any] = {
    "level": Annotated[int, Field(strict=True, ge=1, le=5, description="subdivision level s")],
    "sigma": Annotated[NonNegative, Field(le=100.0, description="Laplacian smoothing weight")],
    "tau_max": Annotated[Unit, Field(description="ceiling of the point-to-plane blend")],
    "margin": Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.0, le=0.5,
                                     description="allowed body softness, metres")],
    "fixed": Annotated[list[Index], Field(description="control vertices held near their start")],
    "gamma": Annotated[NonNegative, Field(le=1e6, description="how strongly fixed vertices "
                                                                "are held")],
    "creases": Annotated[list[Annotated[list[Index], Field(min_length=2, max_length=2)]],
                         Field(description="control edges [i, j] kept sharp")],
    "max_iterations": Annotated[int, Field(strict=True, ge=1, le=10_000)],
    "tolerance": Annotated[NonNegative, Field(le=1.0, description="stop when the best energy "
                                                                  "improves less than this in 5 "
                                                                  "iterations")],
    "anchor": Annotated[NonNegative, Field(le=1e6, description="weak pull of every control "
                                                               "vertex to its start")],
    "pull_range": Annotated[Positive, Field(le=100.0, description="metres: farther body "
                                                                  "points do not pull yet")],
    "step": Annotated[Positive, Field(le=100.0, description="metres a control vertex may "
                                                            "move per iteration (a trust "
                                                            "region)")],
    "floor": Annotated[Union[Coordinate, None], Field(description="the floor's height y, metres: "
                                                  "the surface stays above it (null: no floor)")],
    "sink": Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.0, le=0.1,
                                   description="metres into the skin the surface is fitted "
                                               "to (where the foam is pressed at rest)")],
    "min_ridge_radius": Annotated[NonNegative, Field(
        le=1.0, description="metres: the tightest the surface may bend away from the bodies "
                            "(a solid up to this thick can follow it)")],
}
_missing = sorted({f.name for f in dataclasses.fields(FitParams)} ^ set(FIT_FIELDS))
if _missing:  # a new fit parameter needs its bounds here (or a removed one its entry gone)
    raise ImportError(f"solver.scene.schema.FIT_FIELDS and FitParams differ in {_missing}")


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Grid(_Model):
    """A flat start: `resolution` quads over `size` metres (x, z), at `height` (y)."""

    size: Annotated[list[Annotated[Positive, Field(le=MAX_COORDINATE)]],
                    Field(min_length=2, max_length=2)] = [1.2, 0.8]
    resolution: Annotated[list[Annotated[int, Field(strict=True, ge=1, le=200)]],
                          Field(min_length=2, max_length=2)] = [8, 6]
    height: Coordinate = 0.45


class InlineMesh(_Model):
    """A quad control mesh: vertices [[x, y, z], ...], faces [[a, b, c, d], ...] (from 0)."""

    vertices: Annotated[list[Vector3], Field(min_length=4, max_length=MAX_INLINE_VERTICES)]
    faces: Annotated[list[Annotated[list[Index], Field(min_length=4, max_length=4)]],
                     Field(min_length=1, max_length=2 * MAX_INLINE_VERTICES)]


def _mesh_kind(value: Any) -> str | None:
    if isinstance(value, str):
        return "file"
    if isinstance(value, (dict, InlineMesh)):
        return "inline"
    return None


ControlMesh = Annotated[
    Union[Annotated[str, Tag("file")], Annotated[InlineMesh, Tag("inline")]],
    Discriminator(_mesh_kind, custom_error_type="control_mesh",
                  custom_error_message="expected a file name or a table {vertices, faces}")]
_TAGS = {"file", "inline"}


# one seat of a bench with a profile of its own (`BenchParams.seat_profiles`): any of its keys,
# the others as the bench's
SeatProfile = create_model("SeatProfile", __base__=_Model,
                           **{key: (Union[Number, None], None) for key in SEAT_PROFILE_KEYS})


_TEMPLATE_TYPES = {  # a template parameter's type; its bounds are the template's own checks
    "float": Number, "int": Annotated[int, Field(strict=True)],
    "bool": Annotated[bool, Field(strict=True)],
    "tuple[int, int]": Annotated[list[Annotated[int, Field(strict=True)]],
                                 Field(min_length=2, max_length=2)],
    "tuple[float, float]": Annotated[list[Number], Field(min_length=2, max_length=2)],
    "tuple[dict, ...]": Annotated[list[SeatProfile], Field(max_length=20)],
}


def _template_model(kind: str, params: type) -> type[BaseModel]:
    """The schema of one template kind: `kind`, and each parameter of its dataclass, unset
    (None) by default: measured on the people, or the dataclass's default."""
    fields: dict[str, Any] = {"kind": (Literal[kind], ...)}  # type: ignore[valid-type]
    for f in dataclasses.fields(params):
        default = list(f.default) if isinstance(f.default, tuple) else f.default
        fields[f.name] = (Union[_TEMPLATE_TYPES[str(f.type)], None], Field(
            None, description=f"unset: from the people (else {default!r})"))
    return create_model(f"{kind.title().replace('_', '')}Template", __base__=_Model,
                        __doc__=params.__doc__, **fields)


TEMPLATE_MODELS = {kind: _template_model(kind, cls) for kind, cls in TEMPLATE_PARAMS.items()}


def _template_kind(value: Any) -> str | None:
    kind = value.get("kind") if isinstance(value, dict) else getattr(value, "kind", None)
    return kind if isinstance(kind, str) and kind in TEMPLATE_MODELS else None


Template = Annotated[
    Union[tuple(Annotated[m, Tag(k)] for k, m in TEMPLATE_MODELS.items())],  # type: ignore
    Discriminator(_template_kind, custom_error_type="template",
                  custom_error_message=f"expected a table with kind one of "
                                       f"{list(TEMPLATE_MODELS)}")]
_TAGS = _TAGS | set(TEMPLATE_MODELS)


class _SurfaceBase(_Model):
    grid: Grid | None = None
    control_mesh: ControlMesh | None = None
    template: Template | None = None  # type: ignore[valid-type]

    @model_validator(mode="after")
    def _one_start(self):
        if sum(x is not None for x in (self.grid, self.control_mesh, self.template)) != 1:
            raise PydanticCustomError("surface", "expected exactly one of grid, control_mesh "
                                                 "or template")
        return self


def _fit_field(f: dataclasses.Field) -> tuple[Any, Any]:
    """(type, default) of a fit parameter; tuples (fixed, creases) become lists."""
    to_list = lambda v: [to_list(x) for x in v] if isinstance(v, tuple) else v  # noqa: E731
    return FIT_FIELDS[f.name], to_list(f.default)


Surface = create_model("Surface", __base__=_SurfaceBase, __doc__=(
    "The control mesh to start from and the fit's parameters (`FitParams`)."),
    **{f.name: _fit_field(f) for f in dataclasses.fields(FitParams)})


class _BodyBase(_Model):
    @model_validator(mode="after")
    def _some_race(self):
        if self.african + self.asian + self.caucasian <= 0:
            raise PydanticCustomError("body", "expected race weights that are not all zero")
        return self


BodyShape = create_model(
    "BodyShape", __base__=_BodyBase, __doc__="Shape parameters, each in [0, 1].",
    **{f.name: (Unit, f.default) for f in dataclasses.fields(body_model.BodyShape)})


class Person(_Model):
    pose: Annotated[str, Field(min_length=1, examples=[
        "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"],
        description="db:NAME or bvh:FILE#frame=N (bundled:NAME too)")]
    name: str | None = None
    body: BodyShape = BodyShape()  # type: ignore[valid-type]
    position: Vector3 = [0.0, 0.0, 0.0]
    rotation_deg: Vector3 = [0.0, 0.0, 0.0]
    support: Support = DEFAULT_SUPPORT
    facing: Annotated[Literal["front", "capture"], Field(
        description="front: the pelvis turned to face +Z before rotation_deg (the same for "
                    "every recording); capture: the heading of the capture room")] = "front"
    placement: Annotated[Literal["stored", "standard"], Field(
        description="stored: a library pose that carries where its relaxation left it "
                    "(`sitrelax relax --save`) stands there, before rotation_deg and position; "
                    "standard: its lowest point on the floor and its pelvis over the origin, "
                    "as every other pose")] = "stored"
    joint_map: Annotated[str | dict[str, str] | None, Field(
        description="a joint-map file (TOML, role = \"joint\") or an inline table, for a "
                    "skeleton no profile knows")] = None


MAX_STIFFNESS = 1e6  # kPa per metre: stiffer than any floor's covering (a rigid floor's
# contact is all it can be; beyond, the settle's products overflow)


def _number(ge: float, le: float | None, description: str):
    return Field(strict=True, allow_inf_nan=False, ge=ge, le=le, description=description)


class Evaluation(_Model):
    """How the body settles on the surface (see README, "Contact in equilibrium")."""

    foam_stiffness: Annotated[float, _number(1e-3, MAX_STIFFNESS, "the seat foam's kPa of "
                                             "pressure per metre pressed in")] = 200.0
    foam_thickness: Annotated[float, _number(1e-3, 1.0, "metres of foam; past it the foam is "
                                             "bottomed out")] = 0.1
    friction: Annotated[float, _number(0.0, 2.0, "Coulomb friction between body and "
                                       "supports")] = 0.5
    floor: Annotated[bool, Field(strict=True, description="whether the floor (y = 0) supports "
                                                          "the body too")] = True
    floor_stiffness: Annotated[float, _number(1e-3, MAX_STIFFNESS, "kPa per metre of the floor "
                                              "under feet and shoes")] = 30000.0


class Relief(_Model):
    """Rounds of pressure relief after the fit (see README, "Pressure relief"): the surface
    eased away from the skin it presses harder than `target` of a flat seat's peak at the same
    load, fitted again, and kept only if it misses no bar it met."""

    rounds: Annotated[int, Field(strict=True, ge=0, le=10, description="rounds at most (0: "
                                 "none, the fit alone)")] = 0
    target: Annotated[float, _number(0.2, 1.0, "the pressure aimed at, as a share of the flat "
                                     "seat's peak at the same load")] = 0.5


class Scenario(_Model):
    """A scenario: the surface to fit, how to evaluate it, and the people it supports."""

    surface: Surface  # type: ignore[valid-type]
    evaluation: Evaluation = Evaluation()
    relief: Relief = Relief()
    person: Annotated[list[Person], Field(min_length=1)]


def default(model: type[BaseModel], name: str) -> Any:
    """The schema's default of one field (a copy: lists may be changed)."""
    value = model.model_fields[name].default
    return list(value) if isinstance(value, list) else value


def person_defaults() -> dict:
    """A person's placement and support as the schema gives them when unset."""
    return {name: default(Person, name) for name in ("position", "rotation_deg", "support",
                                                      "facing")}


# error messages -------------------------------------------------------------------------------

def validate(data: Any, where: str) -> Scenario:
    """The scenario model of `data`; a ScenarioError naming `where` and the field otherwise."""
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(error_message(exc, where)) from None


def error_message(exc: ValidationError, where: str) -> str:
    """The first of pydantic's errors as `where: field.path[k]: expected ..., got ...`; an
    unknown key comes first (a misspelt key also leaves its right spelling missing)."""
    errors = exc.errors(include_url=False)
    error = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])
    loc = [p for p in error["loc"] if p not in _TAGS]
    tagged = [p for p in error["loc"] if p not in _TAGS or p in TEMPLATE_MODELS]
    node = _schema_at(tagged[:-1] if error["type"] == "extra_forbidden" else tagged)
    message = _describe(error, node, loc)
    if "body" in loc[:-1] and loc.index("body") < len(loc) - 1:
        # errors inside a person's body name the table, then the key (BodyShape's shape)
        at = loc.index("body") + 1
        return f"{where}: {_path(loc[:at])}: {_path(loc[at:])}: {message}"
    return f"{where}: {_path(loc) or 'scenario'}: {message}"


def _path(loc: list) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


@functools.lru_cache(maxsize=1)
def _json_schema() -> dict:
    return Scenario.model_json_schema()


def _schema_at(loc: list) -> dict:
    """The JSON schema node of a location (its bounds and known keys)."""
    root = _json_schema()
    node = root

    def resolve(n: dict) -> dict:
        while "$ref" in n:
            n = root["$defs"][n["$ref"].split("/")[-1]]
        return n

    def branches(n: dict) -> list[dict]:  # the members of (nested) unions
        n = resolve(n)
        members = n.get("anyOf", n.get("oneOf"))
        return [b for m in members for b in branches(m)] if members else [n]

    for part in loc:
        if isinstance(part, str) and part in TEMPLATE_MODELS:  # a template kind's own table
            node = root["$defs"][TEMPLATE_MODELS[part].__name__]
            continue
        for branch in branches(node):
            if (isinstance(part, int) and branch.get("type") == "array") or (
                    isinstance(part, str) and part in branch.get("properties", {})):
                node = branch
                break
        if isinstance(part, int):
            node = resolve(node).get("items", {})
        else:
            node = resolve(node).get("properties", {}).get(part, {})
    tables = [b for b in branches(node) if "properties" in b]
    if tables:
        return tables[0]
    values = [b for b in branches(node) if b.get("type") != "null"]  # an optional field's
    return values[0] if len(values) == 1 else resolve(node)


def _got(value: Any) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value:g}"
    return repr(value)


def _describe(error: dict, node: dict, loc: list) -> str:
    kind, value, ctx = error["type"], error.get("input"), error.get("ctx") or {}
    sections = {"surface": "expected a [surface] table",
                "person": "expected at least one [[person]]"}
    if len(loc) == 1 and loc[0] in sections and kind in ("missing", "too_short", "model_type",
                                                         "list_type"):
        return sections[loc[0]]
    whole = node.get("type") == "integer"
    noun = "a whole number" if whole else "a number"
    if kind == "extra_forbidden":
        known = sorted(node.get("properties", {}))
        close = difflib.get_close_matches(str(loc[-1]), known, n=1)
        hint = f"did you mean {close[0]}? " if close else ""
        return f"unknown field ({hint}expected one of {known})"
    if kind in ("greater_than_equal", "less_than_equal", "greater_than", "less_than"):
        low, high = node.get("minimum"), node.get("maximum")
        if whole and low is not None and high is not None:
            return f"expected a whole number in {low}..{high}, got {_got(value)}"
        sign, bound = {"greater_than_equal": (">=", "ge"), "less_than_equal": ("<=", "le"),
                       "greater_than": (">", "gt"), "less_than": ("<", "lt")}[kind]
        return f"expected {noun} {sign} {ctx[bound]:g}, got {_got(value)}"
    if kind in ("too_short", "too_long"):
        low, high = node.get("minItems"), node.get("maxItems")
        if low == high:
            return f"expected a list of {low} {_items(node)}, got {value!r}"
        if kind == "too_short":
            return f"expected at least {low} {_items(node, low)}, got {len(value)}"
        return f"expected at most {high} {_items(node)}, got {len(value)}"
    simple = {"float_type": "expected a number", "int_type": "expected a whole number",
              "int_from_float": "expected a whole number",
              "finite_number": "expected a finite number", "list_type": "expected a list",
              "model_type": "expected a table", "model_attributes_type": "expected a table",
              "dict_type": "expected a table", "string_type": "expected a string",
              "string_too_short": "expected a non-empty string",
              "bool_type": "expected true or false"}
    if kind in simple:
        return f"{simple[kind]}, got {_got(value)}"
    if kind == "missing":
        return "missing (a required field)"
    if kind == "literal_error":
        return f"expected one of {ctx.get('expected')}, got {value!r}"
    if kind == "template":  # no kind, or none of the known ones: say which was given
        return _template_kind_message(value)
    return error["msg"]


def _template_kind_message(value: Any) -> str:
    known = list(TEMPLATE_MODELS)
    if not isinstance(value, dict):
        return f"expected a table with kind one of {known}, got {_got(value)}"
    if "kind" not in value:
        return f"expected a table with kind one of {known}, got no kind"
    given = value["kind"]
    close = difflib.get_close_matches(given.lower(), known, n=1, cutoff=0.6) \
        if isinstance(given, str) else []
    hint = f" (did you mean {close[0]}?)" if close else ""
    return f"expected a table with kind one of {known}, got {_got(given)}{hint}"


def _items(node: dict, count: int = 2) -> str:
    kind = node.get("items", {}).get("type")
    noun = {"number": "number", "integer": "whole number", "array": "list"}.get(kind, "item")
    return noun if count == 1 else f"{noun}s"
