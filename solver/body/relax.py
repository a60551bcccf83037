"""Pose relaxation: the paper's section 6 and appendix B.

The rig's pose is moved so that the supportable skin comes to rest on a surface without
cutting into it, while staying close to the captured pose. Parameters: three angles per joint,
a rotation relative to the captured local rotation (L_j = L0_j Rx(a) Ry(b) Rz(c), so the start
is all zeros and far from gimbal lock), and the root translation. Residuals, each weighted by
sqrt(lambda) and by the importance r_i of supportable vertex i:

    point-to-point   r_i (v_i - c_i)                       (c_i: closest surface point)
    point-to-plane   r_i (n_i . v_i - d_i)                 (the surface's tangent plane)
    penetration      r_i (1/2 - arctan(a (n_i . v_i - d_i) + b) / pi)
    similarity       theta - theta0

The penetration term is a smooth step of the signed distance s = n . v - d from the surface: 1
well behind it, 0 well in front. The paper's a = 1000 and b = 10 are in metres (its meshes came
from Blender in metres): the step is about 1/a = 1 mm wide and its middle sits at s = -b/a =
-1 cm, slightly into the surface. Here they are `PENETRATION_WIDTH` = 1 mm and
`PENETRATION_SHIFT` = 1 cm, so a = 1 / width and b = shift / width. A surface fitted with a
softness margin m (the fit lets skin sink m into the foam) is relaxed onto with the step's middle
two widths short of m, so the penalty is nearly full at the margin and absent well inside it
(`solver.scene.run.relax_problem`); otherwise the paper's 1 cm holds.

Only the vertices facing the surface (their closest point is the foot of the perpendicular, not a
point on a border they lie beside) can be behind it: a thigh below the level of an armrest's
edge has not cut into the armrest.

Jacobians are analytic, as in appendix B: d v_i / d theta_k = a_k x sum_{j below k} w_ij
(u_ij - p_k), with a_k the world axis of the angle, p_k its joint, u_ij the point joint j moves
vertex i to and w_ij the skinning weight; d v_i / d t = I for the root translation. The problem
is solved by scipy's trust-region reflective least squares with box constraints (`JOINT_LIMITS`,
in degrees from the captured pose), re-pairing with the surface between solves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from capture import WorldPose

from solver.body.model import Body
from solver.mesh import face_normals
from solver.body.rig import descendants, rig_pose

LAMBDAS = (0.2, 0.2, 0.5, 0.1)  # point-to-point, point-to-plane, penetration, similarity
PENETRATION_WIDTH = 0.001  # metres: 1 / a
FACING_TOLERANCE = 1e-6  # metres off the perpendicular foot that still counts as facing
PENETRATION_SHIFT = 0.01  # metres: b / a, how far behind the surface the step's middle lies
ROOT_RANGE = 0.15  # metres the root may move
FTOL = 1e-5  # relative cost change at which a round stops

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
    surface_vertices (N, 3), surface_triangles (F, 3): the surface (normals towards the body).
    """

    body: Body
    local0: np.ndarray
    root0: np.ndarray
    vertex_ids: np.ndarray
    importance: np.ndarray
    surface_vertices: np.ndarray
    surface_triangles: np.ndarray
    lambdas: tuple[float, float, float, float] = LAMBDAS
    penetration_shift: float = PENETRATION_SHIFT  # metres behind the surface: the step's middle


