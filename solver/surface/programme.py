"""The fit's quadratic programme: the control vertices and one slack per non-penetration row.

Both take only the rows that could bind (within NEAR_ROW of their bound where the step starts,
then any other the solution breaks, until none does). Small meshes (a dense Hessian) are solved
exactly by DAQP, a dual active-set solver (`DenseProgramme`); larger ones by OSQP, set up again
when the rows taken change and updated in place otherwise (`Programme`)."""

from __future__ import annotations

import functools
import threading
import time

import numpy as np
import scipy.sparse as sp


EPS_ABS, EPS_REL = 1e-5, 1e-4  # OSQP tolerances (metres for the constraints)
NEAR_ROW = 0.01  # m: rows this close to binding at the step's start join the first try
ROW_TOLERANCE = 1e-7  # m: a row left out that the solution breaks by more joins the next try
BOX_TOLERANCE = 1e-9  # m: a coordinate left free that leaves its trust region by more is held
NO_TIME_LIMIT = 1e10  # s: OSQP's time limit without a deadline (its own default)
MAX_ITER = 20000  # OSQP's iterations per solve at most
# Between runs of OSQP's iterations a solve asks the fit's `cancel` (a studio's newer edit): runs
# of POLL_ITERATIONS first, then as many as take about POLL_SECONDS, a multiple of
# POLL_ITERATIONS. OSQP goes on from where a run stopped, its step size adapted every 50
# iterations and its stop checked every 25 as in one run, so a solve in runs is the same as one
# solve, bit for bit (a run that ended on its time limit would not be: its step size restarts).
POLL_ITERATIONS = 50
POLL_SECONDS = 0.1
# DAQP's exit flag for a solve that reached its time limit (DAQP then goes on from where it
# stopped when asked to solve again): a small mesh's solve runs POLL_SECONDS at a time, the
# `cancel` and the deadline asked between runs
DAQP_TIME_LIMIT = -7


NOT_A_NUMBER = ("The surface's quadratic programme has a value that is not a number in its "
                "objective")


class ProgrammeError(ValueError):
    """The solver (DAQP or OSQP) could not solve the programme."""


class DeadlinePassed(Exception):
    """A solve stopped at the programme's `deadline` (the caller's time is up), or because the
    fit's `cancel` said so between runs of OSQP's iterations."""


class _Claimed:
    """What both programmes share: the control vertex count, the cost of an unmet row, the
    set-ups made, and the claim a fit holds while it solves one (a warm refit reuses the last
    fit's: one held by another fit running now is not shared, the refit sets up its own)."""

    def __init__(self, points: sp.spmatrix, n0: int, slack_weight: float):
        self.n0 = n0
        self.slack_weight = slack_weight
        self.s = sp.csr_matrix(points)
        self.setups = 0
        self._in_use = threading.Lock()
        # time.monotonic() at which a solve stops (`DeadlinePassed`), None for none: the fit
        # sets it while it runs with one, so that a large programme's solve (seconds) ends there
        self.deadline: float | None = None
        # the fit's cancel (a callable), asked between runs of a large programme's iterations
        self.cancel = None

    def _check_deadline(self) -> None:
        """`DeadlinePassed` once the `deadline` has passed: asked before each solver run."""
        if self.deadline is not None and time.monotonic() >= self.deadline:
            raise DeadlinePassed

    def claim(self) -> bool:
        """Whether this programme is now the caller's alone (False: another fit solves it)."""
        return self._in_use.acquire(blocking=False)

    def release(self) -> None:
        """Gives the claimed programme back (a later warm refit may claim it)."""
        self._in_use.release()

    def _wanted(self, rows: np.ndarray, normals: np.ndarray, lower: np.ndarray):
        """The rows wanted now (a finite bound; the others never bind): their points, normals
        and bounds, and n . (S x) of them as a function of x (3 n0), from their own rows of S
        (the same sums, term by term, as the product with all of S)."""
        wanted = np.flatnonzero(np.isfinite(lower))
        points, plane_normals = rows[wanted], normals[wanted]
        s_rows = self.s[points]

        def plane(x: np.ndarray) -> np.ndarray:
            return _normals_dot(plane_normals, s_rows @ x.reshape(3, self.n0).T)

        return points, plane_normals, lower[wanted], plane


