"""Pose relaxation: the paper's section 6 and appendix B, judged by the evaluation's figures.

The rig's pose is moved so that the supportable skin comes to rest on a surface without
cutting into it, while staying close to the captured pose. Parameters: three angles per joint,
a rotation relative to the captured local rotation (L_j = L0_j Rx(a) Ry(b) Rz(c), so the start
is all zeros and far from gimbal lock), and the root translation. Residuals, each weighted by
sqrt(lambda) and by the importance r_i of supportable vertex i:

    point-to-point   r_i (v_i - c_i)                       (c_i: closest surface point)
    point-to-plane   r_i s_i,  s_i = n_i . v_i - d_i       (the surface's tangent plane)
    penetration      r_i (2 / pi) arctan(max(0, -(s_i + m)) / w)
    similarity       theta - theta0

The paper's penetration term, 1/2 - arctan(a s + b) / pi with a = 1000 and b = 10 in metres, is
a step about 1/a = 1 mm wide whose middle sits 1 cm behind the surface. Its half in front of the
middle reaches far: on a surface fitted to the same pose, every skin point near the surface was
pushed off it harder than the distance terms pulled it back (the support distance grew, the
contact shrank, the deepest cut deepened). Here the step is cut at its middle and rescaled to
rise from 0: nothing in front of the surface, and nothing sunk in by less than the softness
margin m the surface was fitted with, is pushed; deeper skin is, over `PENETRATION_WIDTH` = 1/a
(m is the paper's b/a = 1 cm, `DEFAULT_MARGIN`, when the surface's is not known).

Skin with no importance takes no part in the distance terms, but where the surface cuts into it
or it lies within `GUARD_BAND` in front of it (`guard_ids`: the calves at a seat's front edge)
it may not sink deeper than it was at the start of a round, or into the surface, by more than
`GUARD_TOLERANCE`, with weight `GUARD_WEIGHT`: pulling the thighs down must not push the
calves into the seat.

With a floor (`RelaxProblem.floor`, its height), the skin near it (`floor_ids`: the feet) is
held likewise: it may not sink under the floor by more than it was at the start of a round or
than `FLOOR_TOLERANCE`, with weight `GUARD_WEIGHT`: a body pulled down onto a seat bends its
legs rather than pushing its feet through the floor.

Only the vertices facing the surface (their closest point is the foot of the perpendicular, not a
point on a border they lie beside) can be behind it: a thigh below the level of an armrest's
edge has not cut into the armrest.

Jacobians are analytic, as in appendix B: d v_i / d theta_k = a_k x sum_{j below k} w_ij
(u_ij - p_k), with a_k the world axis of the angle, p_k its joint, u_ij the point joint j moves
vertex i to and w_ij the skinning weight; d v_i / d t = I for the root translation. The problem
is solved by scipy's trust-region reflective least squares with box constraints (`JOINT_LIMITS`,
in degrees from the captured pose), re-pairing with the surface between rounds.

A round's pose is kept only where a `Gate` (the evaluation's own figures: support distance,
coverage, contact coverage, deepest cut) finds none of them worse than the last kept pose's;
otherwise, in the first round, a shorter step towards it is tried (`STEP_SCALES`), and when
none passes the last kept pose is returned. The result is never worse than the captured pose
by those figures.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from capture import WorldPose

from solver.body.model import Body
from solver.mesh import SurfaceMesh
from solver.body.rig import descendants, rig_pose

LAMBDAS = (0.2, 0.2, 0.5, 0.1)  # point-to-point, point-to-plane, penetration, similarity
PENETRATION_WIDTH = 0.001  # metres: 1 / a
FACING_TOLERANCE = 1e-6  # metres off the perpendicular foot that still counts as facing
DEFAULT_MARGIN = 0.01  # metres skin may sink when the surface's margin is unknown: the paper's b/a
GUARD_WEIGHT = 0.3  # of the penetration term, for the skin with no importance the surface cuts
GUARD_TOLERANCE = 3e-4  # metres such skin may sink past where a round found it
GUARD_BAND = 0.01  # metres in front of the surface within which such skin is guarded too
GUARD_SPACING = 0.015  # metres: one guarded vertex per cube of this side, the deepest
FLOOR_TOLERANCE = 0.001  # metres the skin near the floor may sink under it (its foam is stiff)
ROOT_RANGE = 0.15  # metres the root may move
FTOL = 1e-5  # relative cost change at which a round stops
TR_OPTIONS = {"maxiter": 10}  # lsmr iterations per trust-region step: a rough step is enough

# How far (degrees, per axis) each joint may turn from the captured pose: loose where joints
# are mobile, tight along the spine; fingers and toes hardly move.
JOINT_LIMITS = {
    "Hips": 10, "LowerBack": 15, "Spine": 15, "Spine1": 15, "Neck": 20, "Neck1": 20,
    "Head": 20, "LHipJoint": 0, "RHipJoint": 0, "LeftUpLeg": 30, "RightUpLeg": 30,
    "LeftLeg": 30, "RightLeg": 30, "LeftFoot": 20, "RightFoot": 20, "LeftToeBase": 5,
    "RightToeBase": 5, "LeftShoulder": 10, "RightShoulder": 10, "LeftArm": 45, "RightArm": 45,
    "LeftForeArm": 45, "RightForeArm": 45, "LeftHand": 30, "RightHand": 30,
}
DEFAULT_LIMIT = 5


class RelaxError(ValueError):
    """A relaxation that cannot run as asked."""


@dataclass(frozen=True, eq=False)
class RelaxProblem:
    """A body in a captured pose, its supportable vertices and a surface to settle on.

    local0 : (J, 3, 3) captured local rotations; root0 : (3,) captured root position (m);
    vertex_ids : (m,) the supportable vertices; importance : (m,) their r_i;
    surface_vertices (N, 3), surface_triangles (F, 3): the surface (normals towards the body);
    margin : metres the skin may sink into the surface before the penetration term pushes it;
    guard_ids : (g,) vertices with no importance that may not sink deeper (module docstring);
    floor : the floor's height (m), or None; floor_ids : (f,) the vertices held above it.
    """

    body: Body
    local0: np.ndarray
    root0: np.ndarray
    vertex_ids: np.ndarray
    importance: np.ndarray
    surface_vertices: np.ndarray
    surface_triangles: np.ndarray
    lambdas: tuple[float, float, float, float] = LAMBDAS
    margin: float = DEFAULT_MARGIN
    guard_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    floor: float | None = None
    floor_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self):
        joints, count = len(self.body.joint_names), len(self.body.vertices)
        for name, value, shape in (("local0", self.local0, (joints, 3, 3)),
                                   ("root0", self.root0, (3,))):
            if np.shape(value) != shape or not np.all(np.isfinite(value)):
                raise RelaxError(f"Expected {name} of shape {shape}, finite, got shape "
                                 f"{np.shape(value)}")
        ids = np.asarray(self.vertex_ids)
        guard = np.asarray(self.guard_ids)
        for name, value in (("vertex_ids", ids), ("guard_ids", guard),
                            ("floor_ids", np.asarray(self.floor_ids))):
            if value.ndim != 1 or value.size and (
                    not np.issubdtype(value.dtype, np.integer) or value.min() < 0 or
                    value.max() >= count):
                raise RelaxError(f"Expected {name} as (m,) integer indices in 0..{count - 1}, "
                                 f"got {value.dtype} of shape {value.shape}")
        surface = np.asarray(self.surface_vertices)
        if self.floor is not None and not np.isfinite(self.floor):
            raise RelaxError(f"Expected a finite floor height, got {self.floor}")
        if surface.ndim != 2 or surface.shape[1:] != (3,):
            raise RelaxError(f"Expected surface_vertices of shape (N, 3), got {surface.shape}")
        both = np.intersect1d(self.vertex_ids, self.guard_ids)
        if both.size:
            raise RelaxError(f"Expected guarded vertices that are not supportable, got "
                             f"{both.size} in both (first {int(both[0])})")
        if np.shape(self.importance) != (len(ids),) or \
                not np.all(np.isfinite(self.importance)):
            raise RelaxError(f"Expected one finite importance per supportable vertex "
                             f"({len(ids)}), got shape {np.shape(self.importance)}")

    def surface_mesh(self) -> SurfaceMesh:
        """The surface as a `SurfaceMesh` (its closest-point tree), made on first use and kept."""
        mesh = self.__dict__.get("_surface_mesh")
        if mesh is None:
            mesh = SurfaceMesh.from_triangles(self.surface_vertices, self.surface_triangles)
            object.__setattr__(self, "_surface_mesh", mesh)
        return mesh


class _Model:
    """Forward model and analytic Jacobian of the supportable vertices, then the guarded ones,
    then those held above the floor (`ids`; the first `supported` are the supportable, the
    last `floored` the floor's)."""

    def __init__(self, problem: RelaxProblem):
        self.p = problem
        body = problem.body
        self.n = len(body.joint_names)
        floor_ids = problem.floor_ids if problem.floor is not None else problem.floor_ids[:0]
        self.ids = np.concatenate([problem.vertex_ids, problem.guard_ids,
                                   floor_ids]).astype(np.int64)
        self.supported = len(problem.vertex_ids)
        self.floored = len(floor_ids)
        w = body.weights[self.ids].tocsr()
        w.sum_duplicates()  # one entry per (vertex, joint): the Jacobian assigns, not adds
        w = w.tocoo()
        self.wi, self.wj, self.wv = w.row, w.col, w.data
        self.m = len(self.ids)
        # each (vertex, joint) entry's rest lever arm, and the weights that blend the entries
        # into vertices, both fixed for the problem
        self.lever = body.vertices[self.ids][self.wi] - body.joints[self.wj]
        self.blend = sp.csr_matrix((self.wv, (self.wi, np.arange(len(self.wi)))),
                                   shape=(self.m, len(self.wi)))
        self.desc = descendants(body.parents)
        self._last: tuple[np.ndarray, tuple] | None = None  # least_squares asks twice per x
        self._levers: tuple[np.ndarray, tuple] | None = None

    def pose(self, theta: np.ndarray) -> tuple[np.ndarray, WorldPose]:
        angles = theta[:3 * self.n].reshape(self.n, 3)
        delta = Rotation.from_euler("XYZ", angles).as_matrix()
        local = self.p.local0 @ delta
        return local, rig_pose(self.p.body, local, self.p.root0 + theta[3 * self.n:])

    def vertices(self, theta: np.ndarray):
        if self._last is not None and np.array_equal(self._last[0], theta):
            return self._last[1]
        local, world = self.pose(theta)
        u = np.einsum("kab,kb->ka", world.rotmats[self.wj], self.lever) + \
            world.positions[self.wj]
        out = (self.blend @ u, u, local, world)
        self._last = (theta.copy(), out)
        return out

    def levers(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertices (m, 3); the world axes (J, 3, 3) of each joint's three angles (axis k of
        joint j at [j, k]); and per vertex i and joint j the lever arm (m, 3, J) the turns at
        j move it by: the sum over the joints l at or below j of w_il (u_il - p_j)."""
        if self._levers is not None and np.array_equal(self._levers[0], theta):
            return self._levers[1]
        v, u, local, world = self.vertices(theta)
        n, m = self.n, self.m
        angles = theta[:3 * n].reshape(n, 3)
        parents = self.p.body.parents
        # L = L0 Rx Ry Rz under the parent's frame
        base = np.where(parents[:, None, None] >= 0, world.rotmats[np.maximum(parents, 0)],
                        np.eye(3)) @ self.p.local0
        rx = Rotation.from_euler("X", angles[:, :1]).as_matrix()
        ry = Rotation.from_euler("Y", angles[:, 1:2]).as_matrix()
        axes = np.stack([base[:, :, 0], (base @ rx)[:, :, 1], (base @ rx @ ry)[:, :, 2]], axis=1)
        cu = np.zeros((m, 3, n))
        wsum = np.zeros((m, n))
        cu[self.wi, :, self.wj] = self.wv[:, None] * u
        wsum[self.wi, self.wj] = self.wv
        below = (cu.reshape(3 * m, n) @ self.desc).reshape(m, 3, n) - \
            (wsum @ self.desc)[:, None, :] * world.positions.T[None]
        self._levers = (theta.copy(), (v, axes, below))
        return v, axes, below

    def jacobian_vertices(self, theta: np.ndarray,
                          rows: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (m, 3) and d v / d theta (r, 3, P) of the vertices `rows`, P = 3 J + 3:
        a turn about axis a moves a vertex by a x its lever arm, the root by the identity."""
        v, axes, below = self.levers(theta)
        bx, by, bz = below[rows, 0], below[rows, 1], below[rows, 2]  # (r, J) each
        n = self.n
        jac = np.zeros((len(bx), 3, 3 * n + 3))
        for k in range(3):
            ax, ay, az = axes[:, k, 0], axes[:, k, 1], axes[:, k, 2]  # (J,) each
            jac[:, 0, k:3 * n:3] = ay * bz - az * by
            jac[:, 1, k:3 * n:3] = az * bx - ax * bz
            jac[:, 2, k:3 * n:3] = ax * by - ay * bx
        jac[:, :, 3 * n:] = np.eye(3)[None]
        return v, jac

    def normal_jacobian(self, theta: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """d (n_i . v_i) / d theta (m, P) for unit normals (m, 3): n . (a x b) = a . (b x n),
        without the vertices' whole Jacobian."""
        _, axes, below = self.levers(theta)
        nx, ny, nz = normals[:, 0:1], normals[:, 1:2], normals[:, 2:3]  # (m, 1) each
        bx, by, bz = below[:, 0], below[:, 1], below[:, 2]  # (m, J) each
        cx, cy, cz = by * nz - bz * ny, bz * nx - bx * nz, bx * ny - by * nx
        n = self.n
        jn = np.empty((self.m, 3 * n + 3))
        for k in range(3):
            jn[:, k:3 * n:3] = axes[:, k, 0] * cx + axes[:, k, 1] * cy + axes[:, k, 2] * cz
        jn[:, 3 * n:] = normals
        return jn


def joint_bounds(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Box constraints on the parameters (radians, metres)."""
    lim = np.radians([max(JOINT_LIMITS.get(name, DEFAULT_LIMIT), 1e-6)
                      for name in body.joint_names])
    hi = np.concatenate([np.repeat(lim, 3), np.full(3, ROOT_RANGE)])
    return -hi, hi


def _surface_frames(points: np.ndarray, surface: SurfaceMesh):
    """Closest surface points (m, 3), unit normals (m, 3) of their faces, and whether each
    point faces its surface point (m,): its closest point is the foot of the perpendicular,
    not a point on the surface's border that the point lies beside.

    Only a facing point can be behind the surface; one beside the border and below its
    plane has not cut into anything, and the penetration term leaves it alone."""
    _, along, _, face, closest = surface.closest(points)
    fn = surface.face_normals[face]
    sideways = np.linalg.norm(points - closest - along[:, None] * fn, axis=1)
    facing = sideways <= FACING_TOLERANCE + 1e-3 * np.abs(along)
    return closest, fn, facing.astype(np.float64)


def penetration_step(signed: np.ndarray, allowed) -> tuple[np.ndarray, np.ndarray]:
    """The penetration term's step (m,) in [0, 1) of the signed distances (m,) (metres, positive
    in front of the surface) and its derivative (m,) per metre: 0 in front of the surface and
    down to `allowed` behind it (metres, a number or (m,)), then rising as the paper's arctan
    step does past its middle, over `PENETRATION_WIDTH`, towards 1 deep behind it."""
    depth = np.maximum(-(signed + allowed), 0.0) / PENETRATION_WIDTH
    step = (2.0 / np.pi) * np.arctan(depth)
    slope = np.where(depth > 0.0, -(2.0 / np.pi) / PENETRATION_WIDTH / (1.0 + depth ** 2), 0.0)
    return step, slope


def residuals(theta: np.ndarray, model: _Model, closest: np.ndarray, normals: np.ndarray,
              weights: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """The residuals of the module docstring at theta, for a round's pairing: per vertex of
    the model (m) its closest surface point (m, 3), that face's unit normal (m, 3), the weight
    of its penetration term (m,) (0 where it does not face the surface) and the depth (m,)
    metres it may sink before that term pushes it."""
    lp, lt, lpen, ls = (np.sqrt(x) for x in model.p.lambdas)
    r, k = model.p.importance, model.supported
    v = model.vertices(theta)[0]
    s = np.einsum("ij,ij->i", normals, v - closest)
    return np.concatenate([
        lp * (r[:, None] * (v[:k] - closest[:k])).ravel(),
        lt * r * s[:k],
        lpen * weights * penetration_step(s, allowed)[0],
        ls * theta,
    ])


def residual_jacobian(theta: np.ndarray, model: _Model, closest: np.ndarray,
                      normals: np.ndarray, weights: np.ndarray,
                      allowed: np.ndarray) -> np.ndarray:
    """d residuals / d theta (R, P), analytic (appendix B)."""
    lp, lt, lpen, ls = (np.sqrt(x) for x in model.p.lambdas)
    r, k = model.p.importance, model.supported
    v, jv = model.jacobian_vertices(theta, slice(0, k))  # (m, 3), (k, 3, P)
    jn = model.normal_jacobian(theta, normals)  # (m, P): d s / d theta
    s = np.einsum("ij,ij->i", normals, v - closest)
    size = jv.shape[2]
    out = np.empty((4 * k + model.m + size, size))
    np.multiply((lp * r)[:, None, None], jv, out=out[:3 * k].reshape(k, 3, size))
    np.multiply((lt * r)[:, None], jn[:k], out=out[3 * k:4 * k])
    np.multiply((lpen * weights * penetration_step(s, allowed)[1])[:, None], jn,
                out=out[4 * k:4 * k + model.m])
    out[4 * k + model.m:] = ls * np.eye(size)
    return out


def pairing(model: _Model, theta: np.ndarray, surface: SurfaceMesh):
    """A round's pairing at theta, the arguments of `residuals` after the model: the closest
    surface points (m, 3), their faces' normals (m, 3), the penetration term's weights (m,)
    and the depths (m,) each vertex may sink (the margin; for a guarded vertex where it is
    now, at least 0, and `GUARD_TOLERANCE` more; for one held above the floor, paired with
    the floor's plane under it, where it is now or `FLOOR_TOLERANCE`, the more)."""
    p, k, f = model.p, model.supported, model.floored
    v = model.vertices(theta)[0]
    closest, normals, facing = _surface_frames(v, surface)
    if f:  # the floor's rows: the plane y = floor under each, facing up
        on = slice(model.m - f, model.m)
        closest[on] = v[on]
        closest[on, 1] = p.floor
        normals[on] = (0.0, 1.0, 0.0)
        facing[on] = 1.0
    weights = np.concatenate([p.importance, np.full(model.m - k, GUARD_WEIGHT)]) * facing
    allowed = np.full(model.m, float(p.margin))
    depth = -np.einsum("ij,ij->i", normals[k:], v[k:] - closest[k:])
    allowed[k:] = np.maximum(depth, 0.0) + GUARD_TOLERANCE
    if f:
        allowed[model.m - f:] = np.maximum(depth[-f:], FLOOR_TOLERANCE)
    return closest, normals, weights, allowed


class Gate(Protocol):
    """What judges a relaxed pose: `figures` of the whole skin (V, 3) in metres (a dict; given
    a `reference`, it may stop short once one figure is worse than the reference's), and
    `worse`, the names of the figures worse in `after` than in `before` (empty: not worse)."""

    def figures(self, vertices: np.ndarray, reference: dict | None = None) -> dict: ...

    def worse(self, before: dict, after: dict) -> list[str]: ...


STEP_SCALES = (1.0, 0.5)  # shares of the first round's step tried, until one is not worse


@dataclass(frozen=True)
class RelaxStep:
    """One pose a gated relaxation tried: its round (from 1), the share of the round's step
    (1: the round's solution, 1/2: half way to it from the last accepted pose), whether it was
    accepted, its figures, and the names of the figures worse than the last accepted pose's
    (why it was rejected) and better (what it gained)."""

    round: int
    scale: float
    accepted: bool
    figures: dict
    worse: tuple[str, ...]
    better: tuple[str, ...]


@dataclass
class RelaxResult:
    """A relaxed pose (see `relax`).

    theta : (3 J + 3,) float, the solution: per joint three angles (radians) from the captured
        local rotation, L_j = L0_j Rx Ry Rz, then the root translation (metres) from `root0`.
    local : (J, 3, 3) float relaxed local rotations; world : WorldPose (J) relaxed world frames.
    vertices : (V, 3) float, metres, the whole relaxed body.
    cost : half the sum of squared residuals of the returned pose, paired as in the last round.
    evaluations : residual evaluations over all rounds; rounds : the rounds run.
    at_limit : how many parameters ended on their box limit.
    steps : with a gate, every pose tried (`RelaxStep`), in order; empty without one.
    figures_before, figures : with a gate, its figures of the captured pose and of the returned
        one (None without a gate).
    """

    theta: np.ndarray
    local: np.ndarray
    world: WorldPose
    vertices: np.ndarray  # (V, 3) the whole relaxed body
    cost: float
    evaluations: int
    rounds: int
    at_limit: int  # parameters on their box limit
    steps: tuple[RelaxStep, ...] = ()
    figures_before: dict | None = None
    figures: dict | None = None

    @property
    def accepted(self) -> bool:
        """Whether a gate accepted some round (True without a gate: every round is taken)."""
        if self.figures is None and not self.steps:
            return True
        return any(s.accepted for s in self.steps)


def relax(problem: RelaxProblem, rounds: int = 3, max_evaluations: int = 15, *,
          numeric_jacobian: bool = False, gate: Gate | None = None,
          figures_before: dict | None = None) -> RelaxResult:
    """Relaxes the pose: `rounds` of pairing with the surface, each a bounded least squares,
    each round's pose accepted only where the `gate` finds none of its figures worse.

    Each round pairs the supportable and guarded vertices with their closest surface points,
    then solves the least squares of the module docstring from the last accepted pose
    (trust-region reflective, box constraints `JOINT_LIMITS` in degrees per axis and
    `ROOT_RANGE` metres). With a gate, the round's solution is accepted when none of its
    figures is worse than the last accepted pose's; in the first round, whose step is the
    longest, the shares `STEP_SCALES` of the step are tried in turn, the whole step first.
    When no pose of a round is accepted, the last accepted one is kept and the relaxation stops
    (a next round would pair and solve the same). The returned pose is then never worse than
    the captured one by the gate's figures.

    Parameters
    ----------
    problem : RelaxProblem
        The body, its captured pose, its supportable vertices with their importance, and the
        surface (metres).
    rounds : int, default 3
        Rounds of pairing and solving.
    max_evaluations : int, default 15
        Residual evaluations allowed in the first round; later rounds, which refine it, get
        half as many.
    numeric_jacobian : bool, default False
        Swaps the analytic Jacobian for finite differences (a reference).
    gate : Gate, optional
        What judges each round's pose (`solver.contact.evaluate.SupportGate`: the evaluation's
        own figures); None accepts every round.
    figures_before : dict, optional
        The gate's figures of the captured pose when the caller has them (computed otherwise).

    Returns
    -------
    RelaxResult
        The parameters theta (3 J + 3,) (radians per joint axis, then the root translation in
        metres), the relaxed local rotations (J, 3, 3) and world frames (J), the whole relaxed
        skin (V, 3) in metres, its cost, the evaluations over all rounds, the number of
        parameters at their limit, and with a gate every pose tried and the figures before and
        after.
    """
    from scipy.optimize import least_squares  # loaded when a pose is relaxed

    if rounds < 1 or max_evaluations < 1:
        raise RelaxError(f"Expected at least one round and one evaluation per round, got "
                         f"rounds={rounds}, max_evaluations={max_evaluations}")
    model = _Model(problem)
    lo, hi = joint_bounds(problem.body)
    theta = np.zeros(3 * model.n + 3)
    surface = problem.surface_mesh()
    jac = "2-point" if numeric_jacobian else residual_jacobian
    verts, figures = None, None
    if gate is not None:
        verts = _skin(model, theta)
        figures = gate.figures(verts) if figures_before is None else figures_before
    before = figures
    evaluations, run, steps = 0, 0, []
    paired = None
    for run in range(1, rounds + 1):
        paired = pairing(model, theta, surface)
        budget = max_evaluations if run == 1 else (max_evaluations + 1) // 2
        sol = least_squares(residuals, theta, jac=jac, bounds=(lo, hi), method="trf",
                            tr_solver="lsmr", max_nfev=budget, ftol=FTOL, xtol=1e-8,
                            x_scale="jac", args=(model, *paired), tr_options=TR_OPTIONS)
        evaluations += sol.nfev
        if gate is None:
            theta = sol.x
            continue
        for scale in STEP_SCALES if run == 1 else STEP_SCALES[:1]:
            tried = theta + scale * (sol.x - theta)  # between two poses in the box: in it
            tried_verts = _skin(model, tried)
            tried_figures = gate.figures(tried_verts, reference=figures)
            worse = tuple(gate.worse(figures, tried_figures))
            steps.append(RelaxStep(run, scale, not worse, tried_figures, worse,
                                   tuple(gate.worse(tried_figures, figures))))
            if not worse:
                theta, verts, figures = tried, tried_verts, tried_figures
                break
        else:
            break
    if gate is None:
        verts = _skin(model, theta)
    local, world = model.pose(theta)
    cost = 0.5 * float(np.sum(residuals(theta, model, *paired) ** 2))
    at_limit = int(np.sum((theta <= lo + 1e-9) | (theta >= hi - 1e-9)))
    return RelaxResult(theta, local, world, verts, cost, evaluations, run, at_limit,
                       tuple(steps), before, figures)


def _skin(model: _Model, theta: np.ndarray) -> np.ndarray:
    """(V, 3) the whole skin in the pose theta."""
    from solver.body.skinning import skin

    _, world = model.pose(theta)
    return skin(model.p.body, WorldPose(world.positions, world.rotmats), normals=False)[0]
