"""Fitting the supporting surface: the paper's section 5 and appendix A.

Given posed bodies (their vertices, normals and importance) and a quad control mesh V0, find the
control mesh whose level-s Catmull-Clark surface S V supports each body where it needs support,
smoothly, without cutting into it. Each iteration:

1. subdivides (the operator S is built once) and takes the surface normals;
2. pairs every important body vertex b_k with its closest surface vertex s(k) (a KD-tree);
3. minimises, as a quadratic programme solved by OSQP,

   E = (1 / sum rho) sum_k rho_k [(1 - tau) |b_k - v_s(k)|^2 + tau (n_s(k) . (b_k - v_s(k)))^2]
       + (sigma / n0) |L V|^2 + gamma sum_fixed |v_j - v0_j|^2

       + (anchor / n0) sum_all |v_j - v0_j|^2

   where L is the cotangent Laplacian of the control mesh, tau rises from 0 to tau_max over the
   first iterations, subject to every surface vertex near a body staying on the outer side of the
   tangent plane at its closest body vertex, less the softness margin:
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
later) and are active only within that radius; OSQP is set up again only when that set changes
and is otherwise updated in place, warm-started from the last solution, and its status is checked
every time. The loop judges each iterate by the programme's own objective, the energy plus the
cost of the non-penetration demands it leaves unmet, and stops once tau has reached tau_max and
that has not improved by `tolerance` (relative) in PATIENCE iterations, or after
`max_iterations`; the best iterate is kept.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from solver.contact.supported import SupportedBody
from solver.surface.subdivision import Subdivision, subdivision

REACH = 0.5  # metres: a person whose supported points are all farther from the surface is an error
CONSTRAINT_RADIUS = 0.12  # metres: surface vertices this close to a body get a non-penetration row
FACING_SCALE = 0.1  # metres a body normal's turn away from the surface counts as, in the search
# the farthest a pairing in that search can be while its skin point lies within CONSTRAINT_RADIUS
FACING_REACH = float(np.hypot(CONSTRAINT_RADIUS, 2 * FACING_SCALE)) + 1e-9
INSIDE_REACH = 0.3  # metres: no body part is thicker than twice this
EXIT_SCALE = 1.0  # the same, for a surface vertex inside a body: it leaves through the skin
                  # facing against the surface's normal, behind the body (below a seated one)
TAU_RAMP = 5  # iterations over which tau rises from 0 to tau_max
PATIENCE = 5  # iterations without improvement before the loop stops
EPS_ABS, EPS_REL = 1e-5, 1e-4  # OSQP tolerances (metres for the constraints)
SLACK_WEIGHT = 1e3  # cost per m^2 of a non-penetration row left unmet (soft constraints)
DENSE_UP_TO = 150  # control vertices up to which the Hessian is built dense
PROXIMAL = 0.01  # weight of the pull to the current control mesh (per coordinate)


class FitError(ValueError):
    """A fit that cannot run or cannot go on (and why)."""


@dataclass(frozen=True)
class FitParams:
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


@dataclass
class FitResult:
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


def control_laplacian(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """(n, n) cotangent Laplacian of a polygon control mesh (libigl's polygon Laplacian)."""
    import igl

    corners, sizes = igl.polygon_corners(np.asarray(faces, dtype=np.int64))
    lap, _, _ = igl.cotmatrix(np.asarray(vertices, dtype=np.float64), corners, sizes)
    return sp.csr_matrix(lap)


class _Programme:
    """The QP over the control vertices x (3 n0) and one slack per non-penetration row.

    Rows are soft: n . (S x)_r + slack_r >= lower_r with slack_r >= 0 costing SLACK_WEIGHT
    slack^2, so overlapping bodies that no surface can clear at once leave a measured residual
    instead of an infeasible programme. The objective's pattern for x is fixed for the whole
    fit; OSQP is set up again only when the set of rows changes, and updated in place otherwise.
    """

    def __init__(self, sub: Subdivision, lap: sp.csr_matrix, n0: int, slack_weight: float):
        import osqp

        self._osqp = osqp
        self.n0 = n0
        self.slack_weight = slack_weight
        s = sub.matrix.tocsr()
        self.s = s
        coupling = (s.T @ s).tocsr() + (lap.T @ lap) + sp.identity(n0)
        coupling.data[:] = 1.0
        block = sp.kron(sp.csr_matrix(np.ones((3, 3))), coupling).tocsc()
        self.x_pattern = sp.triu(block, format="csc")
        self.x_pattern.sort_indices()
        self.rows: np.ndarray | None = None
        self.solver = None
        self.setups = 0

    def _setup_patterns(self, rows: np.ndarray) -> None:
        n, r = 3 * self.n0, len(rows)
        # objective: [P_x 0; 0 2 w I_r]
        p = sp.block_diag([self.x_pattern, sp.identity(r)], format="csc")
        p.sort_indices()
        self.p_pattern = p
        self.p_rows, self.p_cols = _coo_of(p)
        self.p_is_x = self.p_cols < n
        self.p_xr, self.p_xc = self.p_rows[self.p_is_x], self.p_cols[self.p_is_x]
        # constraints: [n.S  I_r; I_x 0; 0 I_r]
        sub = self.s[rows]
        self.s_rows = sub
        a = sp.vstack([
            sp.hstack([sub, sub, sub, sp.identity(r)]),
            sp.hstack([sp.identity(n), sp.csr_matrix((n, r))]),
            sp.hstack([sp.csr_matrix((r, n)), sp.identity(r)]),
        ], format="csc")
        a.sort_indices()
        self.a_pattern = a
        ar, ac = _coo_of(a)
        plane = (ar < r) & (ac < n)
        self.a_plane = plane
        self.a_row = np.where(plane, ar, 0)
        self.a_axis = np.where(plane, ac // self.n0, 0)
        self.a_s = np.ones(len(ar))
        self.a_s[plane] = np.asarray(sub[ar[plane], ac[plane] % self.n0]).ravel()

    def _set_up(self, p_values, q, a_values, low, high) -> None:
        p = self.p_pattern.copy()
        p.data = p_values
        a = self.a_pattern.copy()
        a.data = a_values
        self.solver = self._osqp.OSQP()
        # no Ruiz equilibration: the variables are metres already, and equilibrating the stiff
        # slack columns against the soft control vertices left some programmes at OSQP's
        # iteration limit (thousands of iterations where 100-200 do without)
        self.solver.setup(p, q, a, low, high, verbose=False, warm_starting=True, polishing=False,
                          eps_abs=EPS_ABS, eps_rel=EPS_REL, max_iter=20000, adaptive_rho=True,
                          scaling=0)
        self.setups += 1

    def solve(self, p_x: np.ndarray | sp.csr_matrix, q: np.ndarray, rows: np.ndarray, normals: np.ndarray,
              lower: np.ndarray, x0: np.ndarray, step: float) -> tuple[np.ndarray, str, float]:
        n, r = 3 * self.n0, len(rows)
        fresh = self.rows is None or not np.array_equal(rows, self.rows)
        if fresh:
            self.rows = rows
            self._setup_patterns(rows)
        p_values = np.full(len(self.p_rows), 2 * self.slack_weight)
        p_values[self.p_is_x] = np.asarray(p_x[self.p_xr, self.p_xc]).ravel()
        a_values = np.where(self.a_plane, self.a_s * normals[self.a_row, self.a_axis], 1.0)
        q_full = np.concatenate([q, np.zeros(r)])
        low = np.concatenate([lower, x0 - step, np.zeros(r)])
        high = np.concatenate([np.full(r, np.inf), x0 + step, np.full(r, np.inf)])
        if fresh:
            self._set_up(p_values, q_full, a_values, low, high)
        else:
            self.solver.update(Px=p_values, q=q_full, Ax=a_values, l=low, u=high)
        slack0 = np.maximum(0.0, lower - _normals_dot(normals, self.s_rows @ x0.reshape(3, -1).T))
        self.solver.warm_start(x=np.concatenate([x0, slack0]))
        res = self.solver.solve(raise_error=False)
        status = str(res.info.status)
        if status not in ("solved", "solved inaccurate"):
            raise FitError(f"The surface's quadratic programme failed: OSQP says {status!r}")
        return res.x[:n], status, float(res.x[n:].max(initial=0.0))


def _normals_dot(normals: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", normals, points)


def _coo_of(m: sp.csc_matrix) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of each stored entry, in the matrix's own data order (CSC)."""
    cols = np.repeat(np.arange(m.shape[1]), np.diff(m.indptr))
    return m.indices.copy(), cols


def _stack(targets: Sequence[SupportedBody]):
    points = np.concatenate([t.vertices for t in targets])
    normals = np.concatenate([t.normals for t in targets])
    rho = np.concatenate([t.importance for t in targets])
    owner = np.concatenate([np.full(len(t.vertices), k) for k, t in enumerate(targets)])
    return points, normals, rho, owner


def fit_surface(control: np.ndarray, faces: np.ndarray, targets: Sequence[SupportedBody],
                params: FitParams = FitParams(),
                progress: Callable[[int, float, float], None] | None = None) -> FitResult:
    """Fits the control mesh to the bodies (see the module docstring).

    progress : optional callback (iteration, energy, tau).
    """
    start = time.perf_counter()
    v0 = np.asarray(control, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n0 = len(v0)
    if not targets:
        raise FitError("Expected at least one body to support, got none")
    for j in params.fixed:
        if not 0 <= j < n0:
            raise FitError(f"Expected fixed control vertices in 0..{n0 - 1}, got {j}")
    sub = subdivision(n0, faces, params.level, params.creases or None)
    s = sub.matrix
    lap = control_laplacian(v0, faces)
    points, normals, rho, owner = _stack(targets)
    important = np.flatnonzero(rho > 1e-3)
    surface0 = s @ v0
    near, _ = cKDTree(surface0).query(points[important])
    for k, t in enumerate(targets):
        mine = owner[important] == k
        if not mine.any():
            raise FitError(f"{t.label}: no body part to support faces the surface (nothing has "
                           "importance)")
        if near[mine].min() > REACH:
            raise FitError(f"{t.label} is entirely outside the surface's reach: its nearest "
                           f"supported point is {near[mine].min():.2f} m from the surface "
                           f"(reach {REACH} m); move the person or the surface")
    b_imp, w_imp = points[important], rho[important]
    total = w_imp.sum()
    body_tree = cKDTree(np.concatenate([points, FACING_SCALE * normals], axis=1))
    body_tree3 = cKDTree(points)
    exit_tree = cKDTree(np.concatenate([points, EXIT_SCALE * normals], axis=1))
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
    if dense:
        diagonal = diagonal.toarray()
    prog = _Programme(sub, lap, n0, SLACK_WEIGHT / people)
    v = v0.copy()
    energies: list[float] = []
    statuses: list[str] = []
    residuals: list[float] = []
    member = np.zeros(s.shape[0], dtype=bool)
    # non-penetration rows on the surface vertices that are vertex points of the level before
    # (every other vertex each way, about 2 cm apart on a seat): a quarter of the rows
    sampled_ids = np.arange(sub.steps[-1].matrix.shape[1] if sub.steps else s.shape[0])
    # rows start on every sampled vertex a body could reach, so that the set (and OSQP's set-up)
    # seldom changes as the surface moves
    reach, _ = body_tree3.query(surface0[sampled_ids], distance_upper_bound=REACH)
    member[sampled_ids[np.isfinite(reach)]] = True
    best = None
    terms: dict = {}
    stop = f"reached the iteration limit ({params.max_iterations})"
    iteration = 0
    for iteration in range(1, params.max_iterations + 1):
        tau = params.tau_max * min(1.0, (iteration - 1) / TAU_RAMP)
        surf = s @ v
        surf_n = sub.normals(surf)
        # data: each important body point pulls its closest surface vertex
        # body points farther than the pull range do not pull (yet): the surface grows towards
        # the bodies from where the designer put it, instead of reaching across the scene
        surf_tree = cKDTree(surf)
        gap, pair = surf_tree.query(b_imp, distance_upper_bound=params.pull_range)
        reached = np.isfinite(gap)
        if not reached.all():  # the energy still counts them, at their nearest surface vertex
            pair[~reached] = surf_tree.query(b_imp[~reached])[1]
        w_now = np.where(reached, w_imp, 0.0)
        w = np.bincount(pair, w_now, minlength=len(surf))
        target = np.stack([np.bincount(pair, w_now * b_imp[:, a], minlength=len(surf))
                           for a in range(3)], axis=1)
        used = w > 0
        target[used] /= w[used, None]
        # only the paired surface vertices carry data terms: their rows of S (a level-s vertex
        # depends on a few control vertices, so on large meshes the Hessian's blocks stay
        # sparse; on small ones dense products are quicker)
        paired = np.flatnonzero(used)
        s_p = s[paired].toarray() if dense else s[paired]
        w_p, n_p, t_p = w[paired] / total, surf_n[paired], target[paired]
        nt = np.einsum("ij,ij->i", n_p, t_p)  # n . p per paired surface vertex
        blocks = [[None] * 3 for _ in range(3)]
        g = np.zeros(3 * n0)
        for a in range(3):
            for b in range(a, 3):
                c = w_p * (tau * n_p[:, a] * n_p[:, b] + ((1 - tau) if a == b else 0.0))
                blocks[a][b] = (s_p.T * c) @ s_p if dense else s_p.T @ sp.diags(c) @ s_p
            ga = w_p * ((1 - tau) * t_p[:, a] + tau * n_p[:, a] * nt)
            g[a * n0:(a + 1) * n0] = s_p.T @ ga + fixed * v0[:, a]
            # the smoothness, the fixed and anchor pulls, and a proximal pull to the current
            # control mesh, which damps the alternation between pairing and solving
            blocks[a][a] = blocks[a][a] + diagonal
        if dense:  # only the upper blocks are read
            zero = np.zeros((n0, n0))
            h = np.block([[blk if blk is not None else zero for blk in row] for row in blocks])
        else:
            h = sp.bmat(blocks, format="csr")
        # non-penetration: stay outside the tangent plane at the closest body vertex
        # (only the sampled surface vertices carry rows, so only they are looked up)
        sv, sn = surf[sampled_ids], surf_n[sampled_ids]
        # (a vertex whose search finds nothing within reach is far from every body: no row)
        _, near_s = body_tree.query(np.concatenate([sv, -FACING_SCALE * sn], axis=1),
                                    distance_upper_bound=FACING_REACH)
        far = near_s == len(points)
        near_s[far] = 0
        dist = np.where(far, np.inf, np.linalg.norm(points[near_s] - sv, axis=1))
        # a surface vertex inside a body (behind its nearest skin vertex) is always constrained,
        # however far the skin it faces: it must get out (no body part is so thick that a point
        # inside it lies farther than INSIDE_REACH from its skin)
        _, nearest = body_tree3.query(sv, distance_upper_bound=INSIDE_REACH)
        outside = nearest == len(points)
        nearest[outside] = 0
        inside_s = ~outside & (np.einsum("ij,ij->i", sv - points[nearest], normals[nearest]) < 0)
        if inside_s.any():
            _, exits = exit_tree.query(np.concatenate([sv[inside_s],
                                                       -EXIT_SCALE * sn[inside_s]], axis=1))
            near_s[inside_s] = exits
        closest = np.zeros(len(surf), dtype=np.int64)
        closest[sampled_ids] = near_s
        wanted = np.zeros(len(surf), dtype=bool)
        wanted[sampled_ids] = (dist <= CONSTRAINT_RADIUS) | inside_s
        # rows only join the programme (and stay, inactive when not wanted) so that OSQP is set
        # up again only when a new surface vertex comes near a body
        member |= wanted
        rows = np.flatnonzero(member)
        cn = np.zeros((len(surf), 3))
        cn[rows] = normals[closest[rows]]
        lower = np.einsum("ij,ij->i", cn[rows], points[closest[rows]]) - params.margin
        lower[~wanted[rows]] = -np.inf
        demanded = lower.copy()
        # a violated row need only improve by most of a step per iteration (it stays feasible
        # within the trust region)
        now = np.einsum("ij,ij->i", cn[rows], surf[rows])
        lower = np.minimum(lower, now + 0.8 * params.step)
        x0 = v.T.reshape(-1)
        g += proximal * x0
        x, status, residual = prog.solve(2 * h, -2 * g, rows, cn[rows], lower, x0, params.step)
        statuses.append(status)
        residuals.append(residual)
        v = x.reshape(3, n0).T
        new_surf = s @ v
        energy, terms = _energy(new_surf, v, v0, pair, b_imp, w_imp, surf_n, tau, smooth, fixed)
        # what the loop judges is the programme's own objective: the energy plus the cost of
        # the rows the step left unmet (against the whole demand, not the step's share of it),
        # so an iterate that cuts into a body does not count as the best
        short = np.maximum(0.0, demanded - np.einsum("ij,ij->i", cn[rows], new_surf[rows]))
        energy += prog.slack_weight * float(np.sum(short ** 2))
        terms["unmet_rows_m2"] = float(np.sum(short ** 2))
        terms["laplacian_m2"] = float(np.mean(np.sum((lap @ v) ** 2, axis=1)))
        energies.append(energy)
        # energies are comparable only at the same tau: keep and judge those after the ramp
        if best is None or energy < best[0] or iteration <= TAU_RAMP + 1:
            best = (energy, v.copy(), dict(terms), iteration)
        if progress is not None:
            progress(iteration, energy, tau)
        post = energies[TAU_RAMP:]
        if len(post) > PATIENCE and min(post) > min(post[:-PATIENCE]) * (1 - params.tolerance):
            stop = (f"converged: the best energy has not improved by {100 * params.tolerance:g} %"
                    f" in {PATIENCE} iterations (best {best[0]:.6g} at iteration {best[3]})")
            break
    _, v, terms, best_iteration = best
    surface = s @ v
    terms["best_iteration"] = best_iteration
    terms["qp_setups"] = prog.setups
    terms["largest_row_residual_m"] = residuals[best_iteration - 1] if residuals else 0.0
    return FitResult(v, faces, surface, sub.faces, iteration, stop, energies, terms,
                     time.perf_counter() - start, statuses, sub)


def _energy(surf, v, v0, pair, b, w, surf_n, tau, smooth, fixed) -> tuple[float, dict]:
    """The fit energy at control vertices v for the iteration's pairing."""
    diff = b - surf[pair]
    total = max(w.sum(), 1e-300)
    point = float(np.sum(w * np.einsum("ij,ij->i", diff, diff)) / total)
    plane = float(np.sum(w * np.einsum("ij,ij->i", diff, surf_n[pair]) ** 2) / total)
    smooth_e = float(sum(v[:, a] @ (smooth @ v[:, a]) for a in range(3)))
    fixed_e = float(np.sum(fixed[:, None] * (v - v0) ** 2))  # gamma on fixed, anchor on all
    data = (1 - tau) * point + tau * plane
    return data + smooth_e + fixed_e, {"point_to_point_m2": point, "point_to_plane_m2": plane,
                                       "smoothness": smooth_e, "fixed": fixed_e, "tau": tau}