class Programme(_Claimed):
    """The QP over the control vertices x (3 n0) and one slack per non-penetration row.

    Rows are soft: n . (S x)_r + slack_r >= lower_r with slack_r >= 0 costing SLACK_WEIGHT
    slack^2, so overlapping bodies that no surface can clear at once leave a measured residual
    instead of an infeasible programme. The objective's pattern for x is fixed for the whole
    fit; OSQP takes the rows that could bind (`solve`), is set up again only when they change and
    updated in place otherwise, and starts from the last solve: its solution, its duals (a row
    on the same surface point takes that row's) and its adapted step size rho.
    A fit `claim`s the programme it solves (a warm refit reuses the last fit's): one held by
    another fit running now is not shared, the refit sets up its own.
    """

    def __init__(self, points: sp.spmatrix, lap: sp.csr_matrix, n0: int, slack_weight: float):
        """points: (P, n0) the surface points rows may hold, as linear maps of the control
        vertices (the level-s vertices, then any more); lap: (n0, n0) the control Laplacian."""
        import osqp

        super().__init__(points, n0, slack_weight)
        self._osqp = osqp
        s = self.s
        coupling = (s.T @ s).tocsr() + (lap.T @ lap) + sp.identity(n0)
        coupling.data[:] = 1.0
        block = sp.kron(sp.csr_matrix(np.ones((3, 3))), coupling).tocsc()
        self.x_pattern = sp.triu(block, format="csc")
        self.x_pattern.sort_indices()
        self.p_xr, self.p_xc = _coo_of(self.x_pattern)  # the objective's entries for x (first)
        self.rows: np.ndarray | None = None
        self.solver = None
        self._duals: tuple | None = None  # the last solve's rows, duals and OSQP's rho

    def _setup_patterns(self, rows: np.ndarray) -> None:
        """The programme's matrices for these rows, in OSQP's CSC layout, written directly:
        the objective [P_x 0; 0 2 w I_r] and the constraints [n.S I_r; I_x 0; 0 I_r], with
        where each stored constraint value comes from (row, axis, S's weight)."""
        n, r, n0 = 3 * self.n0, len(rows), self.n0
        x = self.x_pattern
        span = np.arange(r)
        self.p_pattern = sp.csc_matrix(
            (np.ones(x.nnz + r), np.concatenate([x.indices, n + span]),
             np.concatenate([x.indptr, x.nnz + 1 + span])), shape=(n + r, n + r))
        self.p_is_x = np.arange(x.nnz + r) < x.nnz
        sub = self.s[rows].tocoo()
        sub.sum_duplicates()
        k = len(sub.data)
        coordinates = np.arange(n)
        row = np.concatenate([np.tile(sub.row, 3), r + coordinates, span, r + n + span])
        col = np.concatenate([(np.arange(3)[:, None] * n0 + sub.col).ravel(), coordinates,
                              n + span, n + span])
        order = np.lexsort((row, col))
        plane = np.zeros(len(row), dtype=bool)
        plane[:3 * k] = True
        axis = np.zeros(len(row), dtype=np.int64)
        axis[:3 * k] = np.repeat(np.arange(3), k)
        weight = np.ones(len(row))
        weight[:3 * k] = np.tile(sub.data, 3)
        row, plane, axis, weight = row[order], plane[order], axis[order], weight[order]
        indptr = np.concatenate([[0], np.cumsum(np.bincount(col, minlength=n + r))])
        self.a_pattern = sp.csc_matrix((np.ones(len(row)), row, indptr),
                                       shape=(2 * r + n, n + r))
        self.a_plane = plane
        self.a_row = np.where(plane, row, 0)
        self.a_axis = axis
        self.a_s = weight

    def _set_up(self, p_values, q, a_values, low, high) -> None:
        p = self.p_pattern.copy()
        p.data = p_values
        a = self.a_pattern.copy()
        a.data = a_values
        self.solver = _osqp_solver(self._osqp)()
        # no Ruiz equilibration: the variables are metres already, and equilibrating the stiff
        # slack columns against the soft control vertices left some programmes at OSQP's
        # iteration limit (thousands of iterations where 100-200 do without)
        try:
            # OSQP's step size as the last solve adapted it (a fresh set-up starts from 0.1)
            rho = {"initial_rho": self._duals[2]} if self._duals is not None else {}
            self.solver.setup(p, q, a, low, high, verbose=False, warm_starting=True, **rho,
                              polishing=False, eps_abs=EPS_ABS, eps_rel=EPS_REL,
                              max_iter=MAX_ITER,
                              adaptive_rho=True, scaling=0)
        except self._osqp.OSQPException as exc:  # (a programme that is not convex)
            self.rows = None  # set up again next time
            raise ProgrammeError(f"The surface's quadratic programme could not be set up: OSQP "
                                 f"error {exc}") from None
        self.setups += 1

    def solve(self, p_x: np.ndarray | sp.csr_matrix, q: np.ndarray, rows: np.ndarray,
              normals: np.ndarray, lower: np.ndarray, x0: np.ndarray, step: float
              ) -> tuple[np.ndarray, str, float]:
        """The step over the rows that could bind: those within NEAR_ROW of their bound where
        it starts, then any other the solution breaks by more than ROW_TOLERANCE, until none
        does (a row left out is inactive at the solution, which is so the optimum of the whole
        programme; the rows not wanted now, a bound of -inf, never bind). OSQP is set up again
        when the rows taken change and updated in place otherwise."""
        points, plane_normals, bounds, plane = self._wanted(rows, normals, lower)
        now = plane(x0)
        taking = bounds > now - NEAR_ROW
        while True:
            take = np.flatnonzero(taking)
            x, status, residual = self._solve_rows(
                p_x, q, points[take], plane_normals[take], bounds[take], now[take], x0, step)
            broken = ~taking & (plane(x) < bounds - ROW_TOLERANCE)
            if not broken.any():
                return x, status, residual
            taking |= broken

    def _solve_polled(self):
        """OSQP's solve; with a `cancel`, in runs of iterations (POLL_ITERATIONS, then about
        POLL_SECONDS each) with `cancel` (and the `deadline`) asked between them
        (`DeadlinePassed` when it says so, or has passed), the same solve as one run."""
        if self.cancel is None:
            return self.solver.solve(raise_error=False)
        done, run = 0, POLL_ITERATIONS
        try:
            while True:
                run = min(run, MAX_ITER - done)
                self.solver.update_settings(max_iter=run)
                began = time.monotonic()
                res = self.solver.solve(raise_error=False)
                done += res.info.iter
                # (a run cut short by its iteration limit: maximum iterations, or solved
                # inaccurate, which OSQP says at its limit when the looser tolerance holds; it
                # could say infeasible inaccurate there too, returned as a failure, but the
                # programme is always feasible, each row with its slack, and bounded, the trust
                # region a box)
                if res.info.iter < run or done >= MAX_ITER or str(res.info.status) not in (
                        "maximum iterations reached", "solved inaccurate"):
                    return res
                left = NO_TIME_LIMIT if self.deadline is None else \
                    self.deadline - time.monotonic()  # (one reading: OSQP takes none <= 0)
                if self.cancel() or left <= 0:
                    raise DeadlinePassed
                if self.deadline is not None:  # (OSQP's time limit counts from each run)
                    self.solver.update_settings(time_limit=left)
                each = (time.monotonic() - began) / max(res.info.iter, 1)
                run = POLL_ITERATIONS * max(1, int(POLL_SECONDS / max(each, 1e-9)) //
                                            POLL_ITERATIONS)
        finally:
            self.solver.update_settings(max_iter=MAX_ITER)

    def _warm_duals(self, rows: np.ndarray) -> np.ndarray | None:
        """OSQP's duals to start from: each row's from the last solve where that solve held a
        row on the same surface point (0 for a new one), the trust region's as they were."""
        if self._duals is None:
            return None
        before, y, _ = self._duals
        n, r, b = 3 * self.n0, len(rows), len(before)
        plane, slack = np.zeros(r), np.zeros(r)
        if b:
            order = np.argsort(before, kind="stable")
            at = np.minimum(np.searchsorted(before[order], rows), b - 1)
            found = before[order][at] == rows
            match = order[at][found]
            plane[found], slack[found] = y[match], y[b + n + match]
        return np.concatenate([plane, y[b:b + n], slack])

    def _solve_rows(self, p_x, q, rows, normals, lower, now, x0, step):
        """OSQP on the programme with these rows (every one wanted)."""
        n, r = 3 * self.n0, len(rows)
        fresh = self.rows is None or not np.array_equal(rows, self.rows)
        if fresh:
            self.rows = rows
            self._setup_patterns(rows)
        p_values = np.full(len(self.p_is_x), 2 * self.slack_weight)
        p_values[self.p_is_x] = np.asarray(p_x[self.p_xr, self.p_xc]).ravel()
        a_values = self.a_s.copy()
        a_values[self.a_plane] *= normals[self.a_row[self.a_plane], self.a_axis[self.a_plane]]
        q_full = np.concatenate([q, np.zeros(r)])
        low = np.concatenate([lower, x0 - step, np.zeros(r)])
        high = np.concatenate([np.full(r, np.inf), x0 + step, np.full(r, np.inf)])
        began = time.monotonic()  # (OSQP counts its set-up or update into its time limit)
        if fresh:
            self._set_up(p_values, q_full, a_values, low, high)
        else:
            self.solver.update(Px=p_values, q=q_full, Ax=a_values, l=low, u=high)
        slack0 = np.maximum(0.0, lower - now)
        self.solver.warm_start(x=np.concatenate([x0, slack0]), y=self._warm_duals(rows))
        # OSQP's own time limit (its default, 1e10 s, without a deadline): a solve that ends
        # before it is the same either way
        self._check_deadline()
        left = NO_TIME_LIMIT if self.deadline is None else self.deadline - began
        self.solver.update_settings(time_limit=min(left, NO_TIME_LIMIT))
        res = self._solve_polled()
        status = str(res.info.status)
        if status == "run time limit reached":
            raise DeadlinePassed
        if status not in ("solved", "solved inaccurate"):
            self._duals = None
            raise ProgrammeError(f"The surface's quadratic programme failed: OSQP says "
                                 f"{status!r}")
        rho = float(res.info.rho_estimate)
        if np.all(np.isfinite(res.y)) and np.isfinite(rho) and rho > 0:
            self._duals = (rows.copy(), res.y.copy(), rho)
        return res.x[:n], status, float(res.x[n:].max(initial=0.0))


