"""Furniture templates: parametric quad control meshes a designer starts a fit from.

Each template is one regular quad grid (so its limit surface exports as exact NURBS patches,
`solver.surface.nurbs`), bent into the furniture's shape: a side profile in the (z, y) plane
swept across the width (x), with optional bands offset along the profile's normal (the arms of
a chair, which become wings along its back). Faces point towards the bodies: a seat's up, a
back's forward. Creases run along whole grid lines, where an upholsterer's seams would: where a
seat meets its back and where a seat meets its arms (a grid cut by full crease lines still
exports patch by patch).

Frame: metres, Y up, the floor at y = 0. In its own frame a template stands with its origin on
the floor under the middle of its reference line (a seat's rear line, a lounger's seat hollow,
the middle of a bed or a stool), its width along x and its front (where the sitter's knees or
a sleeper's feet are) towards +z. `position` (x, z) moves that origin on the floor and
`heading_deg` turns the template about +y (0: its front towards +z, 90: towards +x).

    chair          seat and back, optional arms (one person)
    bench          a seat for `seats` people side by side, optional back and arms
    stool          a small seat without back (perching)
    floor_cushion  a low seat on the floor, optional back (a floor chair)
    lounger        a chaise: foot rest, knee crest, seat hollow, reclined back
    bed            a flat top under lying bodies, edges rounded down

`make_template(kind, **parameters)` builds one; each kind's parameters are a frozen dataclass
(`TEMPLATE_PARAMS[kind]`) whose defaults are a sensible piece of furniture.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np


class TemplateError(ValueError):
    """Template parameters that make no furniture (the message names the parameter)."""


def _check(kind: str, name: str, value, low: float | None = None, high: float | None = None,
           *, whole: bool = False, low_open: bool = False) -> None:
    """A TemplateError unless `value` is a finite number (whole with `whole`) within bounds."""
    noun = "a whole number" if whole else "a number"
    ok_type = isinstance(value, int) if whole else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type or not math.isfinite(value):
        raise TemplateError(f"{kind}.{name}: expected {noun}, got {value!r}")
    if low is not None and (value <= low if low_open else value < low):
        raise TemplateError(f"{kind}.{name}: expected {noun} {'>' if low_open else '>='} "
                            f"{low:g}, got {value:g}")
    if high is not None and value > high:
        raise TemplateError(f"{kind}.{name}: expected {noun} <= {high:g}, got {value:g}")


def _check_flag(kind: str, name: str, value) -> None:
    if not isinstance(value, bool):
        raise TemplateError(f"{kind}.{name}: expected true or false, got {value!r}")


def _check_placement(kind: str, position, heading_deg) -> None:
    if len(tuple(position)) != 2:
        raise TemplateError(f"{kind}.position: expected [x, z] (metres), got {position!r}")
    for k, v in enumerate(position):
        _check(kind, f"position[{k}]", v)
    _check(kind, "heading_deg", heading_deg, -360.0, 360.0)


@dataclass(frozen=True)
class ChairParams:
    """A chair: a seat (its front edge `seat_height` above the floor, `seat_depth` from the
    back to the front edge, `seat_width` across, its rear `seat_tilt_deg` lower than its
    front, its front edge rounded down by `front_drop`), a back `back_height` long, leaning
    `back_angle_deg` from vertical, and optional arms `arm_height` above the seat and
    `arm_width` wide (which run on up the back as wings). With `seams`, creases where the
    seat meets the back and the arms (an upholsterer's seams; without, the default, the fit
    rounds them: a sharp seat-back seam can fold the surface back on itself into a slit).
    Lengths in metres."""

    seat_height: float = 0.45
    seat_depth: float = 0.46
    seat_width: float = 0.50
    seat_tilt_deg: float = 4.0
    front_drop: float = 0.0
    back: bool = True
    back_angle_deg: float = 12.0
    back_height: float = 0.50
    arms: bool = False
    arm_height: float = 0.22
    arm_width: float = 0.08
    seams: bool = False
    seat_quads: tuple[int, int] = (8, 6)
    back_quads: int = 5
    position: tuple[float, float] = (0.0, 0.0)
    heading_deg: float = 0.0

    def __post_init__(self):
        _check_seat(self, "chair")


SEAT_PROFILE_KEYS = ("seat_height", "seat_depth", "seat_tilt_deg", "back_angle_deg",
                     "back_height", "seat_width", "rear")


@dataclass(frozen=True)
class BenchParams(ChairParams):
    """A bench for `seats` people side by side, each `seat_width` wide: a chair's seat
    across all of them (see `ChairParams`), backless by default, arms at the ends.

    `seat_profiles`: a table per seat, from -x to +x, that gives that seat its own
    `seat_height`, `seat_depth`, `seat_tilt_deg`, `back_angle_deg`, `back_height`,
    `seat_width` and `rear` (how far its rear line lies in front of the bench's, metres), any
    of them (the others as the bench's): each sitter a chair of their own, side by side in one
    sheet (the seams between seats take the mean of both profiles). `seat_each`: measure
    those tables on each sitter (`solver.scene.furnish`), as for a chair of their own."""

    seat_width: float = 0.55
    seat_tilt_deg: float = 3.0
    back: bool = False
    back_height: float = 0.45
    seats: int = 2
    seat_profiles: tuple[dict, ...] = ()
    seat_each: bool = False

    def __post_init__(self):
        _check("bench", "seats", self.seats, 1, 20, whole=True)
        _check_seat(self, "bench")
        _check_flag("bench", "seat_each", self.seat_each)
        if not self.seat_profiles:
            return
        if len(self.seat_profiles) != self.seats:
            raise TemplateError(f"bench.seat_profiles: expected one table per seat "
                                f"({self.seats}), got {len(self.seat_profiles)}")
        for k in range(self.seats):
            seat = _seat_of(self, k)
            _check(f"bench.seat_profiles[{k}]", "rear",
                   self.seat_profiles[k].get("rear", 0.0), -1.0, 1.0)
            if self.arms and self.back and k in (0, self.seats - 1):
                _check_arms("bench", self, seat, f" (seat_profiles[{k}])")


def _seat_of(p: BenchParams, k: int) -> ChairParams:
    """Seat k of a bench with `seat_profiles`: a chair of the bench's parameters and the
    seat's own (TemplateError naming the seat's table for a bad one)."""
    where = f"bench.seat_profiles[{k}]"
    entry = p.seat_profiles[k]
    if not isinstance(entry, dict):
        raise TemplateError(f"{where}: expected a table of {list(SEAT_PROFILE_KEYS)}, got "
                            f"{entry!r}")
    unknown = sorted(set(entry) - set(SEAT_PROFILE_KEYS))
    if unknown:
        raise TemplateError(f"{where}: unknown parameter {unknown[0]!r} (expected one of "
                            f"{list(SEAT_PROFILE_KEYS)})")
    values = {f.name: getattr(p, f.name) for f in dataclasses.fields(ChairParams)}
    values.update({key: v for key, v in entry.items() if key != "rear"})
    values["arms"] = False  # (the bench's arms stand on its end seats: checked there)
    try:
        return ChairParams(**values)
    except TemplateError as exc:
        raise TemplateError(str(exc).replace("chair.", f"{where}.", 1)) from None


@dataclass(frozen=True)
class StoolParams:
    """A stool: a seat `seat_height` high (its front edge), `seat_width` x `seat_depth`, its
    rear `seat_tilt_deg` lower than its front (negative: tilted forward, for perching), every
    edge rounded down by `edge_drop`."""

    seat_height: float = 0.65
    seat_depth: float = 0.36
    seat_width: float = 0.40
    seat_tilt_deg: float = 0.0
    edge_drop: float = 0.03
    seat_quads: tuple[int, int] = (6, 6)
    position: tuple[float, float] = (0.0, 0.0)
    heading_deg: float = 0.0

    def __post_init__(self):
        kind = "stool"
        _check_seat(self, kind)
        # rounded all round, as a bed or a cushion is
        _check_rounding(kind, "edge_drop", self.edge_drop, {"seat_width": self.seat_width,
                        "seat_depth": self.seat_depth})
        _check_corners(kind, "edge_drop", self.edge_drop, {
            "seat_height": self.seat_height, "seat_depth": self.seat_depth,
            "seat_tilt_deg": self.seat_tilt_deg}, dataclasses.asdict(self))


@dataclass(frozen=True)
class FloorCushionParams:
    """A cushion on the floor, its top `height` above it, `width` x `depth`, its edges rounded
    down by `edge_drop`; with `back`, a back as a chair's (a floor chair)."""

    height: float = 0.12
    depth: float = 0.55
    width: float = 0.60
    edge_drop: float = 0.03
    back: bool = False
    back_angle_deg: float = 20.0
    back_height: float = 0.45
    # a floor sitter's cushion runs from the buttocks to the heels (about a metre) and rises
    # under the knees: at 8 x 6 quads its rise swings its free edges into walls beside the
    # shins, one down to the floor (coverage 0.949 of the bundled floor sitter); at 10 x 8 the
    # walls stay low (0.970, lowest point 38 mm)
    quads: tuple[int, int] = (10, 8)
    back_quads: int = 5
    position: tuple[float, float] = (0.0, 0.0)
    heading_deg: float = 0.0

    def __post_init__(self):
        kind = "floor_cushion"
        _check(kind, "height", self.height, 0.02, 0.6)
        _check(kind, "depth", self.depth, 0.1, 2.0)
        _check(kind, "width", self.width, 0.1, 6.0)
        _check(kind, "edge_drop", self.edge_drop, 0.0, min(self.height, 0.1))
        _check_flag(kind, "back", self.back)
        _check(kind, "back_angle_deg", self.back_angle_deg, -10.0, 80.0)
        _check(kind, "back_height", self.back_height, 0.05, 1.5)
        _check_quads(kind, "quads", self.quads, 2)
        _check(kind, "back_quads", self.back_quads, 1, 40, whole=True)
        _check_placement(kind, self.position, self.heading_deg)
        _check_rounding(kind, "edge_drop", self.edge_drop, {"width": self.width,
                        "depth": self.depth})
        _check_corners(kind, "edge_drop", self.edge_drop, {"height": self.height},
                       dataclasses.asdict(self))


@dataclass(frozen=True)
class LoungerParams:
    """A chaise longue, in profile from the foot end to the head end: a foot rest from
    `foot_height` at the foot end up to the knee crest `knee_height` high, `leg_length` along
    it; a thigh rest `thigh_length` down to the seat hollow `seat_height` high; a back
    `back_length` long reclined `back_angle_deg` from vertical. `width` across."""

    seat_height: float = 0.32
    width: float = 0.62
    back_angle_deg: float = 55.0
    back_length: float = 0.85
    thigh_length: float = 0.45
    knee_height: float = 0.45
    leg_length: float = 0.50
    foot_height: float = 0.32
    quads_across: int = 8
    back_quads: int = 7
    thigh_quads: int = 4
    leg_quads: int = 3
    position: tuple[float, float] = (0.0, 0.0)
    heading_deg: float = 0.0

    def __post_init__(self):
        kind = "lounger"
        _check(kind, "seat_height", self.seat_height, 0.05, 1.2)
        _check(kind, "width", self.width, 0.2, 6.0)
        _check(kind, "back_angle_deg", self.back_angle_deg, 10.0, 85.0)
        _check(kind, "back_length", self.back_length, 0.2, 2.0)
        _check(kind, "thigh_length", self.thigh_length, 0.1, 1.0)
        _check(kind, "knee_height", self.knee_height, 0.05, 1.5)
        _check(kind, "leg_length", self.leg_length, 0.1, 1.2)
        _check(kind, "foot_height", self.foot_height, 0.02, 1.5)
        rise = self.knee_height - self.seat_height
        if abs(rise) >= self.thigh_length:
            raise TemplateError(f"lounger.knee_height: expected within thigh_length "
                                f"({self.thigh_length:g} m) of seat_height "
                                f"({self.seat_height:g} m), got {self.knee_height:g}")
        if abs(self.foot_height - self.knee_height) >= self.leg_length:
            raise TemplateError(f"lounger.foot_height: expected within leg_length "
                                f"({self.leg_length:g} m) of knee_height "
                                f"({self.knee_height:g} m), got {self.foot_height:g}")
        for name in ("quads_across", "back_quads", "thigh_quads", "leg_quads"):
            _check(kind, name, getattr(self, name), 1, 60, whole=True)
        _check_placement(kind, self.position, self.heading_deg)


@dataclass(frozen=True)
class BedParams:
    """A bed: a flat top `height` above the floor, `width` x `length` (its foot end towards
    +z), every edge rounded down by `edge_drop`."""

    height: float = 0.45
    width: float = 0.90
    length: float = 2.00
    edge_drop: float = 0.04
    quads: tuple[int, int] = (8, 16)
    position: tuple[float, float] = (0.0, 0.0)
    heading_deg: float = 0.0

    def __post_init__(self):
        kind = "bed"
        _check(kind, "height", self.height, 0.05, 1.2)
        _check(kind, "width", self.width, 0.3, 6.0)
        _check(kind, "length", self.length, 0.5, 3.5)
        _check(kind, "edge_drop", self.edge_drop, 0.0, min(self.height, 0.15))
        _check_quads(kind, "quads", self.quads, 2)
        _check_placement(kind, self.position, self.heading_deg)
        _check_rounding(kind, "edge_drop", self.edge_drop, {"width": self.width,
                        "length": self.length})
        _check_corners(kind, "edge_drop", self.edge_drop, {"height": self.height},
                       dataclasses.asdict(self))


def _check_quads(kind: str, name: str, value, low: int) -> None:
    if len(tuple(value)) != 2:
        raise TemplateError(f"{kind}.{name}: expected [across, along] (two whole numbers), "
                            f"got {value!r}")
    for k, v in enumerate(value):
        _check(kind, f"{name}[{k}]", v, low, 200, whole=True)


def _check_seat(p, kind: str) -> None:
    """The checks chairs, benches and stools share."""
    _check(kind, "seat_height", p.seat_height, 0.05, 1.2)
    _check(kind, "seat_depth", p.seat_depth, 0.1, 1.5)
    _check(kind, "seat_width", p.seat_width, 0.1, 3.0)
    _check(kind, "seat_tilt_deg", p.seat_tilt_deg, -30.0, 30.0)
    drop_name = "front_drop" if hasattr(p, "front_drop") else "edge_drop"
    drop = getattr(p, drop_name)
    # (a stool's edges, rounded all round, are held to `_check_rounding`'s flat top: its own)
    _check(kind, drop_name, drop, 0.0, min(0.1, p.seat_depth / 4) if hasattr(p, "back") else 0.1)
    low = p.seat_height - p.seat_depth * math.tan(math.radians(max(p.seat_tilt_deg, 0.0)))
    if low < EDGE_CLEARANCE or (drop > 0 and low - drop < EDGE_CLEARANCE and hasattr(p, "back")):
        if low >= EDGE_CLEARANCE:  # (the seat stands clear, its dropped edge does not; a
            # stool's corners, rounded along both edges, drop further: its own check, one limit)
            raise TemplateError(f"{kind}.{drop_name}: expected a drop that keeps the seat's "
                                f"edge above the floor, at most "
                                f"{_floor_mm(low - EDGE_CLEARANCE):.3f} here, got {drop:g} (the "
                                f"edge would be at {low - drop:.3f} m)")
        raise TemplateError(f"{kind}.seat_tilt_deg: expected a tilt that keeps the seat above "
                            f"the floor, got {p.seat_tilt_deg:g} (its rear would be at "
                            f"{low - drop:.3f} m)")
    _check_quads(kind, "seat_quads", p.seat_quads, 2)
    if hasattr(p, "back"):
        _check_flag(kind, "back", p.back)
        _check(kind, "back_angle_deg", p.back_angle_deg, -10.0, 60.0)
        _check(kind, "back_height", p.back_height, 0.05, 1.5)
        _check(kind, "back_quads", p.back_quads, 1, 40, whole=True)
        _check_flag(kind, "arms", p.arms)
        _check_flag(kind, "seams", p.seams)
        _check(kind, "arm_height", p.arm_height, 0.03, 0.6)
        _check(kind, "arm_width", p.arm_width, 0.02, 0.4)
        if p.arms and p.back and not getattr(p, "seat_profiles", ()):
            _check_arms(kind, p, p)  # (a bench with a profile per seat: its end seats')
    _check_placement(kind, p.position, p.heading_deg)


FLAT_MIDDLE = 0.02  # metres of flat top at least between the rounded edges of opposite sides
EDGE_CLEARANCE = 0.02  # metres a seat's dropped edge (and a stool's corners) stay above the floor


def _check_rounding(kind: str, name: str, drop: float, sides: dict[str, float]) -> None:
    """A TemplateError unless the rounding `drop` of a sheet's edges leaves FLAT_MIDDLE of
    flat top on each of its `sides` (name -> metres) between the rounded edges of opposite
    sides: at half a side they meet (zero-area quads), past it they cross (flipped ones)."""
    limit = (min(sides.values()) - FLAT_MIDDLE) / 2
    if drop > limit + 1e-9:
        given = ", ".join(f"{key} {value:g} m" for key, value in sides.items())
        raise TemplateError(f"{kind}.{name}: expected a drop that leaves "
                            f"{100 * FLAT_MIDDLE:g} cm of flat top between the rounded edges of "
                            f"{' and '.join(sides)}, at most {_floor_mm(limit):.3f} here "
                            f"({given}), got {drop:g} (the rounded edges would meet)")


def _floor_mm(metres: float) -> float:
    """`metres` rounded down to the millimetre (a limit quoted never above the true one)."""
    return math.floor(metres * 1000 + 1e-9) / 1000


def _corner_lowest(kind: str, values: dict):
    """lowest(drop) -> the height (m) of the lowest control point of a `kind` template rounded
    down all round by `drop`, with its other parameters `values` (name -> value; None for a
    kind without rounded corners), and the clearance its corners keep above the floor."""
    if kind == "bed":
        return (lambda drop: _rounded_sheet_low(values["height"], values["length"], 0.0,
                                                drop)), 0.0
    if kind == "floor_cushion":
        back = (values["back_angle_deg"], values["back_height"]) if values["back"] else None
        return (lambda drop: _rounded_sheet_low(values["height"], values["depth"], 0.0, drop,
                                                back)), 0.0
    if kind == "stool":
        return (lambda drop: _rounded_sheet_low(values["seat_height"], values["seat_depth"],
                                                values["seat_tilt_deg"], drop)), EDGE_CLEARANCE
    return None, 0.0


def _largest_drop(lowest, drop: float, clearance: float) -> float:
    """The largest drop up to `drop` whose lowest point (`lowest(drop)`) keeps `clearance`
    above the floor (0 when none does), to a nanometre."""
    if lowest(drop) >= clearance - 1e-9:
        return drop
    keep, lose = 0.0, drop
    for _ in range(40):
        mid = (keep + lose) / 2
        keep, lose = (mid, lose) if lowest(mid) >= clearance - 1e-9 else (keep, mid)
    return keep


def edge_drop_limit(kind: str, values: dict) -> float | None:
    """The largest `edge_drop` that keeps the corners of a `kind` template clear of the floor
    (a stool's by EDGE_CLEARANCE), with its other parameters `values` (name -> value; those
    left out at their defaults), rounded down to the millimetre; None for a kind whose edges
    are not rounded down all round. For a default that must not be refused (`furnish`)."""
    defaults = {f.name: f.default for f in dataclasses.fields(TEMPLATE_PARAMS[kind])
                if f.default is not dataclasses.MISSING}
    lowest, clearance = _corner_lowest(kind, defaults | values)
    if lowest is None:
        return None
    return _floor_mm(_largest_drop(lowest, 1.0, clearance))


def _check_corners(kind: str, name: str, drop: float, involved: dict[str, float],
                   values: dict) -> None:
    """A TemplateError unless a sheet rounded down by `drop` keeps its corners clear of the
    floor (`_corner_lowest`, of `kind` with its parameters `values`): rounded along both
    edges, a corner drops further than either edge. The message names the `involved`
    parameters (name -> value)."""
    lowest, clearance = _corner_lowest(kind, values)
    low = lowest(drop)
    if low >= clearance - 1e-9:
        return
    keep = _floor_mm(_largest_drop(lowest, drop, clearance))
    given = ", ".join(f"{key} {value:g}" for key, value in involved.items())
    above = f"{100 * clearance:g} cm above the floor" if clearance else "above the floor"
    raise TemplateError(f"{kind}.{name}: expected a drop that keeps the corners {above}, at "
                        f"most {keep:.3f} here ({given}), got {drop:g} (a corner would be at "
                        f"{low:.3f} m)")


def _rounded_sheet_low(height: float, depth: float, tilt_deg: float, drop: float,
                       back: tuple[float, float] | None = None) -> float:
    """The lowest control point (y, metres) of a sheet `depth` long whose front edge is
    `height` high, tilted `tilt_deg`, with every edge rounded down by `drop` (its sides the
    profile offset by -drop, as `_sweep` makes them) but the rear's, with a `back`."""
    keys, counts, _ = _seat_profile(height, depth, tilt_deg, drop, drop, back, 1, 1)
    sides = keys - drop * _offset_normals(keys, counts)
    return float(min(keys[:, 1].min(), sides[:, 1].min()))


def _check_arms(kind: str, p, seat, where: str = "") -> None:
    """A TemplateError unless the arms of `p` (their height, offset from the seat's profile
    along its normal) fit in the profile of `seat` (a chair's parameters: its seat and back):
    an arm band offset from the inner corner where the seat meets the back loses length on
    both; too high, its top shrinks to nothing and folds over itself."""
    keys, counts, junction = _seat_profile(
        seat.seat_height, seat.seat_depth, seat.seat_tilt_deg, p.front_drop, 0.0,
        (seat.back_angle_deg, seat.back_height), p.seat_quads[1], p.back_quads)
    reach, j = _offset_reach(keys, counts)
    if p.arm_height < reach:
        return
    part = "back" if j >= junction else "seat"
    given = ", ".join(f"{key} {getattr(seat, key):g}" for key in (
        "seat_depth", "seat_tilt_deg", "back_angle_deg", "back_height"))
    raise TemplateError(f"{kind}.arm_height: expected arms that the {part}{where} is long "
                        f"enough to carry, below {reach:.3f} here ({given}), got "
                        f"{p.arm_height:g} (where the seat meets the back, the arms' tops "
                        f"would fold over themselves)")


TEMPLATE_PARAMS: dict[str, type] = {
    "chair": ChairParams, "bench": BenchParams, "stool": StoolParams,
    "floor_cushion": FloorCushionParams, "lounger": LoungerParams, "bed": BedParams,
}
KINDS = tuple(TEMPLATE_PARAMS)


@dataclass(frozen=True, eq=False)
class TemplateMesh:
    """A template's control mesh, in the scene (metres, Y up).

    vertices : (n, 3) float; quads : (F, 4) int, faces towards the bodies; creases : (C, 2)
    int control edges kept sharp; grid : (Nu, Nv) int, the vertex layout (u across the width,
    v along the profile); kind and params : what made it.
    """

    vertices: np.ndarray
    quads: np.ndarray
    creases: np.ndarray
    grid: np.ndarray
    kind: str
    params: Any

    @property
    def source(self) -> str:
        """A line saying what the mesh is (reports, error messages)."""
        nu, nv = self.grid.shape
        return f"{self.kind} template, {nu - 1} x {nv - 1} quads"


def template_params(kind: str, **values) -> Any:
    """The parameter dataclass of a template kind from keyword values (lists become tuples);
    unset ones take their defaults. Raises TemplateError for an unknown kind or parameter."""
    if kind not in TEMPLATE_PARAMS:
        raise TemplateError(f"Expected a template kind of {list(KINDS)}, got {kind!r}")
    cls = TEMPLATE_PARAMS[kind]
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise TemplateError(f"{kind}: unknown parameter {unknown[0]!r} (expected one of "
                            f"{sorted(known)})")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def make_template(kind: str, params: Any = None, **values) -> TemplateMesh:
    """The control mesh of a template.

    Parameters
    ----------
    kind : one of `KINDS`.
    params : the kind's parameter dataclass (`TEMPLATE_PARAMS[kind]`), or None to make it from
        `values` (its defaults for the rest).

    Returns
    -------
    TemplateMesh : vertices (n, 3) metres, quads (F, 4) facing the bodies, creases (C, 2).
    Raises TemplateError for bad parameters.
    """
    if params is None:
        params = template_params(kind, **values)
    elif values:
        raise TemplateError("Expected parameters as a dataclass or as keywords, not both")
    elif not isinstance(params, TEMPLATE_PARAMS.get(kind, ())):
        raise TemplateError(f"Expected {TEMPLATE_PARAMS[kind].__name__} for a {kind}, got "
                            f"{type(params).__name__}")
    build = {"chair": _chair, "bench": _bench, "stool": _stool,
             "floor_cushion": _floor_cushion, "lounger": _lounger, "bed": _bed}[kind]
    columns, keys, counts, crease_cols, crease_rows = build(params)
    verts, quads, creases, grid = _sweep(columns, keys, counts, crease_cols, crease_rows)
    turn = math.radians(params.heading_deg)
    c, s = math.cos(turn), math.sin(turn)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # about +y: +z -> (s, 0, c)
    verts = verts @ rot.T + [params.position[0], 0.0, params.position[1]]
    return TemplateMesh(verts, quads, creases, grid, kind, params)


# profiles -------------------------------------------------------------------------------------

def _polyline(keys: np.ndarray, counts) -> tuple[np.ndarray, np.ndarray]:
    """Points along a polyline through `keys` (k, d), `counts[i]` equal steps on segment i;
    and the index of each key point among them (the grid lines creases may run along)."""
    keys = np.asarray(keys, dtype=float)
    pieces, at = [keys[:1]], [0]
    for a, b, n in zip(keys[:-1], keys[1:], counts):
        t = np.arange(1, n + 1)[:, None] / n
        pieces.append(a + t * (b - a))
        at.append(at[-1] + n)
    return np.concatenate(pieces), np.array(at)


def _seat_profile(height: float, depth: float, tilt_deg: float, front_drop: float,
                  rear_drop: float | None, back: tuple[float, float] | None, nz: int,
                  back_quads: int) -> tuple[np.ndarray, list[int], int | None]:
    """(m, 2) (z, y) points of a seat's profile from its front edge to its rear (and up its
    back): the rounded front, the seat, then the back or a rounded rear. The seat's rear line
    is at z = 0. Returns the points, the counts per segment and the seat-back key's index."""
    slope = math.tan(math.radians(tilt_deg))
    front = np.array([depth, height])
    rear = np.array([0.0, height - depth * slope])
    keys = [front + [0.0, -front_drop], front + [-front_drop, 0.0]] if front_drop > 0 \
        else [front]
    counts = [1] if front_drop > 0 else []
    if back is None:
        drop = rear_drop or 0.0
        keys += [rear + [drop, -drop * slope]] + ([rear + [0.0, -drop]] if drop > 0 else [])
        counts += [nz] + ([1] if drop > 0 else [])
        return np.array(keys), counts, None
    angle, length = back
    a = math.radians(angle)
    keys += [rear, rear + length * np.array([-math.sin(a), math.cos(a)])]
    counts += [nz, back_quads]
    return np.array(keys), counts, len(keys) - 2


def _across(width: float, n: int, drop: float = 0.0,
            arms: tuple[float, float] | None = None) -> tuple[np.ndarray, list[int], list[int]]:
    """(k, 2) (x, offset along the profile's normal) of the columns across a sheet `width`
    wide in `n` quads: edges rounded down by `drop`, or arms (height, width) at both sides
    (a wall up, then the arm's top); and the key columns that get creases."""
    half = width / 2
    keys, counts = [[-half, 0.0], [half, 0.0]], [n]
    creases: list[int] = []
    if drop > 0:
        keys = [[-half, -drop], [-half + drop, 0.0], [half - drop, 0.0], [half, -drop]]
        counts = [1, max(n - 2, 1), 1]
    if arms is not None:
        rise, wide = arms
        keys = [[-half - wide, rise], [-half, rise]] + keys + [[half, rise], [half + wide, rise]]
        counts = [1, 1] + counts + [1, 1]
    points, at = _polyline(np.array(keys), counts)
    if arms is not None:
        creases = [int(at[1]), int(at[2]), int(at[-3]), int(at[-2])]
    return points, counts, creases


def _miter_normals(points: np.ndarray) -> np.ndarray:
    """(m, 2) normals of a (z, y) polyline, towards the body's side (up along a seat that runs
    towards -z, forward along a back that rises), scaled so that offsetting by h moves every
    segment by h (a miter at the corners)."""
    tangent = np.diff(points, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    seg = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)  # (z, y) of the normal
    before = np.concatenate([seg[:1], seg])
    after = np.concatenate([seg, seg[-1:]])
    return (before + after) / (1.0 + np.einsum("ij,ij->i", before, after))[:, None]


def _offset_normals(profile: np.ndarray, counts) -> np.ndarray:
    """(m, 2) normals that the key polyline `profile` (m, 2) of (z, y) is offset along in a
    sweep (`_miter_normals`, but for a rounded front edge, `counts[0]` one step)."""
    normals = _miter_normals(profile)
    if counts[0] == 1 and len(profile) > 2:
        # a rounded front edge: bands offset from it (arms) are the rounded edge moved along
        # the seat's normal, not rolled forward around it
        normals[:2] = _miter_normals(profile[1:3])[0]
    return normals


def _offset_reach(profile: np.ndarray, counts) -> tuple[float, int]:
    """How far (metres) the key polyline `profile` (m, 2) can be offset towards the body
    (`_offset_normals`) before one of its segments shrinks to nothing (and beyond, turns back
    on itself: the offset band folds), and that segment's index (inf, -1: never)."""
    normals = _offset_normals(profile, counts)
    step = np.diff(profile, axis=0)
    # segment j offset by h runs step_j + h (n_j+1 - n_j); along step_j it keeps
    # |step_j|^2 + h (n_j+1 - n_j) . step_j
    length2 = np.einsum("ij,ij->i", step, step)
    shrink = -np.einsum("ij,ij->i", np.diff(normals, axis=0), step)
    reach = np.full(len(step), np.inf)
    np.divide(length2, shrink, out=reach, where=shrink > 1e-12 * length2)
    j = int(np.argmin(reach))
    return (float(reach[j]), j) if math.isfinite(reach[j]) else (math.inf, -1)


def _sweep(columns: np.ndarray, keys: np.ndarray, counts, crease_cols, crease_key_rows
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The grid of a side profile swept across columns (k, 2) of (x, offset): column i's
    profile is the key polyline (m, 2) of (z, y) (or, `keys` a list, column i's own, all with
    the same steps) offset by its offset along the keys' normals
    (so an arm's profile keeps its corners where the seat's are, never folding over an inner
    corner), with `counts[s]` equal steps on key segment s. Quads run so that their normal is
    +x cross the profile's direction (towards the body); creases along whole lines: the
    columns `crease_cols`, and the rows through the keys `crease_key_rows`."""
    each = keys if isinstance(keys, list) else [keys] * len(columns)
    normals_of: dict[int, np.ndarray] = {}  # per distinct profile (most columns share one)
    rows = []
    for profile, h in zip(each, columns[:, 1]):
        normals = normals_of.get(id(profile))
        if normals is None:
            normals = normals_of[id(profile)] = _offset_normals(profile, counts)
        rows.append(_polyline(profile + h * normals, counts)[0])
    _, at = _polyline(each[0], counts)
    zy = np.stack(rows)  # (nu, nv, 2)
    nu, nv = zy.shape[:2]
    verts = np.stack([np.broadcast_to(columns[:, None, 0], (nu, nv)), zy[..., 1], zy[..., 0]],
                     axis=-1).reshape(-1, 3)
    grid = np.arange(nu * nv).reshape(nu, nv)
    quads = np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]],
                     axis=-1).reshape(-1, 4)
    creases = [np.stack([grid[i, :-1], grid[i, 1:]], axis=1) for i in crease_cols]
    creases += [np.stack([grid[:-1, at[k]], grid[1:, at[k]]], axis=1) for k in crease_key_rows]
    creases = np.concatenate(creases) if creases else np.zeros((0, 2), dtype=np.int64)
    return verts, quads, creases.astype(np.int64), grid


# the kinds: each gives the columns across, the profile's keys and steps, and the creases ---------

def _seat_with_back(p, width: float, nx: int):
    back = (p.back_angle_deg, p.back_height) if p.back else None
    keys, counts, junction = _seat_profile(p.seat_height, p.seat_depth, p.seat_tilt_deg,
                                           p.front_drop, 0.0, back, p.seat_quads[1],
                                           p.back_quads)
    columns, _, crease_cols = _across(width, nx,
                                      arms=(p.arm_height, p.arm_width) if p.arms else None)
    if not p.seams:
        return columns, keys, counts, [], []
    return columns, keys, counts, crease_cols, [junction] if junction is not None else []


def _chair(p: ChairParams):
    return _seat_with_back(p, p.seat_width, p.seat_quads[0])


def _bench(p: BenchParams):
    if not p.seat_profiles:
        return _seat_with_back(p, p.seat_width * p.seats, p.seat_quads[0] * p.seats)
    seats = [_seat_of(p, k) for k in range(p.seats)]
    profiles = []
    for seat, entry in zip(seats, p.seat_profiles):
        keys, counts, junction = _seat_profile(
            seat.seat_height, seat.seat_depth, seat.seat_tilt_deg, p.front_drop, 0.0,
            (seat.back_angle_deg, seat.back_height) if p.back else None, p.seat_quads[1],
            p.back_quads)
        profiles.append(keys + [float(entry.get("rear", 0.0)), 0.0])
    # the seats side by side, centred on the bench's origin, each its own width in
    # seat_quads[0] columns; a seam column between two seats takes the mean of their profiles
    widths = np.array([seat.seat_width for seat in seats])
    edges = np.concatenate([[0.0], np.cumsum(widths)]) - widths.sum() / 2
    nq = p.seat_quads[0]
    xs, keys = [edges[0]], [profiles[0]]
    for k in range(p.seats):
        for j in range(1, nq + 1):
            xs.append(edges[k] + widths[k] * j / nq)
            seam = j == nq and k + 1 < p.seats
            keys.append((profiles[k] + profiles[k + 1]) / 2 if seam else profiles[k])
    columns, _, crease_cols = _across(widths.sum(), nq * p.seats,
                                      arms=(p.arm_height, p.arm_width) if p.arms else None)
    first = 2 if p.arms else 0  # (an arm's two columns come before the seat's)
    columns[first:first + len(xs), 0] = xs
    keys = [profiles[0]] * first + keys + [profiles[-1]] * (len(columns) - first - len(xs))
    if not p.seams:
        return columns, keys, counts, [], []
    return columns, keys, counts, crease_cols, [junction] if junction is not None else []


def _stool(p: StoolParams):
    keys, counts, _ = _seat_profile(p.seat_height, p.seat_depth, p.seat_tilt_deg, p.edge_drop,
                                    p.edge_drop, None, max(p.seat_quads[1] - 2, 1), 0)
    keys[:, 0] -= p.seat_depth / 2  # the origin under the middle
    columns, _, _ = _across(p.seat_width, p.seat_quads[0], p.edge_drop)
    return columns, keys, counts, [], []


def _floor_cushion(p: FloorCushionParams):
    back = (p.back_angle_deg, p.back_height) if p.back else None
    nz = p.quads[1] if p.back else max(p.quads[1] - 2, 1)
    keys, counts, junction = _seat_profile(p.height, p.depth, 0.0, p.edge_drop, p.edge_drop,
                                           back, nz, p.back_quads)
    columns, _, _ = _across(p.width, p.quads[0], p.edge_drop)
    return columns, keys, counts, [], [junction] if junction is not None else []


def _lounger(p: LoungerParams):
    a = math.radians(p.back_angle_deg)
    rise = p.knee_height - p.seat_height
    knee_z = math.sqrt(p.thigh_length ** 2 - rise ** 2)
    foot_z = knee_z + math.sqrt(p.leg_length ** 2 - (p.knee_height - p.foot_height) ** 2)
    keys = np.array([[foot_z, p.foot_height], [knee_z, p.knee_height], [0.0, p.seat_height],
                     [-p.back_length * math.sin(a), p.seat_height + p.back_length * math.cos(a)]])
    columns, _, _ = _across(p.width, p.quads_across)
    return columns, keys, [p.leg_quads, p.thigh_quads, p.back_quads], [], []


def _bed(p: BedParams):
    half, d = p.length / 2, p.edge_drop
    if d > 0:
        keys = np.array([[half, p.height - d], [half - d, p.height], [-half + d, p.height],
                         [-half, p.height - d]])
        counts = [1, max(p.quads[1] - 2, 1), 1]
    else:
        keys, counts = np.array([[half, p.height], [-half, p.height]]), [p.quads[1]]
    columns, _, _ = _across(p.width, p.quads[0], d)
    return columns, keys, counts, [], []
