"""Second-order cone programmes for the contact references, solved by Clarabel.

Clarabel solves min 1/2 x' P x + c' x subject to A x + s = b, s in a product of cones; here only
the non-negative orthant and second-order cones of dimension 3 (a friction cone or a slip's
length) occur.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


class ConicError(RuntimeError):
    """Clarabel did not solve a contact programme."""


def solve_conic(p: sp.spmatrix, c: np.ndarray, a: sp.spmatrix, b: np.ndarray,
                zero: int, nonneg: int, soc: int) -> tuple[np.ndarray, np.ndarray]:
    """Primal x and dual z of the programme; the rows of A are `zero` equalities, then
    `nonneg` inequalities, then `soc` cones of dimension 3. Raises `ConicError` unless solved."""
    import clarabel

    cones = []
    if zero:
        cones.append(clarabel.ZeroConeT(zero))
    if nonneg:
        cones.append(clarabel.NonnegativeConeT(nonneg))
    cones += [clarabel.SecondOrderConeT(3)] * soc
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.max_threads = 1
    solver = clarabel.DefaultSolver(sp.triu(p, format="csc"), np.asarray(c, dtype=np.float64),
                                    sp.csc_matrix(a), np.asarray(b, dtype=np.float64), cones,
                                    settings)
    sol = solver.solve()
    status = str(sol.status)
    if status not in ("Solved", "AlmostSolved"):
        raise ConicError(f"Expected Clarabel to solve the contact programme, got {status}")
    return np.asarray(sol.x), np.asarray(sol.z)


def tangent_frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (K, 3) each, orthogonal to the unit `normals` (K, 3) and each other."""
    n = np.asarray(normals, dtype=np.float64)
    helper = np.zeros_like(n)
    helper[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


def rigid_rows(directions: np.ndarray, arms: np.ndarray) -> np.ndarray:
    """(K, 6) e_k . (u + theta x a_k) as coefficients of (u, theta): the displacement of the
    body points at arms a_k (K, 3) along the directions e_k (K, 3) under a small rigid motion."""
    return np.concatenate([directions, np.cross(arms, directions)], axis=1)
