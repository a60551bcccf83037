"""The fit's quadratic programme against an independent solver: Clarabel (an interior-point
method) on the programme written out with its slacks as variables. Both back-ends (DAQP in the
coordinates of the Hessian's Cholesky factor, OSQP; each over the rows that could bind) must
find its optimum."""

import clarabel
import numpy as np
import pytest
import scipy.sparse as sp

from solver.surface.programme import DenseProgramme, Programme, ProgrammeError

N0, POINTS, ROWS, STEP, WEIGHT = 12, 40, 30, 0.05, 1000.0


def _problem(seed: int):
    """A random programme: points as convex combinations of the control vertices (as
    subdivision makes them), an SPD Hessian given by its upper blocks (as the fit does), rows
    with bounds some of which the start breaks, some far, some not wanted (-inf)."""
    rng = np.random.default_rng(seed)
    s = rng.random((POINTS, N0)) * (rng.random((POINTS, N0)) < 0.3)
    s[np.arange(POINTS), rng.integers(0, N0, POINTS)] += 1.0
    s /= s.sum(axis=1, keepdims=True)
    m = rng.normal(size=(3 * N0, 3 * N0))
    hessian = m @ m.T / (3 * N0) + 0.05 * np.eye(3 * N0)
    q = rng.normal(size=3 * N0) * 0.05
    x0 = rng.normal(size=3 * N0) * 0.1
    # the rows hold a shuffled subset of the points (as the fit's hold every other vertex)
    rows = rng.choice(POINTS, ROWS, replace=False)
    normals = rng.normal(size=(ROWS, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    now = np.einsum("ij,ij->i", normals, s[rows] @ x0.reshape(3, N0).T)
    lower = now + rng.uniform(-0.08, 0.03, ROWS)  # some broken now, some far from binding
    lower[rng.random(ROWS) < 0.2] = -np.inf
    return sp.csr_matrix(s), np.triu(2 * hessian), q, rows, normals, lower, x0


def _clarabel(s, p_upper, q, rows, normals, lower, x0, step, weight):
    """The programme with its slacks as variables: min 1/2 x'Px + q'x + w |slack|^2 subject to
    n.(S x) + slack >= lower, slack >= 0, |x - x0| <= step; by Clarabel."""
    n = 3 * N0
    keep = np.flatnonzero(np.isfinite(lower))
    r = len(keep)
    dense = s[rows[keep]].toarray()
    a = np.hstack([dense * normals[keep, axis][:, None] for axis in range(3)])
    p = sp.block_diag([sp.csr_matrix(np.triu(p_upper) + np.triu(p_upper, 1).T),
                       2 * weight * sp.identity(r)], format="csc")
    # Clarabel: A z + slack = b, slack in the non-negative cone, i.e. A z <= b
    big = sp.vstack([sp.hstack([-sp.csr_matrix(a), -sp.identity(r)]),
                     sp.hstack([sp.csr_matrix((r, n)), -sp.identity(r)]),
                     sp.hstack([sp.identity(n), sp.csr_matrix((n, r))]),
                     sp.hstack([-sp.identity(n), sp.csr_matrix((n, r))])], format="csc")
    b = np.concatenate([-lower[keep], np.zeros(r), x0 + step, -(x0 - step)])
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-10
    solution = clarabel.DefaultSolver(sp.triu(p, format="csc"), np.concatenate([q, np.zeros(r)]),
                                      big, b, [clarabel.NonnegativeConeT(len(b))],
                                      settings).solve()
    assert str(solution.status) == "Solved"
    z = np.asarray(solution.x)
    return z[:n], float(max(z[n:].max(initial=0.0), 0.0))


@pytest.mark.parametrize("seed", range(6))
def test_dense_programme_finds_the_optimum_clarabel_finds(seed):
    s, p_upper, q, rows, normals, lower, x0 = _problem(seed)
    programme = DenseProgramme(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    x, status, residual = programme.solve(p_upper, q, rows, normals, lower, x0, STEP)
    expected, slack = _clarabel(s, p_upper, q, rows, normals, lower, x0, STEP, WEIGHT)
    assert status == "solved"
    np.testing.assert_allclose(x, expected, atol=1e-6)
    assert residual == pytest.approx(slack, abs=1e-6)
    assert np.all(np.abs(x - x0) <= STEP + 1e-9)  # the trust region holds exactly
    # the case matters: some rows bind at the optimum, some coordinates sit on the box
    now = np.einsum("ij,ij->i", normals, s[rows] @ x.reshape(3, N0).T)
    finite = np.isfinite(lower)
    assert np.any(np.abs(now[finite] - lower[finite]) < 1e-6) or residual > 1e-6
    assert np.any(np.abs(np.abs(x - x0) - STEP) < 1e-9)


@pytest.mark.parametrize("kind, atol", [(DenseProgramme, 1e-6), (Programme, 2e-3)])
def test_a_row_far_from_binding_at_the_start_still_holds(kind, atol):
    """A row more than NEAR_ROW from its bound where the step starts, which the unconstrained
    step would break, still holds at the solution (it joins the next try), for both
    back-ends (each takes only the rows near binding first)."""
    s, p_upper, q, rows, normals, lower, x0 = _problem(7)
    lower[:] = -np.inf
    # the step without rows
    free = DenseProgramme(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    x_free, _, _ = free.solve(p_upper, q, rows, normals, lower, x0, STEP)
    now0 = np.einsum("ij,ij->i", normals, s[rows] @ x0.reshape(3, N0).T)
    moved = np.einsum("ij,ij->i", normals, s[rows] @ x_free.reshape(3, N0).T)
    k = int(np.argmin(moved - now0))  # the row the free step moves furthest down
    assert moved[k] < now0[k] - 0.015
    lower[k] = now0[k] - 0.012  # far from binding at the start, broken by the free step
    programme = kind(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    matrix = sp.csr_matrix(p_upper) if kind is Programme else p_upper
    x, _, _ = programme.solve(matrix, q, rows, normals, lower, x0, STEP)
    expected, _ = _clarabel(s, p_upper, q, rows, normals, lower, x0, STEP, WEIGHT)
    np.testing.assert_allclose(x, expected, atol=atol)
    assert programme.setups >= 2  # the first try left the row out, a later one took it


@pytest.mark.parametrize("seed", range(6))
def test_osqp_programme_agrees_with_clarabel_to_its_tolerance(seed):
    s, p_upper, q, rows, normals, lower, x0 = _problem(seed)
    programme = Programme(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    x, status, residual = programme.solve(sp.csr_matrix(p_upper), q, rows, normals, lower, x0,
                                          STEP)
    expected, slack = _clarabel(s, p_upper, q, rows, normals, lower, x0, STEP, WEIGHT)
    assert status in ("solved", "solved inaccurate")
    np.testing.assert_allclose(x, expected, atol=2e-3)
    assert residual == pytest.approx(slack, abs=1e-3)


def test_dense_programme_refuses_a_hessian_that_is_not_convex():
    s, p_upper, q, rows, normals, lower, x0 = _problem(1)
    programme = DenseProgramme(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    with pytest.raises(ProgrammeError, match="DAQP.*OSQP"):  # both say so
        programme.solve(-p_upper, q, rows, normals, lower, x0, STEP)


def test_a_factor_made_ahead_serves_only_the_same_matrix(monkeypatch):
    """`prepare` factors the next step's matrix while the fit makes its rows: the solve of that
    matrix uses the factor (one Cholesky factorisation in all, the same step bit for bit); the
    solve of another matrix factors its own; a matrix without a factor still fails in its
    solve, with the reason."""
    import scipy.linalg as sl

    s, p_upper, q, rows, normals, lower, x0 = _problem(3)
    factored = []
    cholesky = sl.cholesky
    monkeypatch.setattr(sl, "cholesky", lambda *a, **k: factored.append(1) or cholesky(*a, **k))
    plain = DenseProgramme(s, sp.identity(N0, format="csr"), N0, WEIGHT).solve(
        p_upper, q, rows, normals, lower, x0, STEP)
    programme = DenseProgramme(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    factored.clear()
    programme.prepare(p_upper.copy())
    ahead = programme.solve(p_upper, q, rows, normals, lower, x0, STEP)
    assert len(factored) == 1
    np.testing.assert_array_equal(ahead[0], plain[0])
    assert ahead[1:] == plain[1:]
    # prepared for another matrix: the solve factors its own and finds its own optimum
    other = p_upper * 1.5
    programme.prepare(p_upper)
    x, _, _ = programme.solve(other, q, rows, normals, lower, x0, STEP)
    expected, _ = _clarabel(s, other, q, rows, normals, lower, x0, STEP, WEIGHT)
    np.testing.assert_allclose(x, expected, atol=1e-6)
    programme.prepare(-p_upper)  # no factor: nothing kept, the solve says why
    with pytest.raises(ProgrammeError, match="not convex"):
        programme.solve(-p_upper, q, rows, normals, lower, x0, STEP)


class _Failing:
    """A DAQP whose every set-up fails (as a cycling or badly scaled programme makes it)."""

    class Model:
        def setup(self, *args, **kwargs):
            return -2, 0.0


def test_dense_programme_falls_back_to_osqp_when_daqp_fails():
    s, p_upper, q, rows, normals, lower, x0 = _problem(2)
    programme = DenseProgramme(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    programme._daqp = _Failing
    x, status, _ = programme.solve(p_upper, q, rows, normals, lower, x0, STEP)
    expected, _ = _clarabel(s, p_upper, q, rows, normals, lower, x0, STEP, WEIGHT)
    assert status in ("solved", "solved inaccurate") and programme.fallbacks == 1
    np.testing.assert_allclose(x, expected, atol=2e-3)


def test_a_coordinate_far_stiffer_than_the_rest_stays_in_its_trust_region():
    """A fixed vertex held 1e12 times harder than the rest, its start 20 cm away: the step may
    still move it only 5 cm (DAQP drops the trust region's row of so stiff a coordinate, which
    the programme notices and hands to OSQP)."""
    s, p_upper, q, rows, normals, lower, x0 = _problem(4)
    stiff = 1e12
    p_upper = p_upper.copy()
    p_upper[0, 0] += 2 * stiff
    q = q.copy()
    q[0] -= 2 * stiff * (x0[0] + 0.2)  # pulled towards x0 + 20 cm
    programme = DenseProgramme(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    x, _, _ = programme.solve(p_upper, q, rows, normals, lower, x0, STEP)
    assert abs(x[0] - x0[0]) <= STEP + 1e-6
    assert x[0] - x0[0] == pytest.approx(STEP, abs=1e-4)  # pulled as far as it may go


def test_osqp_starts_from_the_duals_of_the_rows_on_the_same_points():
    """After a solve, the duals offered to the next are the last solve's, row by row, for rows
    on the same surface points in another order (a new row: 0), the trust region's as they
    were; a solve started so finds the same optimum."""
    s, p_upper, q, rows, normals, lower, x0 = _problem(5)
    lower[:] = np.where(np.isfinite(lower), lower, 0.0)  # every row taken
    lower = np.maximum(lower, np.einsum("ij,ij->i", normals, s[rows] @ x0.reshape(3, N0).T) - 0.005)
    programme = Programme(s, sp.identity(N0, format="csr"), N0, WEIGHT)
    x, _, _ = programme.solve(sp.csr_matrix(p_upper), q, rows, normals, lower, x0, STEP)
    before, y, rho = programme._duals
    r, n = len(before), 3 * N0
    assert np.any(np.abs(y[:r]) > 1e-6)  # some rows bind: their duals matter
    perm = np.random.default_rng(0).permutation(r)
    new = np.concatenate([before[perm], [POINTS + 7]])  # a point no row held before
    warm = programme._warm_duals(new)
    np.testing.assert_array_equal(warm[:r], y[:r][perm])
    assert warm[r] == 0.0
    np.testing.assert_array_equal(warm[r + 1:r + 1 + n], y[r:r + n])
    np.testing.assert_array_equal(warm[r + 1 + n:r + 1 + n + r], y[r + n:][perm])
    again, _, _ = programme.solve(sp.csr_matrix(p_upper), q * 1.01, rows, normals, lower, x0,
                                  STEP)
    expected, _ = _clarabel(s, p_upper, q * 1.01, rows, normals, lower, x0, STEP, WEIGHT)
    np.testing.assert_allclose(again, expected, atol=2e-3)
    assert rho > 0


def test_osqp_takes_its_first_step_size_at_set_up_and_solves_to_the_same_bits():
    """The programme's OSQP solver takes its first step size at set-up (`initial_rho`) rather
    than OSQP's `rho` setting, which builds the solver with that step size and then sets it
    again (a second factoring of the same system): the solver holds that step size and solves
    to the same bits in as many iterations."""
    import osqp

    from solver.surface.programme import _osqp_solver

    rng = np.random.default_rng(3)
    m = sp.random(60, 60, density=0.1, random_state=4)
    p = sp.triu(m @ m.T + sp.identity(60), format="csc")
    a = sp.random(80, 60, density=0.1, random_state=5, format="csc")
    q, low = rng.normal(size=60), -rng.random(80)
    high = np.full(80, np.inf)
    settings = dict(verbose=False, polishing=False, eps_abs=1e-6, eps_rel=1e-6, scaling=0)
    theirs = osqp.OSQP()
    theirs.setup(p, q, a, low, high, rho=0.037, **settings)
    ours = _osqp_solver(osqp)()
    ours.setup(p, q, a, low, high, initial_rho=0.037, **settings)
    assert ours.settings.rho == theirs.settings.rho == 0.037
    mine, other = ours.solve(raise_error=False), theirs.solve(raise_error=False)
    assert mine.info.iter == other.info.iter
    np.testing.assert_array_equal(mine.x, other.x)
    np.testing.assert_array_equal(mine.y, other.y)
    # a solver set up without it starts from OSQP's default, as before
    plain = _osqp_solver(osqp)()
    plain.setup(p, q, a, low, high, **settings)
    assert plain.settings.rho == 0.1


def _stiff(n0: int, points: int):
    """A programme whose DAQP solve takes a while (0.3-2.3 s here): a dense S, most rows
    binding, so the active set grows row by row."""
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(points, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    programme = DenseProgramme(sp.csr_matrix(rng.normal(size=(points, n0))),
                               sp.identity(n0, format="csr"), n0, WEIGHT)
    problem = (np.eye(3 * n0), rng.normal(size=3 * n0), np.arange(points), normals,
               rng.normal(size=points) * 3 + 5, np.zeros(3 * n0), 100.0)
    return programme, problem


@pytest.mark.parametrize("how", ["deadline", "cancel"])
def test_a_long_daqp_solve_stops_soon_after_its_deadline_or_cancel(how):
    """One DAQP solve of a stiff programme runs POLL_SECONDS at a time: a deadline passing, or
    a cancel saying so, mid-solve ends it there, not when the solve would have finished.
    Counted, not timed (a busy host stretched a run past a wall-clock bound): DAQP ends each
    run on its own time limit, and the solve makes no run once the deadline has passed or the
    cancel has said so."""
    import time
    import types

    import daqp

    from solver.surface.programme import DAQP_TIME_LIMIT, POLL_SECONDS, DeadlinePassed

    runs = []  # (DAQP's time limit for the run, its exit flag)

    class Counted(daqp.Model):
        def setup(self, *args):
            out = super().setup(*args)
            if how == "deadline":  # (counted from the set-up's end: on a busy host the
                # programme's own set-up outlasted a deadline set before the solve)
                programme.deadline = time.monotonic() + 0.1
            return out

        def solve(self):
            out = super().solve()
            runs.append((self.settings["time_limit"], out[2]))
            return out

    programme, problem = _stiff(100, 1500)  # (its first DAQP run alone: 0.75 s)
    programme._daqp = types.SimpleNamespace(Model=Counted)
    asked = []
    if how == "deadline":
        programme.deadline = time.monotonic() + 60.0  # (until the set-up sets the real one)
    else:
        programme.cancel = lambda: asked.append(True) or True  # (yes, at the first asking)
    with pytest.raises(DeadlinePassed):
        programme.solve(*problem)
    # one run, cut short by its own time limit (within the deadline, or POLL_SECONDS), and none
    # after it: the deadline had passed, or the cancel said so when asked after that run
    assert len(runs) == 1 and runs[0][1] == DAQP_TIME_LIMIT
    assert 0 < runs[0][0] <= (0.1 if how == "deadline" else POLL_SECONDS)
    assert len(asked) == (1 if how == "cancel" else 0)


def test_a_daqp_solve_in_runs_is_the_same_as_one_solve(monkeypatch):
    """DAQP goes on from where a run stopped on its time limit: a solve cut into runs of 20 ms
    (a cancel that never says so) finds the same bits as one uncut solve."""
    import time

    import solver.surface.programme as P

    monkeypatch.setattr(P, "POLL_SECONDS", 0.02)
    programme, problem = _stiff(80, 800)
    whole = programme.solve(*problem)
    polls = []
    programme, problem = _stiff(80, 800)
    programme.cancel = lambda: polls.append(time.monotonic()) and False
    cut = programme.solve(*problem)
    assert len(polls) >= 3  # (cut at least three times)
    assert np.array_equal(whole[0], cut[0]) and whole[1:] == cut[1:]