class _Model:
    """Forward model and analytic Jacobian of the supportable vertices."""

    def __init__(self, problem: RelaxProblem):
        self.p = problem
        body = problem.body
        self.n = len(body.joint_names)
        w = body.weights[problem.vertex_ids].tocsr()
        w.sum_duplicates()  # one entry per (vertex, joint): the Jacobian assigns, not adds
        w = w.tocoo()
        self.wi, self.wj, self.wv = w.row, w.col, w.data
        self.m = len(problem.vertex_ids)
        # each (vertex, joint) entry's rest lever arm, and the weights that blend the entries
        # into vertices, both fixed for the problem
        self.lever = body.vertices[problem.vertex_ids][self.wi] - body.joints[self.wj]
        self.blend = sp.csr_matrix((self.wv, (self.wi, np.arange(len(self.wi)))),
                                   shape=(self.m, len(self.wi)))
        self.desc = descendants(body.parents)
        self._last: tuple[np.ndarray, tuple] | None = None  # least_squares asks twice per x

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

    def jacobian_vertices(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (m, 3) and d v / d theta (m, 3, P), P = 3 J + 3."""
        v, u, local, world = self.vertices(theta)
        n, m = self.n, self.m
        angles = theta[:3 * n].reshape(n, 3)
        parents = self.p.body.parents
        # world axes of each joint's three angles: L = L0 Rx Ry Rz under the parent's frame
        base = np.where(parents[:, None, None] >= 0, world.rotmats[np.maximum(parents, 0)],
                        np.eye(3)) @ self.p.local0
        rx = Rotation.from_euler("X", angles[:, :1]).as_matrix()
        ry = Rotation.from_euler("Y", angles[:, 1:2]).as_matrix()
        axes = np.stack([base[:, :, 0], (base @ rx)[:, :, 1], (base @ rx @ ry)[:, :, 2]], axis=1)
        # per vertex i and joint k: the sum over the joints j at or below k of
        # w_ij (u_ij - p_k), the lever arm the rotation at k turns
        cu = np.zeros((m, 3, n))
        wsum = np.zeros((m, n))
        cu[self.wi, :, self.wj] = self.wv[:, None] * u
        wsum[self.wi, self.wj] = self.wv
        below = (cu.reshape(3 * m, n) @ self.desc).reshape(m, 3, n) - \
            (wsum @ self.desc)[:, None, :] * world.positions.T[None]
        bx, by, bz = below[:, 0], below[:, 1], below[:, 2]  # (m, n) each
        jac = np.zeros((m, 3, 3 * n + 3))
        for k in range(3):
            ax, ay, az = axes[:, k, 0], axes[:, k, 1], axes[:, k, 2]  # (n,) each
            jac[:, 0, k:3 * n:3] = ay * bz - az * by
            jac[:, 1, k:3 * n:3] = az * bx - ax * bz
            jac[:, 2, k:3 * n:3] = ax * by - ay * bx
        jac[:, :, 3 * n:] = np.eye(3)[None]
        return v, jac


def joint_bounds(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Box constraints on the parameters (radians, metres)."""
    lim = np.radians([max(JOINT_LIMITS.get(name, DEFAULT_LIMIT), 1e-6)
                      for name in body.joint_names])
    hi = np.concatenate([np.repeat(lim, 3), np.full(3, ROOT_RANGE)])
    return -hi, hi


def _surface_frames(points: np.ndarray, sv: np.ndarray, st: np.ndarray):
    """Closest surface points (m, 3), unit normals (m, 3) of their faces, and whether each
    point faces its surface point (m,): its closest point is the foot of the perpendicular,
    not a point on the surface's border that the point lies beside.

    Only a facing point can be behind the surface; one beside the border and below its
    plane has not cut into anything, and the penetration term leaves it alone."""
    import igl

    _, face, closest = igl.point_mesh_squared_distance(points, sv, st)
    fn = face_normals(sv, st[face])
    offset = points - closest
    along = np.einsum("ij,ij->i", offset, fn)
    sideways = np.linalg.norm(offset - along[:, None] * fn, axis=1)
    facing = sideways <= FACING_TOLERANCE + 1e-3 * np.abs(along)
    return closest, fn, facing.astype(np.float64)


def residuals(theta: np.ndarray, model: _Model, closest: np.ndarray, normals: np.ndarray,
              facing: np.ndarray) -> np.ndarray:
    lp, lt, lpen, ls = (np.sqrt(x) for x in model.p.lambdas)
    r = model.p.importance
    v = model.vertices(theta)[0]
    d = np.einsum("ij,ij->i", normals, closest)
    s = np.einsum("ij,ij->i", normals, v) - d
    a, b = 1.0 / PENETRATION_WIDTH, model.p.penetration_shift / PENETRATION_WIDTH
    return np.concatenate([
        lp * (r[:, None] * (v - closest)).ravel(),
        lt * r * s,
        lpen * r * facing * (0.5 - np.arctan(a * s + b) / np.pi),
        ls * theta,
    ])


def residual_jacobian(theta: np.ndarray, model: _Model, closest: np.ndarray,
                      normals: np.ndarray, facing: np.ndarray) -> np.ndarray:
    lp, lt, lpen, ls = (np.sqrt(x) for x in model.p.lambdas)
    r = model.p.importance
    v, jv = model.jacobian_vertices(theta)  # (m, 3), (m, 3, P)
    s = np.einsum("ij,ij->i", normals, v) - np.einsum("ij,ij->i", normals, closest)
    a, b = 1.0 / PENETRATION_WIDTH, model.p.penetration_shift / PENETRATION_WIDTH
    jn = np.einsum("ic,icp->ip", normals, jv)  # (m, P): d s / d theta
    dpen = -(a / np.pi) / (1.0 + (a * s + b) ** 2)
    return np.concatenate([
        lp * (r[:, None, None] * jv).reshape(-1, jv.shape[2]),
        lt * r[:, None] * jn,
        lpen * (r * facing * dpen)[:, None] * jn,
        ls * np.eye(jv.shape[2]),
    ])


@dataclass
class RelaxResult:
    """A relaxed pose (see `relax`).

    theta : (3 J + 3,) float, the solution: per joint three angles (radians) from the captured
        local rotation, L_j = L0_j Rx Ry Rz, then the root translation (metres) from `root0`.
    local : (J, 3, 3) float relaxed local rotations; world : WorldPose (J) relaxed world frames.
    vertices : (V, 3) float, metres, the whole relaxed body.
    cost : half the sum of squared residuals at the end of the last round (scipy's cost).
    evaluations : residual evaluations over all rounds; rounds : the rounds run.
    at_limit : how many parameters ended on their box limit.
    """

    theta: np.ndarray
    local: np.ndarray
    world: WorldPose
    vertices: np.ndarray  # (V, 3) the whole relaxed body
    cost: float
    evaluations: int
    rounds: int
    at_limit: int  # parameters on their box limit


def relax(problem: RelaxProblem, rounds: int = 3, max_evaluations: int = 60, *,
          numeric_jacobian: bool = False) -> RelaxResult:
    """Relaxes the pose: `rounds` of pairing with the surface, each a bounded least squares.

    Each round pairs the supportable vertices with their closest surface points, then solves
    the least squares of the module docstring from the last round's solution (trust-region
    reflective, box constraints `JOINT_LIMITS` in degrees per axis and `ROOT_RANGE` metres).

    Parameters
    ----------
    problem : RelaxProblem
        The body, its captured pose, its supportable vertices with their importance, and the
        surface (metres).
    rounds : int, default 3
        Rounds of pairing and solving.
    max_evaluations : int, default 60
        Residual evaluations allowed per round.
    numeric_jacobian : bool, default False
        Swaps the analytic Jacobian for finite differences (a reference).

    Returns
    -------
    RelaxResult
        The parameters theta (3 J + 3,) (radians per joint axis, then the root translation in
        metres), the relaxed local rotations (J, 3, 3) and world frames (J), the whole relaxed
        skin (V, 3) in metres, the last round's cost, the evaluations over all rounds and the
        number of parameters at their limit.
    """
    from solver.body.skinning import skin

    model = _Model(problem)
    lo, hi = joint_bounds(problem.body)
    theta = np.zeros(3 * model.n + 3)
    sv = np.asarray(problem.surface_vertices, dtype=np.float64)
    st = np.asarray(problem.surface_triangles, dtype=np.int64)
    evaluations = 0
    cost = 0.0
    for _ in range(rounds):
        v = model.vertices(theta)[0]
        pairing = _surface_frames(v, sv, st)
        sol = least_squares(residuals, theta,
                            jac="2-point" if numeric_jacobian else residual_jacobian,
                            bounds=(lo, hi),
                            method="trf", tr_solver="lsmr", max_nfev=max_evaluations, ftol=FTOL, xtol=1e-8,
                            x_scale="jac",
                            args=(model, *pairing))
        theta, cost = sol.x, float(sol.cost)
        evaluations += sol.nfev
    local, world = model.pose(theta)
    verts, _ = skin(problem.body, WorldPose(world.positions, world.rotmats), normals=False)
    at_limit = int(np.sum((theta <= lo + 1e-9) | (theta >= hi - 1e-9)))
    return RelaxResult(theta, local, world, verts, cost, evaluations, rounds, at_limit)