@functools.lru_cache(maxsize=1)
def _osqp_solver(osqp) -> type:
    """OSQP's solver class, whose set-up also takes `initial_rho`: the step size it factors
    its first system with. OSQP's own `rho` setting at set-up builds the solver with that step
    size and then sets it again, factoring the same system a second time (4 ms of a 10 ms
    set-up on six_overlapping's programmes); this one factors it once, to the same bits."""

    class Solver(osqp.OSQP):
        def update_settings(self, **kwargs):
            rho = kwargs.pop("initial_rho", None)
            if rho is not None:  # (asked only by the set-up, before the solver is built)
                self.settings.rho = rho
            super().update_settings(**kwargs)

    return Solver


def _normals_dot(normals: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", normals, points)


@functools.lru_cache(maxsize=4)
def _strictly_lower(n: int) -> np.ndarray:
    """Where an n x n matrix's entries below its diagonal are (shared, so read-only)."""
    below = np.tri(n, k=-1, dtype=bool)
    below.flags.writeable = False
    return below


def _coo_of(m: sp.csc_matrix) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of each stored entry, in the matrix's own data order (CSC)."""
    cols = np.repeat(np.arange(m.shape[1]), np.diff(m.indptr))
    return m.indices.copy(), cols


class DenseProgramme(_Claimed):
    """The same programme on a small mesh, solved exactly by DAQP (a dual active-set method;
    each row's slack is DAQP's soft constraint, weighted as SLACK_WEIGHT), in the coordinates
    z = R x of the dense Hessian's Cholesky factor R (LAPACK), where the Hessian is the identity.

    Only the rows that could bind take part: those within NEAR_ROW of their bound where the
    step starts, then any other the solution breaks, until none does; likewise the trust
    region's rows, taken for the coordinates the solution moves out of it. A row left out is
    inactive at the solution, so it is the optimum of the whole programme; the rows not wanted
    now (a bound of -inf) never bind. Each try is a fresh set-up (small: the Hessian is at most
    3 DENSE_UP_TO square, a try has tens to a few hundred rows), counted in `setups` (a fit
    reports them as `qp_setups`). Should DAQP fail there (it drops the trust-region row of a
    coordinate some 1e11 times stiffer than a metre; it can cycle on badly scaled programmes),
    DAQP tries again factoring the Hessian itself, with the trust region as simple bounds, and
    failing that OSQP solves the step (`Programme`, set up on first need; counted in
    `fallbacks`)."""

    def __init__(self, points: sp.spmatrix, lap: sp.csr_matrix, n0: int, slack_weight: float):
        import daqp

        super().__init__(points, n0, slack_weight)
        self._daqp = daqp
        self._dense: np.ndarray | None = None  # S as a dense array, made on first need
        self.lap = lap
        self.fallbacks = 0
        self._fallback: Programme | None = None
        self._ahead: tuple | None = None  # (P, Hessian, its factor) made by `prepare`
        self._identity = np.eye(3 * n0)  # the Hessian in z, for DAQP (which only reads it)

    def solve(self, p_x: np.ndarray | sp.csr_matrix, q: np.ndarray, rows: np.ndarray,
              normals: np.ndarray, lower: np.ndarray, x0: np.ndarray, step: float
              ) -> tuple[np.ndarray, str, float]:
        failures = []
        for factored in (True, False):
            try:
                return self._solve_daqp(p_x, q, rows, normals, lower, x0, step, factored)
            except ProgrammeError as exc:
                failures.append(str(exc))
        if self._fallback is None:
            self._fallback = Programme(self.s, self.lap, self.n0, self.slack_weight)
        self.fallbacks += 1
        self._fallback.deadline, self._fallback.cancel = self.deadline, self.cancel
        try:
            return self._fallback.solve(p_x, q, rows, normals, lower, x0, step)
        except ProgrammeError as osqp_failed:
            raise ProgrammeError(f"{'; '.join(failures)}; {osqp_failed} (tried instead)"
                                 ) from None

    def release(self) -> None:
        """Gives the claimed programme back, without what was made ahead for a solve that did
        not come (a kept programme holds no dense matrices it will not use)."""
        self._ahead = None
        super().release()

    def prepare(self, p_x: np.ndarray) -> None:
        """Mirrors and factors the objective's matrix `p_x` (upper blocks filled) ahead of the
        next `solve`, which uses them if its own matrix is the same, entry for entry (else it
        makes its own, as without). Nothing is kept of one that has no factor: its solve says
        why."""
        try:
            hessian = self._mirrored(np.asarray(p_x))
            self._ahead = (np.array(p_x), hessian, self._factor(hessian))
        except ProgrammeError:
            self._ahead = None

    def _mirrored(self, p_x: np.ndarray) -> np.ndarray:
        """The symmetric Hessian whose upper triangle `p_x`'s is (the caller fills the upper
        blocks), checked for values that are not numbers."""
        hessian = p_x.copy()
        np.copyto(hessian, p_x.T, where=_strictly_lower(len(p_x)))
        hessian += 0.0  # (as when the two triangles were summed: a -0.0 becomes 0.0)
        if not np.all(np.isfinite(hessian)):
            raise ProgrammeError(NOT_A_NUMBER)
        return hessian

    @staticmethod
    def _factor(hessian: np.ndarray) -> np.ndarray:
        """The upper Cholesky factor R of `hessian` (H = R^T R, LAPACK)."""
        import scipy.linalg as sl

        try:
            return sl.cholesky(hessian, lower=False, check_finite=False)
        except (sl.LinAlgError, ValueError):
            raise ProgrammeError("The surface's quadratic programme is not convex: its "
                                 "Hessian has no Cholesky factor") from None

    def _run(self, model) -> tuple[np.ndarray, int]:
        """DAQP's solve of a set-up `model`: its solution and exit flag. With a `deadline` or a
        `cancel`, in runs DAQP ends on its own time limit (POLL_SECONDS each, none past the
        deadline), the deadline and `cancel` asked before each (`DeadlinePassed` when either
        says so). DAQP goes on from the working set a run ended with, so a solve in runs is the
        same as one solve, bit for bit."""
        while True:
            self._check_deadline()
            if self.deadline is None and self.cancel is None:
                run = 0.0  # (DAQP's "no time limit")
            else:
                left = NO_TIME_LIMIT if self.deadline is None else \
                    self.deadline - time.monotonic()
                run = min(left, POLL_SECONDS) if self.cancel is not None else left
                if run <= 0:
                    raise DeadlinePassed
            model.settings = {"time_limit": run}
            z, _, flag, _ = model.solve()
            if flag != DAQP_TIME_LIMIT:
                return z, flag
            if self.cancel is not None and self.cancel():
                raise DeadlinePassed

    def _solve_daqp(self, p_x, q, rows, normals, lower, x0, step, factored: bool):
        """DAQP on the programme. `factored`: in the coordinates z = R x (H = R^T R, by LAPACK),
        where the Hessian is the identity, which DAQP sets up in microseconds where it factors
        any other itself, slowly: the rows become rows of A R^-1, the trust region rows of R^-1,
        taken, as the rows are, only once the solution breaks them. Otherwise (DAQP drops a
        row it finds too short, as e_i R^-1 is for a coordinate some 1e11 times stiffer than a
        metre) in x, with the trust region as DAQP's simple bounds."""
        import scipy.linalg as sl

        n = 3 * self.n0
        p_x = p_x.toarray() if sp.issparse(p_x) else np.asarray(p_x)
        if not np.all(np.isfinite(q)):
            raise ProgrammeError(NOT_A_NUMBER)
        ahead, self._ahead = self._ahead, None
        if ahead is not None and np.array_equal(ahead[0], p_x):
            hessian, r = ahead[1], ahead[2]  # (`prepare`: factored while the rows were made)
        else:
            hessian, r = self._mirrored(p_x), None
        if factored:
            if r is None:
                r = self._factor(hessian)
            f = sl.solve_triangular(r, q, trans="T", check_finite=False)  # q^T x = (R^-T q)^T z
        points, plane_normals, bounds, plane = self._wanted(rows, normals, lower)
        if self._dense is None:  # S's rows are taken densely at every step
            self._dense = self.s.toarray()
        taking = bounds > plane(x0) - NEAR_ROW
        boxed = np.zeros(n, dtype=bool)  # the coordinates whose trust-region rows are taken
        weight = 1.0 / (2.0 * self.slack_weight)  # DAQP's soft rows cost s^2 / (2 rho)
        identity = self._identity
        while True:
            take, box = np.flatnonzero(taking), np.flatnonzero(boxed)
            dense = self._dense[points[take]]
            a = np.concatenate([dense * plane_normals[take, axis, None] for axis in range(3)],
                               axis=1)
            high, low = np.full(len(take), 1e30), bounds[take]
            sense = np.full(len(take), 8, dtype=np.int32)
            if factored:  # the held coordinates' rows of R^-1, hard, after the soft rows
                a = np.concatenate([a, identity[box]])
                a = np.ascontiguousarray(
                    sl.solve_triangular(r, a.T, trans="T", check_finite=False).T)  # A R^-1
                high = np.concatenate([high, x0[box] + step])
                low = np.concatenate([low, x0[box] - step])
                sense = np.concatenate([sense, np.zeros(len(box), dtype=np.int32)])
            else:  # the trust region as simple bounds, before the rows
                high = np.concatenate([x0 + step, high])
                low = np.concatenate([x0 - step, low])
                sense = np.concatenate([np.zeros(n, dtype=np.int32), sense])
            model = self._daqp.Model()
            flag, _ = model.setup(identity if factored else hessian, f if factored else q, a,
                                  high, low, sense)  # (exit flag, set-up seconds)
            self.setups += 1
            if flag < 0:
                raise ProgrammeError(f"The surface's quadratic programme could not be set up: "
                                     f"DAQP says {flag}")
            if len(sense):
                model.soft_weights(rho_l=np.full(len(sense), weight),
                                   rho_u=np.full(len(sense), weight))
            z, flag = self._run(model)
            if flag < 1:
                raise ProgrammeError(f"The surface's quadratic programme failed: DAQP exit "
                                     f"flag {flag}")
            x = sl.solve_triangular(r, np.asarray(z), check_finite=False) if factored else \
                np.asarray(z)
            short = bounds - plane(x)
            broken = ~taking & (short > ROW_TOLERANCE)
            outside = np.abs(x - x0) > step + BOX_TOLERANCE
            if factored and np.any(outside & boxed):
                raise ProgrammeError("DAQP left the trust region of a coordinate it held (it "
                                     "drops a row it finds too short: too stiff a Hessian)")
            if not factored:
                outside[:] = False  # (simple bounds: held to DAQP's own tolerance)
            if not broken.any() and not outside.any():
                return x, "solved", float(max(short.max(initial=0.0), 0.0))
            taking |= broken
            boxed |= outside
