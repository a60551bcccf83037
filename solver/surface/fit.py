"""Fitting the supporting surface: the paper's section 5 and appendix A.

Given posed bodies (their vertices, normals and importance) and a quad control mesh V0, find the
control mesh whose level-s Catmull-Clark surface S V supports each body where it needs support,
smoothly, without cutting into it. Each iteration:

1. subdivides (the operator S is built once) and takes the surface normals;
2. pairs every important body vertex b_k with its closest surface vertex s(k) (a KD-tree);
3. minimises, as a quadratic programme (DAQP on small meshes, OSQP on large ones),

   E = (1 / sum rho) sum_k rho_k [(1 - tau) |b_k - v_s(k)|^2 + tau (n_s(k) . (b_k - v_s(k)))^2]
       + (sigma / n0) |L V|^2 + gamma sum_fixed |v_j - v0_j|^2

       + (anchor / n0) sum_all |v_j - v0_j|^2

   where b_k is the body vertex moved `sink` (8 mm) inwards along its normal (the foam is
   pressed that far where it carries the body, so the skin rests on it instead of grazing it:
   aimed at the skin itself, half the supported skin ends up a few millimetres in front of the
   surface, out of contact), L is the cotangent Laplacian of the control mesh, tau rises from
   0 to tau_max over the first iterations, subject to every surface vertex near a body staying
   on the outer side of the tangent plane at its closest body vertex, less the softness margin:
   n_b . (v_s - b) >= -margin. "Closest" weighs the body vertex's normal too: the search runs in
   (position, FACING_SCALE x normal) space for (v_s, -n_s), so a surface vertex pairs with the
   body side that faces it. Without that, a surface that starts inside a body (a grid through
   the thighs) would be pushed out through the top of the thigh, to the wrong side.

   The last term is ours: the smoothness term leaves planes free (tilting the whole surface costs
   nothing), so parts of the surface that no body touches would drift; a weak pull of every
   control vertex to its start (anchor = 0.001 by default, 0 to turn it off) keeps them where the
   designer put them without holding the supported parts back. Two more of ours: body points
   farther than `pull_range` from the surface do not pull yet (the surface grows towards the
   bodies from where it starts instead of reaching across the scene), and a proximal pull to the
   previous iterate (PROXIMAL) damps the alternation between pairing and solving. Each
   iteration is also a trust region: no control vertex moves more than `step` per coordinate
   (so the tangent planes stay valid), and a violated non-penetration row need only improve
   by most of a step.

The data terms are gathered per surface vertex (the weighted mean of the body points it serves),
so the programme's size depends on the control mesh, not on the bodies. Non-penetration rows are
kept for the surface vertices a body can reach (joined by any that come within CONSTRAINT_RADIUS
later) and are active only within that radius. Small meshes (up to DENSE_UP_TO control
vertices) are solved exactly by DAQP, larger ones by OSQP warm-started from the last solution;
both over the rows that could bind (`solver.surface.programme`). The solver's status is checked
every time.

A step is accepted only if it does not raise the judged energy (the programme's own objective:
the energy with every body point at its nearest vertex of the new surface, plus the cost of the
demands the new surface leaves unmet) and folds no neighbouring level-s quads further apart than
FOLD_GUARD_DEG (or than the iterate before it); otherwise it is tried again half as long (a
backtracking line search along the programme's solution), up to MAX_HALVINGS times, after which
the fit has converged; while tau is still ramping, the loop first shortens likewise the proposal
that was refused for its bends but lowered the energy most (a fit that stopped there would stop
before its energy is the fit's). In a cold fit, a full step refused for a fold or a ridge is first
proposed again, up to STIFFEN_ROUNDS times, with the smoothness raised (tenfold each time) at the
control vertices that shape the offending quads (`_stiffened`; the raise stays for the rest of
the fit and only the proposals see it), and a stiffened proposal refused for its energy once as
a step that only bends less there: the programme knows nothing of folds, and halving a step
that folds seldom stops it folding, so without this a fit stopped after a few iterations, far
from its best. In a warm refit (which starts against the guards, and must settle in a few
iterations) such a step is instead tried again as long with the control vertices that shape
the offending quads held still (up to FREEZES times). A step is
judged without its rows (the judgement needs only how deep the surface lies and which vertices
join the rows); the accepted one's rows are made for the next. So the judged energies of
the accepted iterates never rise (a rising tau can only lower them), and a surface that starts
without folds ends without them. The loop stops once tau has reached tau_max and the energy has
not improved by `tolerance` (relative) in PATIENCE iterations, or after `max_iterations`. The
result is the last accepted iterate whose limit surface does not cross itself (checked once at
the end, and by bisection over the accepted iterates if it does).

A warm refit (`fit_surface`'s `warm`: a person moved, a control vertex was edited) starts from
the last result at tau_max with what still holds of its set-up, and stops once settled (or
once its steps shrink so fast that the rest of them would not add up to `tolerance`); a
`cancel` callable ends any fit early with its last accepted iterate.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import Executor, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from solver.contact.supported import SupportedBody
from solver.mesh import boundary_edges
from solver.surface.guarantees import FOLD_LIMIT_DEG, neighbour_faces
from solver.surface.programme import DeadlinePassed, DenseProgramme, Programme, ProgrammeError
from solver.surface.subdivision import Subdivision, subdivision
from solver.threads import overlapped, with_limited_threads

REACH = 0.5  # metres: a person whose supported points are all farther from the surface is an error
CONSTRAINT_RADIUS = 0.12  # metres: surface vertices this close to a body get a non-penetration row
FACING_SCALE = 0.1  # metres a body normal's turn away from the surface counts as, in the search
# the farthest a pairing in that search can be while its skin point lies within CONSTRAINT_RADIUS
FACING_REACH = float(np.hypot(CONSTRAINT_RADIUS, 2 * FACING_SCALE)) + 1e-9
INSIDE_REACH = 0.3  # metres: no body part is thicker than twice this
EXIT_SCALE = 0.1  # the same, for a surface vertex inside a body: it leaves through nearby skin
                  # facing against the surface's normal, behind the body (below a seated one);
                  # a normal turned fully round counts as 20 cm, so skin on the far side of a
                  # limb wins up to about that depth, and the sole of a foot never does
TAU_RAMP = 5  # iterations over which tau rises from 0 to tau_max
PATIENCE = 5  # iterations without improvement before the loop stops
SLACK_WEIGHT = 1e3  # cost per m^2 of a non-penetration row left unmet (soft constraints)
DENSE_UP_TO = 150  # control vertices up to which the Hessian is built dense
PROXIMAL = 0.001  # weight of the pull to the current control mesh (per coordinate): enough
                  # to damp the alternation between pairing and solving; a stronger one slows
                  # the loop's tail (each step goes that much less of the way)
FOLD_GUARD_DEG = 50.0  # degrees between neighbouring level-s quads a step may not exceed
                       # (the guarantee's limit is 60 on the limit surface; a margin for it)
DEPTH_TOLERANCE = 1e-3  # metres beyond the margin an iterate is not yet judged for: the rows hold
                        # the surface to a skin vertex's plane, the judgement measures behind
                        # the nearest one's, and they differ by a fraction of a millimetre
REPAIR_ROUNDS = 5  # rounds of rows on dense samples found deeper than the margin
REPAIR_ITERATIONS = 10  # iterations each such round may take
REPAIR_SAFETY = 2e-3  # metres inside the margin those rows hold the samples to
SAG_ALLOWANCE = 0.01  # metres a triangle may sink deeper between its corners than at them
MAX_HALVINGS = 4  # a rejected step is retried half as long this often
STIFFEN_ROUNDS = 4  # times a step refused for a fold or a ridge is proposed again, the surface
                    # made stiffer where it folded (`_stiffened`), before it is tried shorter
STIFFEN_FIRST = 30.0  # that stiffening's first weight, in units of the smoothness (sigma) ...
STIFFEN_FACTOR = 10.0  # ... and what each further round multiplies it by
FREEZES = 2  # times a warm refit's step that folds or ridges too far is retried with the
             # control vertices that shape the offending quads held still (a cold fit's steps
             # are not: held vertices next to moving ones leave kinks that a thin solid's
             # offset folds over)
TREE_LEAF = 32  # points per leaf of the search trees (of the bodies, of the surface)
FACING_LEAF = 64  # ... and of the bodies' six-dimensional ones (quicker to build and to search)
RIM_CLEARANCE = 0.03  # metres the surface's rim may come no nearer to the unsupported skin in
                      # its foam (the calves that hang under a seat's front edge, a spread knee
                      # under its side): `rim_rows`
RIM_SLANT = 0.33  # ... and this much more per metre the skin lies behind the surface (beside a
                  # border, skin that far out runs sideways off it: not in the foam)
RIM_SLAB = 0.12  # metres behind the surface the foam reaches (the evaluation's 0.1 m and more)
RIM_FRONT = 0.03  # metres in front of the surface unsupported skin still counts (it sinks)
LID_FRONT = 0.08  # metres in front of the rim, skin of a region no one asked support for holds
                  # the rim behind it (more than a step's 5 cm along an axis: a rim that rises
                  # or swings towards such skin meets its row before it passes over it and
                  # leaves it in the foam behind the surface, as a stool's rising front corner
                  # passed over a calf and pressed it at 13 kPa; the row is linear in the step,
                  # so a corner whose normal turns fast can still pass)
LID_OUT = 0.03  # metres beyond the rim such skin still holds it (farther out, the rim's
                # clearance rows keep it off)
LID_CLEAR = 0.02  # metres the rim stays behind such skin along the rim's normal (the body
                  # sinks as it settles)
RIM_INNER = 0.04  # metres under the surface, inside its rim, skin still counts (deeper in, a
                  # surface over it clears it by its own shape, or does not)
RIM_FADE = 0.03  # metres over which a skin point's row fades out at the edges of that region
RIM_REACH = 0.15  # metres: the search radius round each rim vertex (covers that region)
RIM_SLACK = 0.05  # metres a rim vertex may move before the skin near the rim is sought again
RIM_SPAN = 0.4  # metres: skin farther from the start's rim is left out (a fit moves the rim less)
FLOOR_REACH = 2.0  # steps: a surface vertex this near the floor gets a floor row (it moves at
                   # most one step per iteration, so none gets under unseen)
DEPTH_CHUNK = 1024  # sampled vertices sought at a time while the search may be called off
                    # (a candidate refused meanwhile: `_body_side`)


class FitError(ValueError):
    """A fit that cannot run or cannot go on (and why)."""


@dataclass(frozen=True)
class FitParams:
    """The fit's parameters, with their defaults (the scenario schema takes them from here).

    level : subdivision level s; sigma : Laplacian smoothing weight; tau_max : ceiling of the
    point-to-plane blend; margin : metres the surface may sink into a body; fixed : control
    vertices held near their start, by gamma; creases : control edges kept sharp;
    max_iterations, tolerance : the loop's stop (relative improvement over PATIENCE
    iterations); anchor : weak pull of every control vertex to its start; pull_range : metres
    beyond which body points do not pull yet; step : metres a control vertex may move per
    iteration (a trust region); floor : the floor's height y (metres) that every level-s
    surface vertex stays above (soft rows, like non-penetration), None for no floor;
    min_ridge_radius : metres, the tightest a step may bend the surface away from the bodies
    (a ridge; a solid thicker than its radius cannot follow it); sink : metres into the skin,
    along its normal, that the data terms aim the surface (where the foam is pressed when it
    carries the body at rest; 0 fits the skin itself).
    """

    level: int = 3
    sigma: float = 0.003
    tau_max: float = 0.5
    margin: float = 0.03
    fixed: tuple[int, ...] = ()
    gamma: float = 10.0
    creases: tuple[tuple[int, int], ...] = ()
    max_iterations: int = 50
    tolerance: float = 0.01
    anchor: float = 1e-3
    pull_range: float = 0.25
    step: float = 0.05  # metres a control vertex may move per iteration (a trust region)
    floor: float | None = 0.0  # metres: the level-s surface stays above y = floor (None: free)
    min_ridge_radius: float = 0.015  # metres: where the surface bends away from the bodies, no
                                    # tighter (a solid of up to this thickness can follow it)
    sink: float = 0.008  # metres into the skin the data terms aim (the foam pressed at rest)


@dataclass
class FitResult:
    """A fitted surface: the control mesh (n0, 3) and its quads, the level-s surface (ns, 3)
    and quads (metres), the iterations run and why the loop stopped, the judged energy per
    iteration with the best iterate's terms, seconds, the programme's statuses and the
    subdivision."""

    control: np.ndarray  # (n0, 3) fitted control vertices
    faces: np.ndarray  # (F0, 4) control quads
    surface: np.ndarray  # (ns, 3) level-s vertices
    surface_faces: np.ndarray  # (Fs, 4)
    iterations: int
    stop_reason: str
    energies: list[float]
    energy_terms: dict
    seconds: float
    qp_statuses: list[str] = field(default_factory=list)
    subdivision: Subdivision | None = None
    limit: np.ndarray | None = None  # (ns, 3) the level-s vertices' limit points
    state: "FitState | None" = field(default=None, repr=False, compare=False)

    def limit_surface(self, creases=()) -> np.ndarray:
        """(ns, 3) metres: the limit points of the level-s vertices (what `surface.*` holds), as
        the fit computed them, or from the subdivision and the control `creases`."""
        if self.limit is not None:
            return self.limit
        from solver.surface.limit import limit_of_level

        if self.subdivision is None:
            raise ValueError("Expected a FitResult that carries its subdivision, got none")
        return limit_of_level(self.subdivision, self.surface, list(creases) or None)


class _Skin:
    """A body's closed skin (vertices (V, 3) m, triangles (T, 3)) where `stack` (a slice)
    says which of the fit's stacked body vertices are its own, with its winding-number and
    closest-point structures (`solver.contact.skins`', kept by content), built when first asked
    for. A skin that has only been moved (every vertex by the same vector) since asks for the
    ones of the positions they were first built on: queries are moved back by `offset`, the
    vector it moved by since."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, stack: slice):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self.stack = stack
        self.offset = np.zeros(3)
        self._built = self.vertices  # the positions the structures are built on

    def moved(self, vertices: np.ndarray, triangles: np.ndarray, stack: slice) -> "_Skin":
        """This skin at `vertices`: its structures kept when the vertices are these moved by
        one vector (and the triangles the same), else a new skin."""
        vertices = np.asarray(vertices, dtype=np.float64)
        if vertices.shape == self.vertices.shape and np.array_equal(triangles, self.triangles):
            shift = vertices[0] - self._built[0]
            if np.allclose(vertices - shift, self._built, rtol=0.0, atol=1e-12):
                skin = _Skin.__new__(_Skin)
                skin.__dict__.update(self.__dict__, vertices=vertices, stack=stack,
                                     offset=shift)
                return skin
        return _Skin(vertices, triangles, stack)

    def winding(self, points: np.ndarray) -> np.ndarray:
        """(k,) the skin's winding number at points (k, 3)."""
        from solver.contact.skins import body_winding

        return body_winding(self._built, self.triangles).winding_number(points - self.offset)

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Squared distances (k,), triangles (k,) and closest points (k, 3) on the skin of
        points (k, 3)."""
        from solver.contact.skins import body_closest

        tree = body_closest(self._built, self.triangles)
        dist2, face, at = tree.squared_distance(self._built, self.triangles,
                                                points - self.offset)
        return dist2, face, at + self.offset


@dataclass(frozen=True, eq=False)
class FitState:
    """What a fit leaves for a warm refit of the same control mesh (`fit_surface`'s `warm`):
    the subdivision's key (control vertices, level, creases), the start and its Laplacian (kept
    while the start stays where it was), the limit map, the surface vertices that carried rows
    and the programme set up for them, and the bodies with their search structures (reused while
    the bodies only move)."""

    key: tuple
    start: np.ndarray  # (n0, 3) the control vertices that fit started from (its `control`)
    limit: sp.csr_matrix | None
    member: np.ndarray  # (ns,) bool
    floor_member: np.ndarray  # (ns,) bool
    points: np.ndarray  # (P, 3)
    normals: np.ndarray  # (P, 3)
    trees: tuple  # (body_tree, body_tree3, exit_tree), as `_search_trees` builds them
    tree_offset: np.ndarray  # (3,) how far the points moved since the trees were built
    skins: list  # the fit's `_Skin`s
    programme: Programme | None  # the fit's programme while it has no rows on dense samples
    neighbours: np.ndarray  # `_Fit.neighbours`
    quad_maps: tuple  # `_Fit.quad_maps`
    lap: sp.csr_matrix | None = None  # `_Fit.lap`, the start's Laplacian
    rim_member: np.ndarray | None = None  # `_Rim.member`: the rim vertices that had clearance
    # rows, then those that had lid rows


def _search_trees(points: np.ndarray, normals: np.ndarray) -> tuple:
    """The body vertices' search trees: (position, FACING_SCALE x normal), positions,
    (position, EXIT_SCALE x normal), the last the first while the two scales are the same.
    Split at the middle of each box rather than at the median and with larger leaves: quicker
    to build and to query (the same nearest points)."""
    def tree(data: np.ndarray, leaf: int = TREE_LEAF) -> cKDTree:
        return cKDTree(data, leafsize=leaf, balanced_tree=False)

    facing = tree(np.concatenate([points, FACING_SCALE * normals], axis=1), FACING_LEAF)
    return (facing, tree(points), facing if EXIT_SCALE == FACING_SCALE else
            tree(np.concatenate([points, EXIT_SCALE * normals], axis=1), FACING_LEAF))


def _state_key(n0: int, params: "FitParams") -> tuple:
    return n0, params.level, tuple(map(tuple, params.creases))


def control_laplacian(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """(n, n) cotangent Laplacian of a polygon control mesh (libigl's polygon Laplacian)."""
    import igl

    corners, sizes = igl.polygon_corners(np.asarray(faces, dtype=np.int64))
    lap, _, _ = igl.cotmatrix(np.asarray(vertices, dtype=np.float64), corners, sizes)
    return sp.csr_matrix(lap)


@dataclass(eq=False)
class _Fit:
    """What stays fixed over one fit: the start, the operators, the bodies' important points
    and search trees, the quadratic weights and the programme."""

    v0: np.ndarray  # (n0, 3) start control vertices
    faces: np.ndarray
    params: FitParams
    sub: Subdivision
    lap: sp.csr_matrix  # (n0, n0) control-mesh Laplacian
    points: np.ndarray  # (P, 3) every body vertex
    normals: np.ndarray  # (P, 3)
    b_imp: np.ndarray  # (I, 3) the important ones, `sink` inside the skin: where they pull
    w_imp: np.ndarray  # (I,) their importance
    body_tree: cKDTree  # (position, FACING_SCALE x normal) of every body vertex
    body_tree3: cKDTree  # positions
    exit_tree: cKDTree  # (position, EXIT_SCALE x normal)
    fixed: np.ndarray  # (n0,) pull to the start: anchor / n0, plus gamma on fixed vertices
    smooth: sp.csr_matrix  # (sigma / n0) L^T L
    diagonal: np.ndarray | sp.csr_matrix  # smooth + fixed + proximal, per coordinate block
    proximal: float
    dense: bool
    programme: Programme
    sampled_ids: np.ndarray  # the surface vertices that may carry non-penetration rows
    neighbours: np.ndarray  # (E, 2) level-s quads sharing an edge that is no crease
    quad_maps: tuple  # level-s vertices -> their quads' diagonals (2 Fs, ns) and the gaps
                      # between the centres of neighbouring quads (E, ns)
    skins: list  # `_Skin` of every body with a closed skin
    tree_offset: np.ndarray  # (3,) the bodies' move since their trees were built: the trees
                             # are queried this much back
    limit: sp.csr_matrix | None = None  # (ns, n0) control vertices -> limit points of level s
    stiff: np.ndarray | None = None  # (n0,) extra smoothness of the steps' proposals per control
                                     # vertex, where proposals folded (`_stiffened`)
    stiff_matrix: tuple | None = None  # (stiff, L^T diag(stiff) L and its dense block): built
                                       # once per raise of `stiff`, not per proposal
    extra: "ExtraRows | None" = None  # rows on dense samples found too deep (`deep_samples`)
    rim: "_Rim | None" = None  # the surface's rim and the unsupported skin it keeps clear of
    pool: Executor | None = None  # the second thread `assess` overlaps its searches on

    @property
    def n0(self) -> int:
        return len(self.v0)


@dataclass(frozen=True, eq=False)
class Pairing:
    """Each important body point's closest surface vertex `pair` (I,), and per paired surface
    vertex `paired` (K,) its weight (K,) (importance within the pull range, over the total) and
    the weighted mean `target` (K, 3) of the points it serves."""

    pair: np.ndarray
    paired: np.ndarray
    weight: np.ndarray
    target: np.ndarray


@dataclass(frozen=True, eq=False)
class Rows:
    """The non-penetration (and floor) rows: surface vertices `rows` (R,), the normal (R, 3)
    each stays in front of, `demanded` (R,) the whole demand n . b - margin (-inf where a row
    is not wanted now) and `now` (R,) n . v at the current surface; `skin` (m,) the body
    vertex each sampled surface vertex is held to (-1 for none): a vertex inside a body keeps
    the one it had, so that the demand on it (and the judged energy) does not jump as the
    surface moves. `beyond_m2`: how far the surface itself is out of bounds, the sum of squares
    of the depths beyond the margin of its sampled vertices inside a body (each one's depth
    behind the tangent plane of its nearest skin vertex) and of its heights under the floor: a continuous measure of the
    surface (the rows are the programme's linear picture of it, which changes as the surface
    moves), by which an iterate is judged."""

    rows: np.ndarray
    normals: np.ndarray
    demanded: np.ndarray
    now: np.ndarray
    skin: np.ndarray | None = None
    beyond_m2: float = 0.0

    def bound(self, step: float) -> np.ndarray:
        """(R,) the step's bound on n . v: a violated row need only improve by most of a
        trust-region step (it stays feasible within the trust region)."""
        return np.minimum(self.demanded, self.now + 0.8 * step)


def _stack(targets: Sequence[SupportedBody]):
    points = np.concatenate([t.vertices for t in targets])
    normals = np.concatenate([t.normals for t in targets])
    rho = np.concatenate([t.importance for t in targets])
    owner = np.concatenate([np.full(len(t.vertices), k) for k, t in enumerate(targets)])
    return points, normals, rho, owner


def _check_bodies(surface0: np.ndarray, surface_normals: np.ndarray,
                  targets: Sequence[SupportedBody], points: np.ndarray, normals: np.ndarray,
                  rho: np.ndarray, owner: np.ndarray, important: np.ndarray,
                  floor: float | None = None, margin: float = 0.0) -> None:
    """A FitError when a body has nothing to support, lies beyond REACH of the start surface
    `surface0` (ns, 3) or has its lowest supported skin more than the `margin` under the
    `floor` (the floor is under the people: a surface held above a floor over them could reach
    no one; a floor within the margin may hold a surface up under a body sunk into it), or
    when the control mesh's faces point away from the bodies: the skin to be supported faces
    the surface, so its normals run against the surface's normals (`surface_normals`,
    (ns, 3)) where they meet (at the nearest surface vertex); if on the importance-weighted
    balance they run along them, the faces are reversed."""
    near, vertex = cKDTree(surface0).query(points[important])
    for k, t in enumerate(targets):
        mine = owner[important] == k
        if not mine.any():
            raise FitError(f"{t.label}: no body part to support faces the surface (nothing has "
                           "importance)")
        lowest = float(points[important[mine], 1].min())
        if floor is not None and lowest < floor - margin - 1e-9:
            raise FitError(f"The floor (y = {floor:.3g} m) lies more than the margin "
                           f"({margin:g} m) above {t.label}'s lowest supported skin (y = "
                           f"{lowest:.3f} m): the floor is under the people; lower it "
                           "(surface.floor) or set it to none")
        if near[mine].min() > REACH:
            raise FitError(f"{t.label} is entirely outside the surface's reach: its nearest "
                           f"supported point is {near[mine].min():.2f} m from the surface "
                           f"(reach {REACH} m); move the person or the surface")
    along = np.einsum("ij,ij->i", normals[important], surface_normals[vertex])
    share = float(rho[important] @ (along > 0) / rho[important].sum())
    if share > 0.5:
        raise FitError(f"The control mesh's faces point away from the bodies: "
                       f"{share:.0%} of the supported skin faces the same way as the surface "
                       "where they meet; flip the mesh (reverse each face's vertex order)")


def prepare(control: np.ndarray, faces: np.ndarray, targets: Sequence[SupportedBody],
            params: FitParams, state: FitState | None = None, pool: Executor | None = None
            ) -> _Fit:
    """Checks the inputs and builds what stays fixed over the fit (see `_Fit`), reusing what
    `state` (a fit of the same control mesh) built where it still holds. With a `pool` (the
    fit's second thread, which it keeps), the bodies' search trees are built there meanwhile."""
    v0 = np.asarray(control, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n0 = len(v0)
    if not targets:
        raise FitError("Expected at least one body to support, got none")
    for j in params.fixed:
        if not 0 <= j < n0:
            raise FitError(f"Expected fixed control vertices in 0..{n0 - 1}, got {j}")
    sub = subdivision(n0, faces, params.level, params.creases or None)
    lap = state.lap if state is not None and state.lap is not None and \
        np.array_equal(state.start, v0) else control_laplacian(v0, faces)
    points, normals, rho, owner = _stack(targets)
    important = np.flatnonzero(rho > 1e-3)
    surface0 = sub.matrix @ v0
    _check_bodies(surface0, sub.normals(surface0), targets, points, normals, rho, owner,
                  important, params.floor, params.margin)
    fixed = np.full(n0, params.anchor / n0)
    fixed[list(params.fixed)] += params.gamma
    smooth = (params.sigma / n0) * (lap.T @ lap)
    # the data terms are a mean over everybody's importance, so each person's pull per surface
    # vertex shrinks with their number; the numerical devices (the proximal damping, the cost of
    # an unmet row) shrink with it, or they would hold a crowd's surface back
    people = len(targets)
    proximal = PROXIMAL / people
    diagonal = (smooth + sp.diags(fixed + proximal)).tocsr()
    dense = n0 <= DENSE_UP_TO
    # non-penetration rows on the surface vertices that are vertex points of the level before
    # (every other vertex each way, about 2 cm apart on a seat): a quarter of the rows
    sampled = np.arange(sub.steps[-1].matrix.shape[1] if sub.steps else sub.matrix.shape[0])
    same = state is not None and state.key == _state_key(n0, params)
    if same:  # the same control quads (`_warm_state`), level and creases
        neighbours, quad_maps = state.neighbours, state.quad_maps
    else:  # the topology's alone: built once per subdivision operator
        neighbours = sub.kept("fit.neighbours", lambda: neighbour_faces(
            sub.faces, sub.steps[-1].creases if sub.steps else
            (np.asarray(params.creases).reshape(-1, 2) if params.creases else None)))
        quad_maps = sub.kept("fit.quad_maps", lambda: _quad_maps(sub, neighbours))
    trees = None
    if state is not None and state.points.shape == points.shape and \
            np.allclose(state.normals, normals, rtol=0.0, atol=1e-9):
        shift = points[0] - state.points[0]
        if np.allclose(points - shift, state.points, rtol=0.0, atol=1e-12):
            # the bodies only moved (or not at all): their trees hold, queried moved back
            trees, offset = state.trees, state.tree_offset + shift
    building = None
    if trees is None:
        offset = np.zeros(3)
        if pool is None:
            trees = _search_trees(points, normals)
        else:
            building = pool.submit(_search_trees, points, normals)
    if same and state.programme is not None and \
            state.programme.slack_weight == SLACK_WEIGHT / people and state.programme.claim():
        programme = state.programme  # its set-up holds while its rows do (no other fit's now)
    else:
        programme = (DenseProgramme if dense else Programme)(sub.matrix, lap, n0,
                                                             SLACK_WEIGHT / people)
        programme.claim()
    skins, at = [], 0
    for t in targets:
        stack = slice(at, at + len(t.vertices))
        at = stack.stop
        if t.triangles is None:
            continue
        old = state.skins[len(skins)] if state is not None and \
            len(skins) < len(state.skins) else None
        skins.append(old.moved(t.vertices, t.triangles, stack) if old is not None else
                     _Skin(t.vertices, t.triangles, stack))
    try:
        rim = _make_rim(sub, sampled, targets, v0, state.rim_member if same else None) \
            if RIM_CLEARANCE > 0 else None
        if building is not None:
            trees = building.result()
    except BaseException:
        programme.release()  # (a warm refit's programme is claimed above)
        raise
    # the data terms aim `sink` into the skin: the foam is pressed that far where it carries
    # the body at rest, so the skin touches it there rather than grazing it
    return _Fit(v0, faces, params, sub, lap, points, normals,
                points[important] - params.sink * normals[important],
                rho[important], *trees,
                fixed, smooth, diagonal.toarray() if dense else diagonal, proximal, dense,
                programme, sampled, neighbours, quad_maps,
                skins, offset, state.limit if same else None, rim=rim, pool=pool)


def _quad_maps(sub: Subdivision, neighbours: np.ndarray) -> tuple:
    """The linear maps from the level-s vertices to their quads' diagonals, v2 - v0 over
    v3 - v1 (2 Fs, ns), and to the gaps between the centres of neighbouring quads (E, ns)."""
    quads = sub.faces
    count, ns = len(quads), sub.matrix.shape[0]
    rows = np.arange(count)
    diagonals = sp.csr_matrix(
        (np.tile([1.0, -1.0, 1.0, -1.0], count),
         (np.repeat(np.concatenate([rows, count + rows]).reshape(2, -1).T, 2, axis=1).ravel(),
          quads[:, [2, 0, 3, 1]].ravel())), shape=(2 * count, ns))
    centres = sp.csr_matrix((np.full(4 * count, 0.25), (np.repeat(rows, 4), quads.ravel())),
                            shape=(count, ns))
    gaps = centres[neighbours[:, 1]] - centres[neighbours[:, 0]]
    return diagonals, gaps.tocsr()


def initial_rows(fit: _Fit, v: np.ndarray) -> np.ndarray:
    """(ns,) bool: the sampled surface vertices a body could reach from control vertices v
    (n0, 3), where the fit starts, where rows begin, so that the set (and a large mesh's OSQP
    set-up) seldom changes as the surface moves."""
    member = np.zeros(fit.sub.matrix.shape[0], dtype=bool)
    reach, _ = fit.body_tree3.query((fit.sub.matrix @ v)[fit.sampled_ids] - fit.tree_offset,
                                    distance_upper_bound=REACH)
    member[fit.sampled_ids[np.isfinite(reach)]] = True
    return member


def pair(fit: _Fit, surf: np.ndarray) -> Pairing:
    """Each important body point pulls its closest surface vertex. Body points farther than the
    pull range do not pull (yet): the surface grows towards the bodies from where the designer
    put it, instead of reaching across the scene."""
    surf_tree = cKDTree(surf, leafsize=TREE_LEAF, balanced_tree=False,
                        compact_nodes=False)  # built each time
    gap, nearest = surf_tree.query(fit.b_imp, distance_upper_bound=fit.params.pull_range)
    reached = np.isfinite(gap)
    if not reached.all():  # the energy still counts them, at their nearest surface vertex
        nearest[~reached] = surf_tree.query(fit.b_imp[~reached])[1]
    w_now = np.where(reached, fit.w_imp, 0.0)
    w = np.bincount(nearest, w_now, minlength=len(surf))
    target = np.stack([np.bincount(nearest, w_now * fit.b_imp[:, a], minlength=len(surf))
                       for a in range(3)], axis=1)
    used = w > 0
    target[used] /= w[used, None]
    paired = np.flatnonzero(used)
    return Pairing(nearest, paired, w[paired] / fit.w_imp.sum(), target[paired])


def assemble(fit: _Fit, pairing: Pairing, surf_n: np.ndarray, tau: float
             ) -> tuple[np.ndarray | sp.csr_matrix, np.ndarray]:
    """The quadratic energy of the control vertices x (3 n0, coordinate blocks) as
    x^T H x - 2 g^T x + const: the data terms at the pairing, the smoothness, the fixed and
    anchor pulls and the proximal pull (its linear part is added by the caller, who knows the
    current iterate). Only the paired surface vertices carry data terms: their rows of S (a
    level-s vertex depends on a few control vertices, so on large meshes the blocks stay sparse;
    on small ones dense products are quicker)."""
    n0, s, v0 = fit.n0, fit.sub.matrix, fit.v0
    # (a small mesh's S is kept dense once: its rows are taken at every assembly)
    s_p = fit.sub.kept("fit.dense_matrix", s.toarray)[pairing.paired] if fit.dense else \
        s[pairing.paired]
    w_p, n_p, t_p = pairing.weight, surf_n[pairing.paired], pairing.target
    nt = np.einsum("ij,ij->i", n_p, t_p)  # n . p per paired surface vertex
    blocks = [[None] * 3 for _ in range(3)]
    g = np.zeros(3 * n0)
    if not fit.dense:  # S_p^T diag(c) S_p as (the rows of S_p scaled by c)^T times S_p
        s_csc = s_p.tocsc()
        row_of = np.repeat(np.arange(s_p.shape[0]), np.diff(s_p.indptr))
    for a in range(3):
        for b in range(a, 3):
            c = w_p * (tau * n_p[:, a] * n_p[:, b] + ((1 - tau) if a == b else 0.0))
            blocks[a][b] = (s_p.T * c) @ s_p if fit.dense else \
                sp.csr_matrix((s_p.data * c[row_of], s_p.indices, s_p.indptr),
                              shape=s_p.shape).T @ s_csc
        ga = w_p * ((1 - tau) * t_p[:, a] + tau * n_p[:, a] * nt)
        g[a * n0:(a + 1) * n0] = s_p.T @ ga + fit.fixed * v0[:, a]
        blocks[a][a] = blocks[a][a] + fit.diagonal
    if fit.dense:  # only the upper blocks are read (the lower stay zero)
        h = np.zeros((3 * n0, 3 * n0))
        for a in range(3):
            for b in range(a, 3):
                h[a * n0:(a + 1) * n0, b * n0:(b + 1) * n0] = blocks[a][b]
        return h, g
    return sp.bmat(blocks, format="csr"), g


@dataclass(frozen=True, eq=False)
class Depths:
    """Sampled surface vertices (m of them) against the bodies, what the judged energy needs of
    them: the distance `gap` (m,) to each one's nearest body vertex `nearest` (m,) within
    INSIDE_REACH (inf and 0 beyond it), whether it lies inside a body (`inside`, behind that
    vertex's tangent plane) and how deep (`depth`, 0 outside)."""

    gap: np.ndarray
    nearest: np.ndarray
    inside: np.ndarray
    depth: np.ndarray


def _depths(fit: _Fit, sv: np.ndarray, refused: threading.Event | None = None
            ) -> Depths | None:
    """The `Depths` of sampled surface vertices sv (m, 3): how deep, behind the tangent plane of
    the nearest skin vertex (smooth as the surface slides along the skin, where the distance to
    the nearest vertex would jump by a facet). With `refused`, they are sought DEPTH_CHUNK at a
    time, and None once it is set (`_body_side`)."""
    points, normals = fit.points, fit.normals
    query = sv - fit.tree_offset
    if refused is None:
        gap, nearest = fit.body_tree3.query(query, distance_upper_bound=INSIDE_REACH)
    else:  # (each vertex's search is its own: the same nearest vertices, chunk by chunk)
        gap, nearest = np.empty(len(sv)), np.empty(len(sv), dtype=np.intp)
        for at in range(0, len(sv), DEPTH_CHUNK):
            if refused.is_set():
                return None
            gap[at:at + DEPTH_CHUNK], nearest[at:at + DEPTH_CHUNK] = fit.body_tree3.query(
                query[at:at + DEPTH_CHUNK], distance_upper_bound=INSIDE_REACH)
    outside = nearest == len(points)
    nearest[outside] = 0
    ahead = np.einsum("ij,ij->i", sv - np.take(points, nearest, axis=0),
                      np.take(normals, nearest, axis=0))
    inside = ~outside & (ahead < 0)
    return Depths(gap, nearest, inside, np.where(inside, -ahead, 0.0))


def _facing(fit: _Fit, sv: np.ndarray, sn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For surface vertices sv (k, 3) with normals sn that have a skin vertex within
    CONSTRAINT_RADIUS: the closest body vertex facing each (0 where none is within
    FACING_REACH in the search) and its distance (inf for none)."""
    points = fit.points
    near_s = np.zeros(len(sv), dtype=np.int64)
    dist = np.full(len(sv), np.inf)
    _, facing = fit.body_tree.query(np.concatenate([sv - fit.tree_offset, -FACING_SCALE * sn],
                                                   axis=1), distance_upper_bound=FACING_REACH)
    found = facing < len(points)
    near_s[found] = facing[found]
    dist[found] = np.linalg.norm(points[facing[found]] - sv[found], axis=1)
    return near_s, dist


def _nearest_skin(fit: _Fit, sv: np.ndarray, sn: np.ndarray, skin: np.ndarray | None = None,
                  depths: Depths | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For sampled surface vertices sv (m, 3) with normals sn: the body vertex each stays in
    front of, its distance (inf for a vertex inside a body, constrained however far it is,
    and for one far from every body), whether the surface vertex lies inside a body and how
    deep (behind the tangent plane of its nearest skin vertex, 0 outside). `skin` (m,):
    the body vertices the rows held the vertices to before (-1 for none), kept for the
    vertices now inside a body (so the demand on them does not jump as the surface moves).
    `depths`: the vertices' `Depths` when already known."""
    if depths is None:
        depths = _depths(fit, sv)
    # a surface vertex inside a body (behind its nearest skin vertex) is always constrained,
    # however far the skin it faces: it must get out (no body part is so thick that a point
    # inside it lies farther than INSIDE_REACH from its skin); it leaves through the skin it
    # was held to before it went in or, new to the rows, through the skin facing against the
    # surface's normal
    inside = depths.inside
    # for the others, the closest body vertex facing the surface, sought only where a skin
    # vertex lies within CONSTRAINT_RADIUS: the one it finds lies no nearer than that, so
    # elsewhere (or where the search finds nothing within reach) the surface vertex is far
    # from every body: no row
    near_s = np.zeros(len(sv), dtype=np.int64)
    dist = np.full(len(sv), np.inf)
    reach = np.flatnonzero((depths.gap <= CONSTRAINT_RADIUS) & ~inside)
    near_s[reach], dist[reach] = _facing(fit, sv[reach], sn[reach])
    kept = np.zeros(len(sv), dtype=bool) if skin is None else inside & (skin >= 0)
    if kept.any():
        near_s[kept] = skin[kept]
    new = inside & ~kept
    if new.any():
        _, near_s[new] = fit.exit_tree.query(np.concatenate([sv[new] - fit.tree_offset,
                                                             -EXIT_SCALE * sn[new]], axis=1))
    return near_s, dist, inside, depths.depth


def _beyond_margin(fit: _Fit, depth: np.ndarray) -> float:
    """m^2: the sum of squares of the `depth`s (m,) beyond the margin (and DEPTH_TOLERANCE)."""
    return float(np.sum(np.maximum(0.0, depth - fit.params.margin - DEPTH_TOLERANCE) ** 2))


def _rows(rows: np.ndarray, normals: np.ndarray, demanded: np.ndarray, surf: np.ndarray,
          skin: np.ndarray | None = None, beyond_m2: float = 0.0) -> Rows:
    return Rows(rows, normals, demanded, np.einsum("ij,ij->i", normals, surf[rows]), skin,
                beyond_m2)


def constrain(fit: _Fit, surf: np.ndarray, surf_n: np.ndarray, member: np.ndarray,
              floor_member: np.ndarray | None = None, skin: np.ndarray | None = None,
              depths: Depths | None = None) -> Rows:
    """Non-penetration: each sampled surface vertex near a body (or inside one) stays outside
    the tangent plane at its body vertex, less the margin. Rows join `member` (updated in
    place) and stay, inactive when not wanted (the programme leaves those out). `skin`: the
    body vertices the sampled vertices were held to before (`Rows.skin`), kept for those now
    inside a body. With `floor_member` ((ns,) bool, updated in place) and a floor in the
    parameters, the floor's rows follow (`floor_rows`). `depths`: the sampled vertices'
    `Depths` when already known."""
    ids = fit.sampled_ids
    near_s, dist, inside, depth = _nearest_skin(fit, np.take(surf, ids, axis=0),
                                                np.take(surf_n, ids, axis=0), skin, depths)
    closest = np.zeros(len(surf), dtype=np.int64)
    closest[ids] = near_s
    wanted = np.zeros(len(surf), dtype=bool)
    wanted[ids] = (dist <= CONSTRAINT_RADIUS) | inside
    member |= wanted
    rows = np.flatnonzero(member)
    cn = np.take(fit.normals, closest[rows], axis=0)
    demanded = np.einsum("ij,ij->i", cn, np.take(fit.points, closest[rows], axis=0)) - \
        fit.params.margin
    demanded[~wanted[rows]] = -np.inf
    # a vertex outside every body is in no body, whatever the tangent plane of the skin it
    # faces says (a body is not convex: the plane of a calf's back cuts through the space under
    # the thigh): it may not go further in, but nothing is demanded of it
    inside_row = np.zeros(len(surf), dtype=bool)
    inside_row[ids] = inside
    held = np.where(wanted[ids], near_s, -1)
    body = _rows(rows, cn, demanded, surf, held, _beyond_margin(fit, depth))
    outside = ~inside_row[rows]
    body.demanded[outside] = np.minimum(body.demanded[outside], body.now[outside])
    more = [floor_rows(fit, surf, floor_member)] if floor_member is not None and \
        fit.params.floor is not None else []
    if fit.rim is not None:
        more.append(rim_rows(fit, surf, surf_n))
    if not more:
        return body
    parts = [body] + more
    return Rows(*(np.concatenate([getattr(r, name) for r in parts])
                  for name in ("rows", "normals", "demanded", "now")), held,
                sum(r.beyond_m2 for r in parts))


def floor_rows(fit: _Fit, surf: np.ndarray, member: np.ndarray) -> Rows:
    """The floor: each level-s surface vertex within `FLOOR_REACH` steps of the floor (or
    under it) stays at y >= floor, the y row of S being linear in the control vertices. Rows
    join `member` (updated in place) and stay, inactive when not wanted. Limit
    points are convex combinations of level-s vertices, so the limit surface stays above the
    floor too."""
    floor = float(fit.params.floor)
    rows, under = _floor_members(fit, surf, member)
    normals = np.zeros((len(rows), 3))
    normals[:, 1] = 1.0
    return _rows(rows, normals, np.full(len(rows), floor), surf, beyond_m2=under)


def _floor_members(fit: _Fit, surf: np.ndarray, member: np.ndarray) -> tuple[np.ndarray, float]:
    """`floor_rows`' rows (the vertices near the floor join `member`, in place) and how far
    the surface is under the floor (its `Rows.beyond_m2`), without the rows themselves."""
    floor = float(fit.params.floor)
    height = surf[:, 1]
    member |= height < floor + FLOOR_REACH * fit.params.step
    rows = np.flatnonzero(member)
    return rows, float(np.sum(np.maximum(0.0, floor - np.take(height, rows)) ** 2))


@dataclass(eq=False)
class _Rim:
    """The level-s surface's rim and the unsupported skin it is kept clear of.

    ids : (k,) the sampled surface vertices on the surface's border; `before`, `after` (k,)
    their neighbours along it, in the direction the quads run it. `points` (U, 3): the body
    vertices of the parts no one asked support for that lie within RIM_SPAN of the rim where
    the fit starts; `unnamed` (U,) bool: those of a body region the support does not name at
    all (a calf under a seat; not the skin a named region leaves free, as the thighs' knee
    crease, which may be touched); `member` (2k,) bool: the rim vertices that have had
    clearance rows (the first k) and lid rows (the last k) (they keep them, inactive when not
    wanted, as the body's rows do)."""

    ids: np.ndarray
    before: np.ndarray
    after: np.ndarray
    points: np.ndarray
    unnamed: np.ndarray
    member: np.ndarray
    near: np.ndarray | None = None  # the points within RIM_REACH + RIM_SLACK of the rim ...
    where: np.ndarray | None = None  # ... where it lay when they were found (k, 3)
    near_at: np.ndarray | None = None  # ... their positions (len(near), 3) ...
    near_gap: np.ndarray | None = None  # ... and their distances to it there (len(near),)

    def candidates(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The indices of `points` that may lie within RIM_REACH of the rim at p (k, 3), and
        their positions: of those within RIM_REACH + RIM_SLACK of where it lay when last
        sought (sought again once a rim vertex has moved farther than RIM_SLACK), the ones
        that lay within RIM_REACH plus the farthest any rim vertex has moved since (a point
        within reach of a vertex now lay within reach + that move of it then; right after a
        search, that leaves out more than half of them)."""
        moved = 0.0
        if self.where is not None:
            moved = np.max(np.einsum("ij,ij->i", p - self.where, p - self.where))
        if self.where is None or moved > RIM_SLACK ** 2:
            self.near, self.near_gap = within(self.points, p, RIM_REACH + RIM_SLACK,
                                              distances=True)
            self.near_at = np.take(self.points, self.near, axis=0)
            self.where, moved = p.copy(), 0.0
        # (a hair more, for the rounding of the distances; all of them if a move is no number)
        keep = np.flatnonzero(~(self.near_gap >= RIM_REACH + np.sqrt(moved) + 1e-9))
        return np.take(self.near, keep), np.take(self.near_at, keep, axis=0)


def within(points: np.ndarray, others: np.ndarray, reach: float, distances: bool = False
           ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """The indices (ascending) of `points` (P, 3) nearer than `reach` to one of `others`
    (k, 3): sought only among those within the others' box grown by `reach` (the others are a
    rim, the points the bodies' free skin: on six_overlapping's bench 41 % of it, the heads
    and shoulders, lies outside that box). With `distances`, also the distance of each of
    those points to the nearest of the others."""
    low, high = others.min(axis=0) - reach, others.max(axis=0) + reach
    box = np.flatnonzero((points[:, 0] > low[0]) & (points[:, 0] < high[0]) &
                         (points[:, 1] > low[1]) & (points[:, 1] < high[1]) &
                         (points[:, 2] > low[2]) & (points[:, 2] < high[2]))
    dist, _ = cKDTree(others).query(np.take(points, box, axis=0), distance_upper_bound=reach)
    near = np.flatnonzero(np.isfinite(dist))
    return (np.take(box, near), np.take(dist, near)) if distances else np.take(box, near)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k, 3) the cross products of the rows of a and b (k, 3): `np.cross`'s arithmetic, the
    same to the bit, a third of its time (it is general: axes, broadcasting, two-vectors)."""
    out = np.empty_like(a)
    np.subtract(a[:, 1] * b[:, 2], a[:, 2] * b[:, 1], out=out[:, 0])
    np.subtract(a[:, 2] * b[:, 0], a[:, 0] * b[:, 2], out=out[:, 1])
    np.subtract(a[:, 0] * b[:, 1], a[:, 1] * b[:, 0], out=out[:, 2])
    return out


def _first_largest(group: np.ndarray, value: np.ndarray, count: int) -> np.ndarray:
    """The index of the largest `value` (n,) of each of the groups 0..count - 1 that `group`
    (n,) names (the first of equal ones), ascending by group, for the groups that have one:
    what a stable sort by group and then by value, descending, puts first in each."""
    best = np.full(count, -np.inf)
    np.maximum.at(best, group, value)
    hit = np.flatnonzero(value == np.take(best, group))
    first = np.full(count, len(value))
    np.minimum.at(first, np.take(group, hit), hit)
    return first[first < len(value)]


def _rim_topology(faces: np.ndarray, sampled: np.ndarray) -> tuple:
    """(ids, before, after) of `_Rim` from the level-s quads: the sampled vertices on the
    border (`solver.mesh.boundary_edges`, run as the quads run it), the border vertex
    before each and the one after (a vertex where the border pinches, with more than one of
    each, is left out). The quads wind counter-clockwise seen from their normal, so the
    surface lies left of the border's direction: outwards is (after - before) x n."""
    edges = boundary_edges(faces)
    n = int(faces.max()) + 1
    start, end = np.bincount(edges[:, 0], minlength=n), np.bincount(edges[:, 1], minlength=n)
    after, before = np.full(n, -1), np.full(n, -1)
    after[edges[:, 0]], before[edges[:, 1]] = edges[:, 1], edges[:, 0]
    ids = np.intersect1d(np.flatnonzero((start == 1) & (end == 1)), sampled)
    return ids, before[ids], after[ids]


def _make_rim(sub: Subdivision, sampled: np.ndarray, targets: Sequence[SupportedBody],
              control: np.ndarray, member: np.ndarray | None = None) -> "_Rim | None":
    """The fit's `_Rim`, None when every body part is to be supported or the surface has no
    border; `member`: the rim vertices that had rows in a fit before (of the same quads),
    which keep them."""
    free, unnamed = [], []
    for t in targets:
        if t.supported is None:
            continue
        supported = np.asarray(t.supported, dtype=bool)
        free.append(t.vertices[~supported])
        unnamed.append(np.ones(len(free[-1]), dtype=bool) if t.regions is None else
                       ~np.isin(t.regions[~supported], t.regions[supported]))
    points = np.concatenate(free) if free else np.zeros((0, 3))
    if not len(points):
        return None
    ids, before, after = sub.kept("fit.rim", lambda: _rim_topology(sub.faces, sampled))
    if not len(ids):
        return None
    kept = within(points, (sub.matrix @ control)[ids], RIM_SPAN)
    return _Rim(ids, before, after, points[kept], np.concatenate(unnamed)[kept],
                member.copy() if member is not None and len(member) == 2 * len(ids) else
                np.zeros(2 * len(ids), dtype=bool))


def rim_rows(fit: _Fit, surf: np.ndarray, surf_n: np.ndarray) -> Rows:
    """The rim: no rim vertex (`_Rim`) comes nearer than RIM_CLEARANCE (plus RIM_SLANT of how
    deep the skin lies) to unsupported skin that lies in the surface's foam (up to RIM_SLAB
    behind it) or just in front of it (RIM_FRONT), from outside or up to RIM_INNER inside
    the rim: e . v <= e . b - clearance, for the skin point b of each rim vertex that asks the
    most of it (among the points that have it as their nearest rim vertex: skin is sampled
    about as densely as the rim, 1-2 cm apart), e the rim's outward direction (in the
    surface's tangent plane, across the border). A row already
    broken holds the rim where it is (like a body row outside every body: nothing more is
    demanded), so the rows only keep the rim from advancing over the calves, and the fit is
    judged as without them. The rows fade (scaled by a weight, 0 to 1) at the edges of the
    region so that they do not jump as the surface moves.

    Those rows hold the rim beside the skin, not under it: a rim that rises or swings can pass
    over skin in front of it within one step and leave it in the foam. So skin of a region the
    support does not name (`_Rim.unnamed`) that lies up to LID_FRONT in front of the surface,
    from RIM_INNER inside the rim to LID_OUT beyond it, also gets a lid row on its nearest rim
    vertex: n . v <= n . b - LID_CLEAR (the rim stays behind it along the rim's normal n), the
    nearest such point's; a lid row already broken holds the rim where it is. Both kinds join
    `fit.rim.member` and stay (inactive when not wanted), as the body's rows do."""
    rim = fit.rim
    p, n = np.take(surf, rim.ids, axis=0), np.take(surf_n, rim.ids, axis=0)
    e = _cross(np.take(surf, rim.after, axis=0) - np.take(surf, rim.before, axis=0),
               n)  # outwards (`_rim_topology`)
    e /= np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-300)
    # each skin point to its nearest rim vertex within reach
    near, near_at = rim.candidates(p)
    dist, owner = cKDTree(p).query(near_at, distance_upper_bound=RIM_REACH)
    found = np.flatnonzero(np.isfinite(dist))
    point, owner = np.take(near, found), np.take(owner, found)
    k = len(rim.ids)
    demanded, lid = np.full(k, -np.inf), np.full(k, -np.inf)
    scale = np.ones(k)
    if len(point):
        b = np.take(near_at, found, axis=0)  # those skin points (m, 3)
        d = b - np.take(p, owner, axis=0)
        n_o = np.take(n, owner, axis=0)
        behind = -np.einsum("ij,ij->i", d, n_o)
        out = np.einsum("ij,ij->i", d, np.take(e, owner, axis=0))
        over = np.flatnonzero(np.take(rim.unnamed, point) & (behind < 0) &
                              (behind > -LID_FRONT) & (out > -RIM_INNER) & (out < LID_OUT))
        if len(over):  # the row -n . v >= -n . b + LID_CLEAR of the point nearest in front
            np.maximum.at(lid, np.take(owner, over), LID_CLEAR - np.einsum(
                "ij,ij->i", np.take(n_o, over, axis=0), np.take(b, over, axis=0)))
        # how much each point counts, fading to nothing at the edges of the region the rim
        # answers for (so that its row does not jump as the surface moves)
        weight = np.clip((behind + RIM_FRONT) / RIM_FRONT, 0.0, 1.0) * \
            np.clip((RIM_SLAB - behind) / RIM_FADE, 0.0, 1.0) * \
            np.clip((out + RIM_INNER) / (RIM_INNER / 2), 0.0, 1.0)
        wanted = np.flatnonzero(weight > 0)
        if len(wanted):
            # per rim vertex its point of largest weighted shortfall: the row
            # w (-e . v) >= w (clearance - e . b)
            owner, behind, out, weight = (np.take(x, wanted)
                                          for x in (owner, behind, out, weight))
            clear = RIM_CLEARANCE + RIM_SLANT * np.maximum(behind, 0.0)
            top = _first_largest(owner, weight * (clear - out), k)
            owner, weight = np.take(owner, top), np.take(weight, top)
            scale[owner] = weight
            demanded[owner] = weight * (np.take(clear, top) - np.einsum(
                "ij,ij->i", np.take(e, owner, axis=0), np.take(b, wanted[top], axis=0)))
    demanded = np.concatenate([demanded, lid])
    rim.member |= np.isfinite(demanded)
    normals = np.concatenate([-scale[:, None] * e, -n])
    now = np.einsum("ij,ij->i", normals, np.concatenate([p, p]))
    keep = np.flatnonzero(rim.member)
    return Rows(np.take(rim.ids, keep % k), np.take(normals, keep, axis=0),
                np.take(np.minimum(demanded, now), keep), np.take(now, keep))


@dataclass(frozen=True, eq=False)
class ExtraRows:
    """Rows on points of the limit surface between its vertices: `points` (k, n0) maps the
    control vertices to them (barycentric on limit points), each held in front of the plane
    of the skin it was found behind, `normals` (k, 3), less the margin: n . p >= `demanded`."""

    points: sp.csr_matrix
    normals: np.ndarray
    demanded: np.ndarray


def limit_points(fit: _Fit, v: np.ndarray) -> np.ndarray:
    """(ns, 3) the limit points of the level-s vertices of control vertices v (n0, 3) (their
    map built once a fit, when first asked for)."""
    from solver.surface.limit import limit_matrix

    if fit.limit is None:
        fit.limit = limit_matrix(fit.n0, fit.faces, fit.params.level,
                                 list(fit.params.creases) or None)
    return fit.limit @ v


def deep_samples(fit: _Fit, v: np.ndarray) -> ExtraRows | None:
    """Rows for the places where the limit surface of control vertices v (n0, 3) lies deeper
    in a body than the margin less REPAIR_SAFETY between its vertices: over the barycentric
    samples of every level-s triangle (the grid `guarantees.surface_guarantees` checks first;
    it searches a finer one where a cut past the bar could lie between them, which these rows
    do not see: REPAIR_SAFETY keeps them 2 mm inside the margin), the
    deepest of each triangle that a body's winding number puts inside it, held in front of the
    plane of the skin triangle nearest to it. None where there is no such place (or no closed
    skin to look in)."""
    from solver.mesh import face_normals
    from solver.surface.guarantees import barycentric_weights

    if not fit.skins:
        return None
    limit = limit_points(fit, v)
    triangles = fit.sub.triangles
    weights = barycentric_weights()  # (S, 3)
    allowed = fit.params.margin - REPAIR_SAFETY
    # only triangles with a corner inside a body, deeper than `allowed` less a centimetre
    # (behind its nearest skin vertex's plane), can hold a sample deeper than `allowed`
    # between their corners (a facet's sag is far less); the exact tests look at those
    gap, nearest = fit.body_tree3.query(limit - fit.tree_offset,
                                        distance_upper_bound=INSIDE_REACH)
    near = np.isfinite(gap)
    nearest[~near] = 0
    behind = -np.einsum("ij,ij->i", limit - fit.points[nearest], fit.normals[nearest])
    corner_deep = near & (behind > allowed - SAG_ALLOWANCE)
    candidates = np.flatnonzero(corner_deep[triangles].any(axis=1))
    if not len(candidates):
        return None
    points = np.einsum("sk,fkd->fsd", weights, limit[triangles[candidates]]).reshape(-1, 3)
    # a sample within `allowed` of a skin vertex lies no deeper than that in its body: only
    # the others need the exact (and costlier) tests of that body (the nearest vertex's body
    # is spared them; any other body, rarely as near, is tested)
    _, vertex = fit.body_tree3.query(points - fit.tree_offset, distance_upper_bound=allowed)
    sample = np.flatnonzero(vertex < len(fit.points))
    vertex = vertex[sample]
    found: dict[int, tuple[float, int, np.ndarray, np.ndarray]] = {}
    for skin in fit.skins:
        body_v, body_t = skin.vertices, skin.triangles
        lo, hi = body_v.min(axis=0), body_v.max(axis=0)
        shallow = np.zeros(len(points), dtype=bool)
        shallow[sample[(vertex >= skin.stack.start) & (vertex < skin.stack.stop)]] = True
        near = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1) & ~shallow)
        if len(near):
            near = near[skin.winding(points[near]) > 0.5]
        if not len(near):
            continue
        dist2, face, closest = skin.closest(points[near])
        depth = np.sqrt(dist2)
        deep = depth > allowed
        normals = face_normals(body_v, body_t[face[deep]])
        for k, dk, n, c in zip(near[deep], depth[deep], normals, closest[deep]):
            tri = int(candidates[k // len(weights)])
            if tri not in found or dk > found[tri][0]:
                found[tri] = (float(dk), int(k % len(weights)), n, c)
    if not found:
        return None
    tris = np.fromiter(found, dtype=np.int64)
    on_limit = sp.csr_matrix((np.concatenate([weights[found[t][1]] for t in tris]),
                              (np.repeat(np.arange(len(tris)), 3), triangles[tris].ravel())),
                             shape=(len(tris), len(limit)))
    normals = np.array([found[t][2] for t in tris])
    plane = np.einsum("ij,ij->i", normals, np.array([found[t][3] for t in tris]))
    return ExtraRows((on_limit @ fit.limit).tocsr(), normals, plane - allowed)


def add_extra_rows(fit: _Fit, extra: ExtraRows) -> None:
    """Joins `extra` to the fit's rows on samples (after the level-s vertices in the
    programme's point map) and sets the programme up for them."""
    if fit.extra is not None:
        extra = ExtraRows(sp.vstack([fit.extra.points, extra.points]).tocsr(),
                          np.concatenate([fit.extra.normals, extra.normals]),
                          np.concatenate([fit.extra.demanded, extra.demanded]))
    fit.extra = extra
    programme = (DenseProgramme if fit.dense else Programme)(
        sp.vstack([fit.sub.matrix, extra.points]).tocsr(), fit.lap, fit.n0,
        fit.programme.slack_weight)
    programme.setups = fit.programme.setups  # the fit counts them all
    fit.programme = programme


def _with_extra(fit: _Fit, v: np.ndarray, rows: Rows) -> Rows:
    """`rows` followed by the fit's rows on samples (if any), whose shortfall beyond
    DEPTH_TOLERANCE joins `beyond_m2`."""
    if fit.extra is None:
        return rows
    e = fit.extra
    now, short = _extra_now(fit, v)
    ids = fit.sub.matrix.shape[0] + np.arange(len(now))
    return Rows(np.concatenate([rows.rows, ids]), np.concatenate([rows.normals, e.normals]),
                np.concatenate([rows.demanded, e.demanded]), np.concatenate([rows.now, now]),
                rows.skin, rows.beyond_m2 + short)


def _extra_now(fit: _Fit, v: np.ndarray) -> tuple[np.ndarray, float]:
    """The fit's rows on samples (`fit.extra`, not None) at control vertices v (n0, 3): n . p
    now (k,) and the sum of squares of their shortfall beyond DEPTH_TOLERANCE (m^2)."""
    e = fit.extra
    now = np.einsum("ij,ij->i", e.normals, e.points @ v)
    short = np.maximum(0.0, e.demanded - now - DEPTH_TOLERANCE)
    return now, float(np.sum(short ** 2))


def _out_of_bounds(fit: _Fit, v: np.ndarray, surf: np.ndarray, surf_n: np.ndarray,
                   member: np.ndarray, floor_member: np.ndarray | None = None
                   ) -> tuple[Depths, float]:
    """What the judgement needs of the rows of control vertices v (n0, 3) with level-s surface
    `surf` and normals `surf_n`, without the rows themselves (`constrain` and `_with_extra`
    make them, for an iterate that is accepted): the sampled vertices' `Depths` and how far the
    surface is out of bounds (`Rows.beyond_m2`, the same sum). The vertices that `constrain`
    would add to `member` and `floor_member` join them (in place) all the same. (Only the
    floor's members change what a step solves: a body row is wanted, with a finite bound, only
    where the iterate it is made for wants it, and the programme takes no other.)"""
    ids = fit.sampled_ids
    sv = np.take(surf, ids, axis=0)
    depths = _depths(fit, sv)
    # a vertex inside a body is wanted; one outside, when its facing skin is near enough (only
    # those not in the rows yet are sought: the others stay in them anyway)
    joining = np.flatnonzero(~member[ids] & ~depths.inside & (depths.gap <= CONSTRAINT_RADIUS))
    member[ids[depths.inside]] = True
    if len(joining):
        _, dist = _facing(fit, sv[joining], surf_n[ids[joining]])
        member[ids[joining[dist <= CONSTRAINT_RADIUS]]] = True
    return depths, _beyond(fit, v, surf, depths, floor_member)


def _beyond(fit: _Fit, v: np.ndarray, surf: np.ndarray, depths: Depths,
            floor_member: np.ndarray | None) -> float:
    """m^2: how far control vertices v (n0, 3) with level-s surface `surf` and its sampled
    vertices' `depths` are out of bounds (`Rows.beyond_m2`); the vertices near the floor join
    `floor_member` (in place)."""
    beyond = _beyond_margin(fit, depths.depth)
    if floor_member is not None and fit.params.floor is not None:
        beyond = beyond + _floor_members(fit, surf, floor_member)[1]
    if fit.extra is not None:
        beyond = beyond + _extra_now(fit, v)[1]
    return beyond


@dataclass(frozen=True, eq=False)
class Iterate:
    """A control mesh v (n0, 3) as the loop judges it: its level-s surface and normals, its
    own pairing and rows, the energy's parts and its largest fold.

    The judged energy at blend tau is ``(1 - tau) point + tau plane + rest`` plus the cost of
    the surface's depth beyond the margin and under the floor (`energy`): the programme's own
    objective (without the proximal pull) with each body point at its nearest surface vertex
    and the cost of unmet rows measured on the surface itself (`Rows.beyond_m2`).
    Since n . d never exceeds |d|, it cannot rise when tau does: an iterate accepted only if it
    lowers the energy at the step's tau keeps the sequence of judged energies non-increasing.
    """

    v: np.ndarray
    surf: np.ndarray
    surf_n: np.ndarray
    pairing: Pairing
    rows: Rows | None  # None until the iterate is accepted (`with_rows`)
    point: float  # m^2, importance-weighted mean squared distance to the nearest vertex
    plane: float  # m^2, the same along the surface normal
    rest: float  # smoothness and the pulls to the start
    unmet: float  # m^2, `Rows.beyond_m2`
    max_fold: float  # degrees between neighbouring level-s quads (creases left out)
    min_ridge: float  # metres, the tightest radius where the surface bends away from bodies
    slack_weight: float
    depths: Depths | None = None  # the sampled vertices' (the rows start from them)
    ahead: tuple | None = None  # (tau, `assemble` at it): the next step's quadratic, when made
    # while the rows were (`assess`; the loop takes it and drops it)

    def energy(self, tau: float) -> float:
        return (1 - tau) * self.point + tau * self.plane + self.rest + \
            self.slack_weight * self.unmet


def assess(fit: _Fit, v: np.ndarray, member: np.ndarray,
           floor_member: np.ndarray | None = None, skin: np.ndarray | None = None,
           rows: bool = True, ceiling: tuple[float, float] | None = None,
           ahead: float | None = None) -> Iterate:
    """The `Iterate` of control vertices v (n0, 3): subdivides, pairs, constrains (rows join
    `member` and `floor_member` in place; `skin` as `constrain` takes it) and measures the
    energy's parts and the folds. Without `rows`, the iterate is judged without its rows (the
    loop's candidates: most are accepted), which `with_rows` adds. With `ceiling` (tau, energy),
    a candidate whose energy at tau exceeds that energy before its depths are counted (they
    only add to it) is refused then: its `unmet` is inf and its bends are not measured (the
    floor's rows it reaches join `floor_member` all the same; of the body's members, which
    change no step, it may add some or none).

    With the fit's `pool` (`overlapped`), the depths and rows (`_body_side`) are made on the
    pool's thread while this one pairs, measures and, given `ahead` (the next step's tau),
    assembles the next step's quadratic (`Iterate.ahead`) and has the programme factor it
    (`DenseProgramme.prepare`): an iterate that is not refused early comes with its rows
    whatever `rows` says (the loop accepts most candidates). Accepted iterates and steps are
    the same as made in turn, bit for bit; the members of rows that are not wanted (those of
    the body and the rim) may differ, and change nothing."""
    surf = fit.sub.matrix @ v
    surf_n = fit.sub.normals(surf)
    side, refused = None, None
    if fit.pool is not None:
        refused = threading.Event()
        side = fit.pool.submit(_body_side, fit, v, surf, surf_n, member, floor_member, skin,
                               refused)
    try:
        pairing = pair(fit, surf)
        diff = fit.b_imp - np.take(surf, pairing.pair, axis=0)
        total = max(fit.w_imp.sum(), 1e-300)
        point = float(fit.w_imp @ np.einsum("ij,ij->i", diff, diff) / total)
        plane = float(fit.w_imp @ np.einsum("ij,ij->i", diff,
                                            np.take(surf_n, pairing.pair, axis=0)) ** 2 /
                      total)
        smooth = float(sum(v[:, a] @ (fit.smooth @ v[:, a]) for a in range(3)))
        pulls = float(np.sum(fit.fixed[:, None] * (v - fit.v0) ** 2))
        rest = smooth + pulls
        if ceiling is not None and not rows:
            tau, most = ceiling
            # `Iterate.energy` adds its last term to this very sum: it cannot come out less
            if (1 - tau) * point + tau * plane + rest > most:
                if side is not None:
                    refused.set()
                    side.result()  # (its floor rows join as below)
                elif floor_member is not None and fit.params.floor is not None:
                    floor_rows(fit, surf, floor_member)
                return Iterate(v, surf, surf_n, pairing, None, point, plane, rest,
                               np.inf, 0.0, np.inf, fit.programme.slack_weight)
        fold, ridge = _bends(fit, surf)
        if side is None:
            depths, unmet = _out_of_bounds(fit, v, surf, surf_n, member, floor_member)
            it = Iterate(v, surf, surf_n, pairing, None, point, plane, rest, unmet,
                         fold, ridge, fit.programme.slack_weight, depths)
            return with_rows(fit, it, member, floor_member, skin) if rows else it
        quadratic = None
        if ahead is not None:
            quadratic = (ahead, assemble(fit, pairing, surf_n, ahead))
            if fit.dense:  # the next step's programme factored too (a step that stiffens it
                # factors its own)
                fit.programme.prepare(2 * _stiffer(fit, quadratic[1][0]))
    except BaseException:
        if side is not None:  # (it writes to the rows' members: done before they are read)
            refused.set()
            wait([side])  # (this thread's error is the one raised)
        raise
    depths, unmet, body_rows = side.result()
    return Iterate(v, surf, surf_n, pairing, body_rows, point, plane, rest, unmet,
                   fold, ridge, fit.programme.slack_weight, depths, quadratic)


def _body_side(fit: _Fit, v: np.ndarray, surf: np.ndarray, surf_n: np.ndarray,
               member: np.ndarray, floor_member: np.ndarray | None, skin: np.ndarray | None,
               refused: threading.Event) -> tuple[Depths | None, float, Rows | None]:
    """What `assess` makes on the pool's thread: the sampled vertices' `Depths`, how far the
    surface is out of bounds (`_beyond`) and its rows (`with_rows`, whose members include
    those `_out_of_bounds` adds), these last unless `refused` is set once the depths are known
    (None then). Refused while the depths are sought, it leaves them (None, and inf for how
    far out of bounds) and only the vertices near the floor join `floor_member`: `assess`
    waits for no more (on six_overlapping's bench it waited 1-6 ms for the rest of each
    refused candidate's depths, now under one)."""
    depths = _depths(fit, np.take(surf, fit.sampled_ids, axis=0), refused)
    if depths is None:
        if floor_member is not None and fit.params.floor is not None:
            _floor_members(fit, surf, floor_member)
        return None, np.inf, None
    unmet = _beyond(fit, v, surf, depths, floor_member)
    if refused.is_set():
        return depths, unmet, None
    return depths, unmet, _rows_at(fit, v, surf, surf_n, member, floor_member, skin, depths)


def with_rows(fit: _Fit, it: Iterate, member: np.ndarray,
              floor_member: np.ndarray | None = None, skin: np.ndarray | None = None
              ) -> Iterate:
    """`it` with its rows (`constrain`, then the rows on samples): for the members that the
    iterate's assessment left in `member` and `floor_member`."""
    return replace(it, rows=_rows_at(fit, it.v, it.surf, it.surf_n, member, floor_member, skin,
                                     it.depths))


def _rows_at(fit: _Fit, v: np.ndarray, surf: np.ndarray, surf_n: np.ndarray,
             member: np.ndarray, floor_member: np.ndarray | None, skin: np.ndarray | None,
             depths: Depths | None) -> Rows:
    """The rows of control vertices v (n0, 3) with level-s surface `surf`, normals `surf_n`
    and its sampled vertices' `depths`: `constrain`'s, then the rows on samples."""
    return _with_extra(fit, v, constrain(fit, surf, surf_n, member, floor_member, skin, depths))


def _bends(fit: _Fit, surf: np.ndarray) -> tuple[float, float]:
    """The largest angle (degrees) between neighbouring level-s quads of surface `surf`
    (ns, 3), creases left out, and the tightest radius (m) of its ridges (inf without a ridge):
    the extremes of `_bend_pairs`, with the angles taken only where they are needed (the
    largest angle is that of the least cosine)."""
    if not len(fit.neighbours):
        return 0.0, np.inf
    cosine, gap, ridge = _bend_parts(fit, surf)
    fold = float(np.degrees(np.arccos(np.clip(cosine.min(), -1.0, 1.0))))
    _, radii = _ridge_radii(cosine, gap, ridge)
    return fold, float(radii.min()) if len(radii) else np.inf


def _ridge_radii(cosine: np.ndarray, gap: np.ndarray, ridge: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Of `_bend_parts`' pairs: those that make a ridge and bend (by more than 1e-6 rad), and
    the radius of each, the distance between the quads' centres over the angle between them
    (the angles taken for those pairs only)."""
    pairs = np.flatnonzero(ridge)
    angle = np.arccos(np.clip(np.take(cosine, pairs), -1.0, 1.0))
    bent = angle > 1e-6
    return pairs[bent], np.linalg.norm(np.take(gap, pairs[bent], axis=0), axis=1) / angle[bent]


def _bend_parts(fit: _Fit, surf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pair of neighbouring level-s quads (`fit.neighbours`) of surface `surf` (ns, 3):
    the cosine of the angle between their normals (`quad_normals`: the cross product of their
    diagonals, which `fit.quad_maps` gives), the gap between their centres and whether they
    may make a ridge (each quad's centre lies behind its neighbour's plane; `_bend_pairs`)."""
    diagonals, centre_map = fit.quad_maps
    both = diagonals @ surf
    n = np.cross(both[:len(both) // 2], both[len(both) // 2:])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    pairs = np.take(n, fit.neighbours, axis=0)  # (E, 2, 3) (quicker than indexing twice)
    n_a, n_b = pairs[:, 0], pairs[:, 1]
    gap = centre_map @ surf
    ridge = (np.einsum("ij,ij->i", gap, n_a) < 0) & (np.einsum("ij,ij->i", gap, n_b) > 0)
    return np.einsum("ij,ij->i", n_a, n_b), gap, ridge


def _bend_pairs(fit: _Fit, surf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pair of neighbouring level-s quads (`fit.neighbours`) of surface `surf` (ns, 3):
    the angle (radians) between them and the radius (m) of the ridge they
    make where the surface bends away from the bodies (each quad's centre lies behind its
    neighbour's plane), the distance between their centres over that angle (inf where they
    make no ridge)."""
    cosine, gap, ridge = _bend_parts(fit, surf)
    pairs, radii = _ridge_radii(cosine, gap, ridge)
    radius = np.full(len(cosine), np.inf)
    radius[pairs] = radii
    return np.arccos(np.clip(cosine, -1.0, 1.0)), radius


def _bent_controls(fit: _Fit, it: Iterate, candidate: Iterate) -> np.ndarray:
    """(n0,) bool: the control vertices that shape the level-s quads where `candidate` folds
    or ridges past what `acceptable` allows after `it`."""
    angle, radius = _bend_pairs(fit, candidate.surf)
    bad = (np.degrees(angle) > max(FOLD_GUARD_DEG, it.max_fold)) | \
        (radius < min(fit.params.min_ridge_radius, it.min_ridge))
    quads = np.unique(fit.neighbours[bad].ravel())
    corners = np.unique(fit.sub.faces[quads].ravel())
    shaping = np.zeros(fit.n0, dtype=bool)
    shaping[fit.sub.matrix[corners].indices] = True
    return shaping


def terms_of(fit: _Fit, it: Iterate, tau: float) -> dict:
    """The energy's parts of an iterate at blend tau (a report's figures)."""
    smooth = float(sum(it.v[:, a] @ (fit.smooth @ it.v[:, a]) for a in range(3)))
    return {"point_to_point_m2": it.point, "point_to_plane_m2": it.plane,
            "smoothness": smooth, "fixed": it.rest - smooth, "tau": tau,
            "out_of_bounds_m2": it.unmet,
            "laplacian_m2": float(np.mean(np.sum((fit.lap @ it.v) ** 2, axis=1))),
            "max_fold_deg": it.max_fold,
            "min_ridge_radius_m": it.min_ridge if np.isfinite(it.min_ridge) else None}


def _settled_ahead(gains: Sequence[float], energy: float, tolerance: float) -> bool:
    """Whether the steps to come, if each lowers the energy by the same fraction of the one
    before as the last did of its own (a geometric series), would lower `energy` by less
    than `tolerance` (relative) in all."""
    if len(gains) < 2 or not 0 < gains[-1] < gains[-2]:
        return False
    ratio = gains[-1] / gains[-2]
    return gains[-1] * ratio / (1 - ratio) < tolerance * energy


def converged(energies: Sequence[float], tolerance: float) -> bool:
    """Whether the best energy after the tau ramp has not improved by `tolerance` (relative)
    in the last PATIENCE iterations."""
    post = energies[TAU_RAMP:]
    return len(post) > PATIENCE and min(post) > min(post[:-PATIENCE]) * (1 - tolerance)


def _stiffened(fit: _Fit, quadratic: tuple, v: np.ndarray | None = None) -> tuple:
    """The quadratic (H, g) of `assemble` with the surface made stiffer where earlier
    proposals folded: sum_j stiff_j |(L V)_j|^2 (smoother there), or with control vertices v
    (n0, 3) given, sum_j stiff_j |(L (V - v))_j|^2 (the step bends less there; staying costs
    nothing, so the proposal still lowers the programme's objective). Only proposals see it:
    steps are judged by the energy itself."""
    if fit.stiff is None or not fit.stiff.any():
        return quadratic
    h, g = quadratic
    if v is not None:
        g = g + (_stiffness(fit)[0] @ v).T.reshape(-1)  # x^T K x - 2 (K v)^T x: the bending
    return _stiffer(fit, h), g


def _stiffness(fit: _Fit) -> tuple:
    """K = L^T diag(stiff) L (sparse) and, for a dense Hessian, K as an array: made once per
    raise of `fit.stiff`."""
    if fit.stiff_matrix is None or not np.array_equal(fit.stiff_matrix[0], fit.stiff):
        extra = (fit.lap.T @ sp.diags(fit.stiff) @ fit.lap).tocsr()
        fit.stiff_matrix = (fit.stiff.copy(), extra, extra.toarray() if fit.dense else None)
    return fit.stiff_matrix[1:]


def _stiffer(fit: _Fit, h):
    """`_stiffened`'s Hessian: `assemble`'s h with K on each coordinate block (h itself
    without stiffness)."""
    if fit.stiff is None or not fit.stiff.any():
        return h
    extra, block = _stiffness(fit)
    if fit.dense:
        h, n0 = h.copy(), fit.n0
        for a in range(3):
            h[a * n0:(a + 1) * n0, a * n0:(a + 1) * n0] += block
        return h
    return (h + sp.kron(sp.identity(3), extra)).tocsr()


def propose(fit: _Fit, it: Iterate, radius: float, quadratic
            ) -> tuple[np.ndarray, str, float]:
    """One step from iterate `it`: the programme at its pairing and rows, within a trust
    region of `radius` metres per coordinate. Returns the new control vertices (n0, 3),
    the solver's status and the largest row residual (m). `quadratic`: the (H, g) of `assemble`
    for this iterate at the step's tau."""
    h, g = quadratic
    x0 = it.v.T.reshape(-1)
    g = g + fit.proximal * x0  # the proximal pull to the current iterate
    try:
        x, status, residual = fit.programme.solve(2 * h, -2 * g, it.rows.rows, it.rows.normals,
                                                  it.rows.bound(radius), x0, radius)
    except ProgrammeError as exc:
        raise FitError(str(exc)) from None
    return x.reshape(3, fit.n0).T, status, residual


def acceptable(fit: _Fit, it: Iterate, candidate: Iterate, tau: float) -> str | None:
    """Why `candidate` may not follow `it` (None if it may): its judged energy at tau must not
    rise, it must not fold more than FOLD_GUARD_DEG or than `it` does, and its ridges must
    not bend tighter than the `min_ridge_radius` parameter or than `it`'s do."""
    if candidate.energy(tau) > it.energy(tau):
        return "energy"
    if candidate.max_fold > max(FOLD_GUARD_DEG, it.max_fold):
        return "fold"
    if candidate.min_ridge < min(fit.params.min_ridge_radius, it.min_ridge):
        return "ridge"
    return None


def _flaws(fit: _Fit, v: np.ndarray) -> int:
    """What would keep the limit surface of control vertices v (what `surface.*` holds) from
    being furniture: its pairs of triangles that cross (`_crossings`) and its neighbouring
    triangles that fold further apart than the guarantees' FOLD_LIMIT_DEG (`_triangle_folds`:
    the loop's own guard measures the level-s quads, between whose corners the limit surface
    can bend further). A surface with a coordinate that is not a number is all flaw (one per
    triangle): no test can clear it."""
    limit = limit_points(fit, v)
    if not np.all(np.isfinite(limit)):
        return len(fit.sub.triangles)
    return _crossings(fit, limit) + _triangle_folds(fit, limit)


def _triangle_folds(fit: _Fit, limit: np.ndarray) -> int:
    """Pairs of triangles of the limit surface `limit` (ns, 3) (the quads split as
    `surface.*` is) that share an edge that is no crease, with normals further apart than
    FOLD_LIMIT_DEG, or with a normal that is not a number (a triangle shrunk to a point's
    normal is zero, which counts as a right angle)."""
    from solver.mesh import face_normals

    sub, creases = fit.sub, fit.params.creases
    pairs = sub.kept("fit.triangle_neighbours", lambda: neighbour_faces(
        sub.triangles, sub.steps[-1].creases if sub.steps else
        (np.asarray(creases).reshape(-1, 2) if creases else None)))
    n = face_normals(limit, sub.triangles)
    dots = np.einsum("ij,ij->i", n[pairs[:, 0]], n[pairs[:, 1]])
    return int(np.sum(~(dots >= np.cos(np.radians(FOLD_LIMIT_DEG)))))


def _crossings(fit: _Fit, limit: np.ndarray) -> int:
    """Crossing triangle pairs of the limit surface `limit` (ns, 3): none for a disk that lies
    one-to-one over a plane (`one_to_one_over_plane`, a seat or a bench), else as
    `crossing_pairs` counts them (by pieces that are)."""
    from solver.surface.guarantees import crossing_pairs, disk_border, one_to_one_over_plane

    border = fit.sub.kept("disk_border", lambda: disk_border(fit.sub.faces, len(limit)))
    if border is not None and one_to_one_over_plane(limit, fit.sub.triangles, border):
        return 0
    # (the one thing kept with the operator that is written to: a cache of the pieces'
    # topology, `crossing_pairs`' own, which it bounds)
    return len(crossing_pairs(limit, fit.sub.triangles, whole_tried=True,
                              pieces=fit.sub.kept("fit.crossing_pieces", dict)))


def uncrossed(fit: _Fit, accepted: Sequence[np.ndarray]) -> tuple[int, int]:
    """The last of the accepted control meshes whose limit surface does not cross itself (nor
    folds past FOLD_LIMIT_DEG), and the flaws of the last one: the one before the last when
    that is clean (the last step is most often the only one that crossed), else by bisection
    (a surface that starts crossing itself seldom stops). Returns (index, flaws of the last);
    the last index when it is clean, and 0 when even the start crosses; (0, 0) for the start
    alone, unchecked (there is nothing to choose from)."""
    last = len(accepted) - 1
    if last == 0:  # the start alone (a fit cancelled before its first step): nothing to choose
        return 0, 0
    crossings = _flaws(fit, accepted[last])
    if crossings == 0:
        return last, crossings
    if _flaws(fit, accepted[last - 1]) == 0:
        return last - 1, crossings
    if last == 1 or _flaws(fit, accepted[0]):
        return 0, crossings
    good, bad = 0, last - 1
    while bad - good > 1:
        mid = (good + bad) // 2
        if _flaws(fit, accepted[mid]):
            bad = mid
        else:
            good = mid
    return good, crossings


@with_limited_threads  # small products: one BLAS thread (SITRELAX_THREADS), see solver.threads
def fit_surface(control: np.ndarray, faces: np.ndarray, targets: Sequence[SupportedBody],
                params: FitParams = FitParams(),
                progress: Callable[[int, float, float], None] | None = None, *,
                warm: FitResult | None = None, cancel: Callable[[], bool] | None = None,
                iterates: Callable[[int, np.ndarray, np.ndarray], None] | None = None
                ) -> FitResult:
    """Fits the control mesh to the bodies (see the module docstring): each iteration proposes
    a step (pair, assemble, constrain, solve) and accepts it only if it lowers the judged
    energy and folds no further, or tries again half as long; the result is the
    last accepted iterate whose surface does not cross itself.

    A warm refit (`warm`, the result of an earlier fit of the same control mesh, after a person
    moved or a control vertex was edited) starts from that result's control vertices (each
    moved as far as the designer moved it in `control` since) at tau_max, reuses what still
    holds (the limit map, the rows, the bodies' search trees when they did not move) and stops
    as soon as the surface is settled: once an accepted step lowers the judged energy by less
    than `tolerance` (relative), or the last two steps' gains shrink so fast that all the
    steps to come, going on so, would lower it by less than that (`_settled_ahead`). The
    vertices it held still for a fold stay held in its next iteration. The energy is the cold fit's
    own: the pulls still hold the control vertices to `control`, the designer's start.

    Parameters
    ----------
    control : (n0, 3) float
        Start control vertices, metres.
    faces : (F0, 4) int
        The control mesh's quads.
    targets : sequence of SupportedBody
        The bodies to support (vertices in metres, unit normals, importance; their triangles
        unused).
    params : FitParams, optional
        Subdivision level, weights, softness margin (metres), fixed vertices, creases, stopping
        rule and per-iteration step (metres).
    progress : callable, optional
        Called after every accepted iteration as ``progress(iteration, energy, tau)``.
    warm : FitResult, optional
        An earlier fit of a control mesh with the same vertex count and quads to start from.
    cancel : callable, optional
        Polled between iterations; when it returns True the fit ends early with the last
        accepted iterate (the best so far) and a `stop_reason` that begins with "cancelled".
        One with a `deadline` attribute (a `time.monotonic()` value) also ends the solve of a
        large programme (seconds each) running at that time.
    iterates : callable, optional
        Called after every accepted iteration as ``iterates(iteration, control, surface)``
        with that iterate's control vertices (n0, 3) and level-s surface vertices (ns, 3),
        metres (copies: a viewer may keep them), to show the fit as it goes.

    Returns
    -------
    FitResult
        The result's control vertices (n0, 3) in metres with the control quads (F0, 4), its
        level-s surface vertices (ns, 3) in metres and quads (Fs, 4), the iterations run, why
        the loop stopped, the judged energy of every accepted iterate (non-increasing), the
        result's energy terms, the wall-clock seconds, the QP status of every accepted step and
        the subdivision operator.

    Raises
    ------
    FitError
        If there is no body, a fixed vertex index is out of range, a body has nothing to
        support or lies beyond `REACH` of the surface, the control mesh faces away from the
        bodies, `warm` is a fit of another control mesh, or the quadratic programme fails.
    MeshError
        If the control mesh cannot be subdivided (bad faces, non-manifold edges, creases off
        its edges).
    """
    start = time.perf_counter()
    state = _warm_state(warm, control, faces)
    pool = ThreadPoolExecutor(1, thread_name_prefix="sitrelax-fit") if overlapped() else None
    try:
        fit = prepare(control, faces, targets, params, state, pool)
        claimed = fit.programme  # claimed in `prepare` (rounds of rows on samples replace it)
        try:
            return _run(fit, state, warm, progress, iterates, cancel, start)
        finally:
            claimed.release()  # given back however the fit ends
    finally:
        if pool is not None:
            pool.shutdown()


def _run(fit: _Fit, state: "FitState | None", warm: FitResult | None, progress, iterates,
         cancel: Callable[[], bool] | None, start: float) -> FitResult:
    """`fit_surface`'s loop on a prepared fit: the descent, the rounds of rows on dense samples,
    the last uncrossed iterate as the result."""
    params = fit.params
    v_start = fit.v0
    if warm is not None:  # a designer's edit of the start moves the fitted mesh as much
        v_start = warm.control + (fit.v0 - state.start if state is not None else 0.0)
    if state is not None and len(state.member) == fit.sub.matrix.shape[0]:
        # the rows of the last fit (those that come near join as before): OSQP's set-up stays
        member, floor_member = state.member.copy(), state.floor_member.copy()
    else:
        member = initial_rows(fit, v_start)
        floor_member = np.zeros_like(member)
    setups = fit.programme.setups  # a reused programme counts its earlier set-ups
    fit.stiff = np.zeros(fit.n0)
    run = _Descent([assess(fit, v_start.copy(), member, floor_member)])
    stop, iteration = descend(fit, run, member, floor_member, 1, params.max_iterations,
                              _reporter(progress, iterates),
                              tau=None if warm is None else params.tau_max,
                              settle=warm is not None, cancel=cancel,
                              freeze=warm is not None)
    repairs = []
    for _ in range(REPAIR_ROUNDS):
        if stop.startswith("cancelled"):
            break
        extra = deep_samples(fit, run.accepted[-1].v)
        if extra is None:
            break
        add_extra_rows(fit, extra)
        again = _Descent([assess(fit, run.accepted[-1].v, member, floor_member,
                                 run.accepted[-1].rows.skin)])
        repair_stop, iteration = descend(fit, again, member, floor_member, iteration + 1,
                                         iteration + REPAIR_ITERATIONS,
                                         _reporter(progress, iterates),
                                         tau=params.tau_max, settle=True, cancel=cancel,
                                         freeze=warm is not None)
        if repair_stop.startswith("cancelled"):
            stop = repair_stop
        repairs.append({"rows": len(extra.demanded), "energies": again.energies,
                        "stop_reason": repair_stop})
        run.extend(again)
    keep, crossings = uncrossed(fit, [a.v for a in run.accepted])
    if repairs:
        stop += (f"; {len(repairs)} round(s) of rows where the surface lay deeper than the "
                 f"margin between its vertices ({sum(r['rows'] for r in repairs)} rows)")
    if keep < len(run.accepted) - 1:
        stop += (f"; the surface crossed itself or folded past {FOLD_LIMIT_DEG:g} degrees "
                 f"({crossings} triangle pairs) after accepted iterate {keep}, which is kept")
    result = run.accepted[keep]
    terms = terms_of(fit, result, params.tau_max if repairs or warm is not None else
                     params.tau_max * min(1.0, max(keep - 1, 0) / TAU_RAMP))
    terms.update(best_iteration=keep, qp_setups=fit.programme.setups - setups,
                 rejected_steps=dict(run.rejected), stiffened_proposals=run.stiffened,
                 repairs=repairs,
                 largest_row_residual_m=run.residuals[keep - 1] if keep else 0.0)
    loop = len(run.energies) - sum(len(r["energies"]) for r in repairs)
    return FitResult(result.v, fit.faces, result.surf, fit.sub.faces, iteration, stop,
                     run.energies[:loop],
                     terms, time.perf_counter() - start, run.statuses, fit.sub,
                     limit_points(fit, result.v),
                     FitState(_state_key(fit.n0, params), fit.v0, fit.limit, member,
                              floor_member,
                              fit.points, fit.normals,
                              (fit.body_tree, fit.body_tree3, fit.exit_tree), fit.tree_offset,
                              fit.skins, fit.programme if fit.extra is None else None,
                              fit.neighbours, fit.quad_maps, fit.lap,
                              None if fit.rim is None else fit.rim.member.copy()))


def _warm_state(warm: FitResult | None, control: np.ndarray, faces: np.ndarray
                ) -> FitState | None:
    """The state a warm refit reuses; a FitError when `warm` fitted another control mesh."""
    if warm is None:
        return None
    control, faces = np.asarray(control), np.asarray(faces)
    if warm.control.shape != control.shape or warm.faces.shape != faces.shape or \
            not np.array_equal(warm.faces, faces):
        raise FitError(f"Expected a warm start from a fit of the same control mesh "
                       f"({len(control)} vertices, {len(faces)} quads), got one of "
                       f"{len(warm.control)} vertices and {len(warm.faces)} quads "
                       "(or other quads)")
    return warm.state


@dataclass(eq=False)
class _Descent:
    """A run of accepted iterates (the first is where it starts), the judged energy, the
    programme's status and the largest row residual of each step, and the steps refused and why."""

    accepted: list
    energies: list = field(default_factory=list)
    statuses: list = field(default_factory=list)
    residuals: list = field(default_factory=list)
    rejected: dict = field(default_factory=lambda: {"energy": 0, "fold": 0, "ridge": 0,
                                                    "programme": 0})
    stiffened: int = 0  # proposals made again, stiffer where they folded

    def extend(self, other: "_Descent") -> None:
        self.accepted += other.accepted[1:]
        self.energies += other.energies
        self.statuses += other.statuses
        self.residuals += other.residuals
        for why, count in other.rejected.items():
            self.rejected[why] += count
        self.stiffened += other.stiffened


def _reporter(progress, iterates) -> Callable | None:
    """The loop's one callback (iteration, energy, tau, iterate) for the caller's `progress`
    (iteration, energy, tau) and `iterates` (iteration, control, surface)."""
    if progress is None and iterates is None:
        return None

    def report(iteration: int, energy: float, tau: float, it: "Iterate") -> None:
        if progress is not None:
            progress(iteration, energy, tau)
        if iterates is not None:
            iterates(iteration, it.v.copy(), it.surf.copy())
    return report


def _cancelled(done: int) -> str:
    return f"cancelled after {done} iteration(s); the last accepted iterate is kept"


def descend(fit: _Fit, run: _Descent, member: np.ndarray, floor_member: np.ndarray,
            first: int, last: int, progress=None, tau: float | None = None,
            settle: bool = False, cancel: Callable[[], bool] | None = None,
            freeze: bool = False) -> tuple[str, int]:
    """`_descend`, with the programme's solves stopped at the `deadline` of `cancel` (a
    `time.monotonic()` value, when it has one): a fit cancelled there mid-solve ends as one
    cancelled between iterations does."""
    before = len(run.accepted)
    fit.programme.deadline = getattr(cancel, "deadline", None)
    fit.programme.cancel = cancel
    try:
        return _descend(fit, run, member, floor_member, first, last, progress, tau, settle,
                        cancel, freeze)
    except DeadlinePassed:
        done = len(run.accepted) - before
        return _cancelled(done), first - 1 + done
    finally:
        fit.programme.deadline = fit.programme.cancel = None


def _descend(fit: _Fit, run: _Descent, member: np.ndarray, floor_member: np.ndarray,
             first: int, last: int, progress=None, tau: float | None = None,
             settle: bool = False, cancel: Callable[[], bool] | None = None,
             freeze: bool = False) -> tuple[str, int]:
    """Iterations `first`..`last` from the run's last iterate: each proposes a step and
    accepts it (`acceptable`) or tries it half as long; tau ramps over the first TAU_RAMP
    iterations unless given. With `settle`, it stops once an accepted step lowers the energy
    by less than the tolerance (relative), with `freeze` too once the steps to come would
    (`_settled_ahead`); `cancel` is polled before each iteration and before
    each try after the first. A full step refused for a fold or a ridge is proposed again with
    the surface stiffer where it folded (`_stiffened`, up to STIFFEN_ROUNDS times), and one then
    refused for its energy once more as a step that bends less there (or, when the step that
    bends less was the one refused, as the smoother one); the next iteration proposes first
    the kind the last one took (a fit that creeps on with steps that bend less makes no
    smoother proposal, refused every time, before each); with `freeze` (a warm
    refit) such a step is instead tried again with the control vertices that shape the
    offending quads held still. While tau ramps, an iteration whose halvings all fail shortens
    in turn the full proposal refused for a fold or a ridge that lowered the energy most, before
    the loop stops. Returns why it stopped and the last iteration."""
    params = fit.params
    it = run.accepted[-1]
    iteration = first - 1
    gains: list[float] = []  # how much each accepted step lowered the energy
    ahead = None  # (tau, quadratic) of the next step, made with the last accepted iterate
    bend_less = False  # the proposals' stiffening: smoother (False) or bending less (True);
    # an iteration starts with the kind the last one took
    for iteration in range(first, last + 1):
        if cancel is not None and cancel():
            return _cancelled(iteration - first), iteration - 1
        t = params.tau_max * min(1.0, (iteration - 1) / TAU_RAMP) if tau is None else tau
        next_tau = params.tau_max * min(1.0, iteration / TAU_RAMP) if tau is None else tau
        quadratic = ahead[1] if ahead is not None and ahead[0] == t else \
            assemble(fit, it.pairing, it.surf_n, t)
        ahead = None
        bend_less = bend_less and bool(fit.stiff.any())
        try:
            target, status, residual = propose(
                fit, it, params.step, _stiffened(fit, quadratic, it.v if bend_less else None))
        except FitError:
            if not fit.stiff.any():
                raise
            # the solver gave up on the stiffened programme: the programme as it is
            run.rejected["programme"] += 1
            target, status, residual = propose(fit, it, params.step, quadratic)
        if not freeze or iteration == first:
            moving = np.ones((fit.n0, 1))
        halving = freezes = stiffened = 0
        switched = False  # whether the other kind of proposal has been tried
        bent_best = None  # (gain, target, moving, status, residual): the full proposal
        # refused for its bends that lowered the energy most (shortened in turn when the
        # others' halvings fail in the tau ramp)
        while halving <= MAX_HALVINGS:
            if cancel is not None and (halving or stiffened or freezes or switched) and \
                    cancel():  # (a large programme's tries take seconds each)
                return _cancelled(iteration - first), iteration - 1
            v = it.v + 0.5 ** halving * moving * (target - it.v)
            candidate = assess(fit, v, member, floor_member, it.rows.skin, rows=False,
                               ceiling=(t, it.energy(t)), ahead=next_tau)
            why = acceptable(fit, it, candidate, t)
            if why is None:
                break
            run.rejected[why] += 1
            if why != "energy" and halving == 0:
                gain = it.energy(t) - candidate.energy(t)
                if gain > 0 and (bent_best is None or gain > bent_best[0]):
                    bent_best = (gain, target, moving.copy(), status, residual)
            again = None
            if halving == 0 and not freeze:  # (a warm refit holds vertices still instead)
                if why != "energy" and stiffened < STIFFEN_ROUNDS:
                    # the programme knows no fold or ridge: it proposes again with the
                    # surface stiffer where this proposal bends it too far (and stays so)
                    bent = _bent_controls(fit, it, candidate)
                    if bent.any():
                        least = STIFFEN_FIRST * max(params.sigma, FitParams.sigma) / fit.n0
                        fit.stiff[bent] = np.maximum(fit.stiff[bent] * STIFFEN_FACTOR, least)
                        stiffened += 1
                        run.stiffened += 1
                        bend_less = again = False
                elif why == "energy" and not switched and fit.stiff.any():
                    # a smoother surface costs more than it gains: a step that only bends
                    # less where proposals folded (staying costs nothing, so it lowers the
                    # programme's objective); or, when that was the one refused, the smoother
                    bend_less = again = not bend_less
                    switched = True
            if again is not None:
                try:
                    target, status, residual = propose(
                        fit, it, params.step, _stiffened(fit, quadratic, it.v if again else None))
                    continue
                except FitError:  # the solver gave up: the last proposal is shortened instead
                    run.rejected["programme"] += 1
            if freeze and why != "energy" and freezes < FREEZES:
                # the programme knows no fold or ridge: the step is tried again, as long, with
                # the control vertices that shape the offending quads held where they are
                frozen = _bent_controls(fit, it, candidate) & (moving[:, 0] > 0)
                if frozen.any() and not frozen.all():
                    moving[frozen] = 0.0
                    freezes += 1
                    continue
            halving += 1
            if halving > MAX_HALVINGS and bent_best is not None and t < params.tau_max and \
                    bent_best[1] is not target:
                # no step yet at this tau, before tau has reached its top (the energy judged is
                # not yet the fit's): the proposal that gained most but bent too far is
                # shortened instead, rather than the fit stopping there (unless it is the one
                # whose halvings just failed)
                _, target, moving, status, residual = bent_best
                bent_best, halving = None, 1
        else:
            return (f"converged: no step along the programme's solution (down to "
                    f"1/{2 ** MAX_HALVINGS} of it) lowers the energy without folding (energy "
                    f"{it.energy(t):.6g})"), iteration
        before = it.energy(t)
        ahead = candidate.ahead
        it = with_rows(fit, candidate, member, floor_member, it.rows.skin) \
            if candidate.rows is None else replace(candidate, ahead=None)
        run.accepted.append(it)
        run.energies.append(it.energy(t))
        run.statuses.append(status)
        run.residuals.append(residual)
        if progress is not None:
            progress(iteration, run.energies[-1], t, it)
        if settle and run.energies[-1] > before * (1 - params.tolerance):
            return (f"settled: the last step lowered the energy by less than "
                    f"{100 * params.tolerance:g} % ({run.energies[-1]:.6g})"), iteration
        gains.append(before - run.energies[-1])
        if freeze and settle and _settled_ahead(gains, run.energies[-1], params.tolerance):
            return (f"settled: the steps to come would lower the energy by less than "
                    f"{100 * params.tolerance:g} % in all, as the last two shrank "
                    f"({run.energies[-1]:.6g})"), iteration
        if tau is None and converged(run.energies, params.tolerance) or \
                tau is not None and len(run.energies) > PATIENCE and \
                run.energies[-1] > run.energies[-1 - PATIENCE] * (1 - params.tolerance):
            return (f"converged: the energy has not improved by {100 * params.tolerance:g} %"
                    f" in {PATIENCE} iterations ({run.energies[-1]:.6g})"), iteration
    return f"reached the iteration limit ({last})", iteration
