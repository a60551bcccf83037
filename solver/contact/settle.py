"""A body settling in static equilibrium on the supports of a scene.

The posed body is a rigid body under gravity. Each support (the fitted surface, the floor, an
armrest) carries a foam layer: a Winkler foundation whose normal pressure is `stiffness` times how
far the skin presses in, `bottom_factor` times stiffer past the foam's `thickness` (the frame
beneath), and whose shear is an elastic slip of stiffness `shear_ratio x stiffness` capped by
Coulomb friction (|t| <= mu p). Contact is unilateral: a vertex that leaves the foam carries
nothing.

The body's small rigid motion (translation u and rotation theta about its centre of mass) is
solved so that the contact forces balance the weight and its moment: a Newton iteration on the
six balance equations with the exact Jacobian of the linearised contact laws, within a trust
region of STEP and shifted towards the imbalance's push where the stiffness gives way (so that
it seeks a stable rest, not a balance on an edge), scipy's bounded least squares where it
stalls; repeated on the moved body with fresh closest points until the balance holds. The
friction displacement counts from where the body was placed. What does not settle is reported as
such: no contact at all, a rotation past `MAX_TURN` (the pose tips over), a translation past
`MAX_SHIFT` (the body slides off or sinks through), or balance equations without a root.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from solver.contact.mat import G, SupportContact
from solver.mesh import SurfaceMesh, volume_centroid


UP = np.array([0.0, 1.0, 0.0])
BAND = 0.06  # metres above a support within which a vertex may come into contact
MAX_TURN = np.radians(45.0)  # a settle turning the body further tips it over
MAX_SHIFT = 0.12  # metres: a settle moving the body further slides it off or sinks it through
DEPTH = 0.05  # metres past a surface's foam: a vertex deeper behind it is not in contact
MAX_OUTER = 40  # Newton steps: a body leaning back on a backless seat takes 30-40 to find its rest
FORCE_TOL = 3e-3  # the settle stops when the net force is below this share of the weight
MOMENT_TOL = 0.3  # ... and the net moment below this, N m
LEVER = 0.5  # metres: the moment scale for the Newton's residual
STILL = 1e-6  # metres (at LEVER for a turn): a step this small makes no progress
SIDEWAYS = -2 * BAND  # the depth given a vertex beside a surface's border (its closest point on
                      # the border, the offset running sideways off it): not in its foam, which
                      # lies behind the surface only
STEP = 0.03  # metres (at LEVER for a turn): the most the body moves between fresh contacts
SHRINKS = 8  # times the share of Newton's step taken may be halved, after steps that overshot
TOUCHING = 1e-9  # metres: a vertex this little behind a surface lies on it and touches its foam
# (its closest point lies on the body's own skin, where the winding number that tells a cut
# from the surface's far side is a coin toss: a base placed on a slope lost 40 % of its contact)


@dataclass(frozen=True)
class Foam:
    """A support's foam: `stiffness` Pa per metre pressed in, `thickness` m (past it the foam is
    bottomed out and `bottom_factor` times stiffer), Coulomb `friction`, and its shear stiffness
    as `shear_ratio` of the normal one (a foam layer's G / E, about 1 / (2 (1 + nu)))."""

    stiffness: float
    thickness: float = 0.1
    friction: float = 0.5
    shear_ratio: float = 0.4
    bottom_factor: float = 20.0


@dataclass(frozen=True, eq=False)
class Support:
    """Something a body can rest on: a surface `mesh` (face normals towards the body), or the
    floor, the plane y = `height`, when `mesh` is None. `name` is what the report calls it,
    unless `parts(vertices, normals) -> (K,) str` names each contact's part (the body vertices
    in contact, the support's normals there), as a seat, a back or a leg rest."""

    name: str
    foam: Foam
    mesh: SurfaceMesh | None = None
    height: float = 0.0
    parts: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None


@dataclass(frozen=True, eq=False)
class Settled:
    """The settle's outcome for one body.

    stable : whether the body came to rest; `reason` says why not ("tips over", ...).
    vertices : (V, 3) the body's vertices after the settle, metres.
    translation : (3,) m, rotation : (3,) rotation vector (rad) about `centre` (the body's centre
        of mass before the settle).
    contacts : one `SupportContact` per support part that carries load.
    net_force : (3,) N and net_moment : (3,) N m, the balance left over on the settled body
        (contact forces plus weight; moments about the settled centre of mass); NaN when the
        body does not rest (there is no such balance to give).
    weight_n : m g.
    iterations : the outer steps taken.
    gravity : (3,) the unit direction of gravity.
    """

    stable: bool
    reason: str | None
    vertices: np.ndarray
    translation: np.ndarray
    rotation: np.ndarray
    centre: np.ndarray
    contacts: list[SupportContact]
    net_force: np.ndarray
    net_moment: np.ndarray
    weight_n: float
    iterations: int = 0
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))


@dataclass(frozen=True, eq=False)
class _Candidates:
    """The vertices that may touch one support, with their linearised contact geometry."""

    support: int
    index: np.ndarray  # (K,) body vertices
    depth: np.ndarray  # (K,) how far each is pressed in (negative: above the foam)
    normal: np.ndarray  # (K, 3) the support's normal at the closest point
    point: np.ndarray  # (K, 3) the closest point on the support
    face: np.ndarray  # (K,) the support triangle (-1: the floor)


def reach_depth(foam: Foam) -> float:
    """Metres behind a surface to which a vertex can press it: its foam, bottomed out, and
    DEPTH more."""
    return foam.thickness + DEPTH


def _prepare(support: Support, vertices: np.ndarray, normals: np.ndarray,
             cut: np.ndarray | None, inside, k: int, state: dict | None = None,
             skip: np.ndarray | None = None, known: tuple | None = None
             ) -> tuple[np.ndarray, _Candidates, dict | None]:
    """(N,) the body vertices that may touch `support` during the settle: within BAND above
    it, facing it, pressed into a surface less than `reach_depth`; and their contact geometry.
    Behind a surface, where the body was placed (`state` None), only where the surface cuts
    into the body (`cut` (V,) bool says so, or `inside(points) -> bool` for the closest
    points); later, all but those that were behind its far side at the placement. `state`
    keeps those, a lower bound of each vertex's distance to the surface and where it held, so
    that a later look queries only the vertices that can have come within BAND; it leaves out
    the `skip` (V,) bool vertices (a surface's only). `known`: every vertex's closest point
    on the surface as `SurfaceMesh.closest` gives it, when the caller has it already."""
    x = vertices
    if support.mesh is None:
        depth = support.height - x[:, 1]
        facing = normals[:, 1] < 0
        idx = np.flatnonzero(facing & (depth > -BAND))  # the floor has no far side
        return idx, _candidates(support, k, x, idx), None
    mesh = support.mesh
    tree, edge = mesh.vertex_tree()
    if state is None:
        lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
        # at least as far from the surface as from its bounding box, and BAND beyond the tree's
        # reach
        gap = np.linalg.norm(np.maximum(np.maximum(lo - x, x - hi), 0.0), axis=1)
        look = np.flatnonzero(gap <= BAND + edge)
    else:
        gap = state["gap"] - np.linalg.norm(x - state["x"], axis=1)
        look = np.flatnonzero((gap < BAND) & (True if skip is None else ~skip))
    if known is not None:  # the closest points of every vertex, as placed
        unsigned, signed, over, face, point = known
        gap = unsigned.copy()
        idx = np.flatnonzero(unsigned <= BAND + edge)
        unsigned, signed, over, face, point = (a[idx] for a in known)
    else:
        dist, _ = tree.query(x[look], distance_upper_bound=BAND + edge)
        gap[look] = np.maximum(gap[look], BAND)  # found or not: refined below where found
        idx = look[np.isfinite(dist)]
        unsigned, signed, over, face, point = mesh.closest(x[idx])
        gap[idx] = unsigned
    depth = -signed
    ok = over & (depth > -BAND) & (depth < reach_depth(support.foam))
    ok &= np.einsum("ij,ij->i", normals[idx], mesh.face_normals[face]) < 0
    behind = np.flatnonzero(ok & (depth > 0))
    if state is None:
        blocked = np.zeros(len(x), dtype=bool)
        if behind.size:
            pressed = cut[idx[behind]] if cut is not None else inside(point[behind])
            pressed |= depth[behind] < TOUCHING  # (on the surface: it touches it)
            blocked[idx[behind[~pressed]]] = True
    else:
        blocked = state["blocked"]
    ok[behind] = ~blocked[idx[behind]]
    keep = ok & (depth > -BAND)
    return idx[ok], _Candidates(k, idx[keep], depth[keep], mesh.face_normals[face[keep]],
                                point[keep], face[keep]), {"blocked": blocked, "gap": gap,
                                                           "x": x}


def _candidates(support: Support, k: int, vertices: np.ndarray, subset: np.ndarray,
                prev: _Candidates | None = None, prev_x: np.ndarray | None = None
                ) -> _Candidates:
    """The contact geometry of the `subset` of vertices on `support` (linearised: each vertex
    against the tangent plane at its closest point). Given the geometry `prev` of the same
    vertices where they stood at `prev_x`, only those it puts within BAND / 2 of contact are
    looked up afresh; the others keep their planes (they are not in contact either way)."""
    x = vertices[subset]
    if support.mesh is None:
        depth = support.height - x[:, 1]
        n = np.broadcast_to(UP, x.shape)
        point = x.copy()
        point[:, 1] = support.height
        face = np.full(len(x), -1)
    elif prev is not None:
        n, point, face = prev.normal.copy(), prev.point.copy(), prev.face.copy()
        depth = prev.depth - np.einsum("ij,ij->i", n, x - prev_x)
        close = np.flatnonzero(depth > -0.5 * BAND)
        _, signed, over, face[close], point[close] = support.mesh.closest(x[close])
        depth[close] = np.where(over, -signed, SIDEWAYS)
        n[close] = support.mesh.face_normals[face[close]]
    else:
        _, signed, over, face, point = support.mesh.closest(x)
        depth = np.where(over, -signed, SIDEWAYS)
        n = support.mesh.face_normals[face]
    keep = np.flatnonzero(depth > -BAND)
    return _Candidates(k, subset[keep], depth[keep], np.array(n[keep]), point[keep], face[keep])


def _skew(r: np.ndarray) -> np.ndarray:
    """(K, 3, 3) the cross-product matrices [r]x of (K, 3) vectors."""
    m = np.zeros((len(r), 3, 3))
    m[:, 0, 1], m[:, 0, 2] = -r[:, 2], r[:, 1]
    m[:, 1, 0], m[:, 1, 2] = r[:, 2], -r[:, 0]
    m[:, 2, 0], m[:, 2, 1] = -r[:, 1], r[:, 0]
    return m


def _laws(q, c: _Candidates, foam: Foam, area, arm, slip0):
    """The loaded contacts at motion q = (u, theta): which (K,) bool, their forces (L, 3), the
    Jacobian of those (L, 3, 6), and the normal (L,) and tangential (L, 3) parts."""
    d = q[:3] + _cross(q[3:], arm)
    depth = c.depth - np.einsum("ij,ij->i", c.normal, d)
    on = depth > 0
    n, arm, area, depth = c.normal[on], arm[on], area[on], depth[on]
    k, h = foam.stiffness, foam.thickness
    extra = (foam.bottom_factor - 1.0) * k  # past the thickness: bottom_factor x k in all
    normal_force = area * (k * depth + extra * np.maximum(depth - h, 0.0))
    stiff = k + extra * (depth > h)
    nj = np.concatenate([n, _cross(arm, n)], axis=1)  # n . d = nj . q
    dn = -(area * stiff)[:, None] * nj  # (L, 6)
    total = slip0[on] + d[on]
    slip = total - np.einsum("ij,ij->i", n, total)[:, None] * n
    jac = np.zeros((len(n), 3, 6))
    jac[:, :, :3] = np.eye(3)
    jac[:, :, 3:] = -_skew(arm)  # d = u + theta x r = u - [r]x theta
    pj = jac - n[:, :, None] * nj[:, None, :]
    kt = foam.shear_ratio * k * area
    tangent = -kt[:, None] * slip
    cap = foam.friction * normal_force
    size = np.linalg.norm(slip, axis=1)
    dt = -kt[:, None, None] * pj
    slides = kt * size > cap
    if slides.any():
        s_hat = slip[slides] / size[slides, None]
        sj = np.concatenate([s_hat, _cross(arm[slides], s_hat)], axis=1)
        tangent[slides] = -cap[slides, None] * s_hat
        dt[slides] = (-foam.friction * s_hat[:, :, None] * dn[slides, None, :]
                      - (cap[slides] / size[slides])[:, None, None]
                      * (pj[slides] - s_hat[:, :, None] * sj[:, None, :]))
    forces = normal_force[:, None] * n + tangent
    dforce = n[:, :, None] * dn[:, None, :] + dt
    return on, forces, dforce, normal_force, tangent


def _balance(q, groups, weight):
    """Net force and moment (6,) at motion q, and their Jacobian (6, 6)."""
    total = np.zeros(6)
    jac = np.zeros((6, 6))
    total[:3] = weight
    for c, foam, area, arm, slip0 in groups:
        on, f, df, _, _ = _laws(q, c, foam, area, arm, slip0)
        r = arm[on]
        moved = r + _cross(q[3:], r)  # the arms turn with the body
        total[:3] += f.sum(axis=0)
        total[3:] += _cross(moved, f).sum(axis=0)
        jac[:3] += df.sum(axis=0)
        jac[3:] += np.matmul(_skew(moved), df).sum(axis=0)
        jac[3:, 3:] += np.matmul(_skew(f), _skew(r)).sum(axis=0)  # d (theta x r) x f / d theta
    return total, jac


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (K, 3) arrays (or a (3,) with a (K, 3))."""
    a0, a1, a2 = (a[0], a[1], a[2]) if a.ndim == 1 else (a[:, 0], a[:, 1], a[:, 2])
    out = np.empty(b.shape)
    out[:, 0] = a1 * b[:, 2] - a2 * b[:, 1]
    out[:, 1] = a2 * b[:, 0] - a0 * b[:, 2]
    out[:, 2] = a0 * b[:, 1] - a1 * b[:, 0]
    return out


def settle(vertices: np.ndarray, normals: np.ndarray, areas: np.ndarray, triangles: np.ndarray,
           mass_kg: float, supports: list[Support], *, gravity=(0.0, -1.0, 0.0),
           centre: np.ndarray | None = None, cut: np.ndarray | None = None,
           closest: dict | None = None) -> Settled:
    """The body at rest on `supports` (see the module docstring).

    Parameters
    ----------
    vertices, normals : (V, 3) float, the posed skin (metres) and its unit outward normals.
    areas : (V,) float, Voronoi areas, m^2.
    triangles : (F, 3) int, the closed skin (for the centre of mass and the inside tests).
    mass_kg : the body's mass.
    supports : what it may rest on.
    gravity : the direction of gravity.
    centre : (3,) where the weight acts (default: the centroid of the skin's volume).
    cut : (V,) bool, optional: the vertices behind a surface whose closest surface point lies
        inside the body (the surface cuts into the body there, so they press its foam); the
        others behind a surface are on its far side. Computed here when not given.
    closest : dict, optional: per support index, `SurfaceMesh.closest` of every vertex as
        placed, when the caller has it already.

    Returns
    -------
    Settled, with `stable` False and a `reason` when the body does not come to rest; the net
    force and moment left over are below `FORCE_TOL` m g and `MOMENT_TOL` when it does.

    Raises
    ------
    ValueError
        If the mass is not positive or gravity has no direction.
    """
    import igl

    x0 = np.asarray(vertices, dtype=np.float64)
    weight = _weight(mass_kg, gravity)
    c0 = volume_centroid(x0, triangles) if centre is None else np.asarray(centre, float)
    tri = np.asarray(triangles, dtype=np.int64)
    first = [_prepare(s, x0, normals, cut, lambda p: igl.fast_winding_number(x0, tri, p) > 0.5,
                      k, known=(closest or {}).get(k)) for k, s in enumerate(supports)]
    near = [f[0] for f in first]
    known = [(f[1], x0[f[1].index]) for f in first]  # the last geometry, and where it was found
    rot, shift = np.eye(3), np.zeros(3)
    scale = np.array([1.0] * 3 + [1.0 / LEVER] * 3) / np.linalg.norm(weight)
    x_found = x0  # where the candidates were last looked for on the whole body
    damping, last = 1.0, np.inf  # the share of Newton's step taken, the imbalance a step ago
    for outer in range(1, MAX_OUTER + 1):
        x = (x0 - c0) @ rot.T + c0 + shift
        c = c0 + shift
        nrm = normals @ rot.T
        fresh = outer == 1 or np.abs(x - x_found).max() > BAND
        if fresh and outer > 1:  # moved far enough for other skin to come near: look again
            first = [_prepare(s, x, nrm, None, None, k, first[k][2])
                     for k, s in enumerate(supports)]
            near, x_found = [f[0] for f in first], x
        groups, known = _groups(supports, x, x0, c, areas, nrm, near,
                                [f[1] for f in first] if fresh else None, known)
        if not groups:
            return _unsettled("no support touches the body", x, c0, shift, rot, weight)
        residual, jac = _balance(np.zeros(6), groups, weight)
        if (np.linalg.norm(residual[:3]) < FORCE_TOL * np.linalg.norm(weight)
                and np.linalg.norm(residual[3:]) < MOMENT_TOL):
            if np.abs(x - x_found).max() > 0.01 and _new_contact(supports, x, nrm, first,
                                                                    groups):
                x_found = x - 1.0  # at rest, but skin the last look missed touches: look again
                continue
            if _tips(jac):
                return _unsettled("tips over (its rest is a balance on an edge)", x, c0, shift,
                                  rot, weight)
            return _settled(x, c0, shift, rot, groups, supports, residual, weight, outer)
        # later steps move little: only what was near contact stays a candidate
        near = [np.concatenate([g[0].index for g in groups if g[0].support == k] + [near[k][:0]])
                for k in range(len(supports))]
        # a step after which the imbalance did not shrink overshot (the contacts it found
        # push back as hard the other way): the next takes half as much of Newton's step; one
        # that shrank it lets the next take half as much again as it did (so that a body
        # rocking across its rest takes ever shorter steps, three quarters as long every two)
        size = float(np.linalg.norm(residual * scale))
        damping = max(damping / 2, 0.5 ** SHRINKS) if size >= last else min(1.0, 1.5 * damping)
        last = size
        q, reason = _motion(groups, weight, scale, residual, jac, damping)
        if reason:
            return _unsettled(reason, x, c0, shift, rot, weight)
        rot = Rotation.from_rotvec(q[3:]).as_matrix() @ rot
        shift = shift + q[:3]
        reason = _too_far(np.concatenate([shift, Rotation.from_matrix(rot).as_rotvec()]))
        if reason:
            return _unsettled(reason, x, c0, shift, rot, weight)
    return _unsettled(f"no rest within {MAX_OUTER} steps", x, c0, shift, rot, weight)


def _groups(supports, x, x0, c, areas, nrm, near, fresh, known):
    """The contact groups of the body standing at `x`: from the `fresh` candidates of a new
    look, or by updating the `known` geometry of the `near` vertices; and that geometry."""
    cands = [fresh[k] if fresh is not None else _candidates(s, k, x, near[k], *known[k])
             for k, s in enumerate(supports)]
    groups = [g for g in (_group(s, x, x0, c, areas, nrm, cands[k])
                          for k, s in enumerate(supports)) if g is not None]
    return groups, [(cand, x[cand.index]) for cand in cands]


def _weight(mass_kg: float, gravity) -> np.ndarray:
    """(3,) the body's weight, N; a ValueError for a mass or direction that is not one."""
    g = np.asarray(gravity, dtype=np.float64)
    if not (np.isfinite(mass_kg) and mass_kg > 0):
        raise ValueError(f"Expected a body mass > 0 kg, got {mass_kg}")
    if g.shape != (3,) or not np.all(np.isfinite(g)) or not np.linalg.norm(g) > 0:
        raise ValueError(f"Expected a non-zero gravity direction (3,), got {gravity!r}")
    return mass_kg * G * g / np.linalg.norm(g)


def _motion(groups, weight, scale, residual, jac, damping: float = 1.0
            ) -> tuple[np.ndarray | None, str | None]:
    """The next step of the body (6,), at most STEP, or why there is none: a hovering body
    drops onto its nearest support, a touching one takes Newton's way to balance, that step
    times `damping` (1 or less)."""
    if not any((g[0].depth > 0).any() for g in groups):  # hovering: drop onto the nearest
        gap = min(-g[0].depth.max() for g in groups)
        return np.concatenate([(gap + 1e-3) * weight / np.linalg.norm(weight), np.zeros(3)]), None
    q = _newton(groups, weight, scale, residual, jac)
    if q is None:
        return None, "the balance has no solution (slides off?)"
    size = _size(q)
    if size < STILL:  # no motion brings the imbalance down: no balance within reach
        return None, "finds no balance (it tips over or slides off)"
    return damping * q * min(1.0, STEP / size), None


def _new_contact(supports, x, nrm, first, groups) -> bool:
    """Whether, looking over the whole body again, skin that is not among the candidates
    presses a support."""
    for k, s in enumerate(supports):
        known = np.zeros(len(x), dtype=bool)
        for g in groups:
            if g[0].support == k:
                known[g[0].index] = True
        _, cand, _ = _prepare(s, x, nrm, None, None, k, first[k][2], skip=known)
        if (~known[cand.index[cand.depth > 0]]).any():
            return True
    return False


def _group(support: Support, x, x0, c, areas, normals, cand: _Candidates):
    """One support's contact candidates with what the contact laws need, or None. `normals`
    are the body's as it now stands."""
    if not cand.index.size:
        return None
    i = cand.index
    # the skin's footprint on the support: its area projected along the support's normal
    footprint = areas[i] * np.maximum(-np.einsum("ij,ij->i", normals[i], cand.normal), 0.0)
    return cand, support.foam, footprint, x[i] - c, x[i] - x0[i]


def _size(q: np.ndarray) -> float:
    """How far a motion (u, theta) moves the body: metres, a turn counted at LEVER."""
    return max(float(np.linalg.norm(q[:3])), LEVER * float(np.linalg.norm(q[3:])))


def _descent_step(jac: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Newton's step q = K^-1 r on the stiffness K = -jac where that is stable; where K has a
    direction that gives way (an eigenvalue with a negative real part: a balance on an edge,
    which Newton's root would seek), the step of K + lambda I instead, lambda shifting every
    eigenvalue positive, so that the body moves the way the imbalance pushes it (towards a
    stable rest) and not towards the unstable balance. Turns are measured at LEVER."""
    d = np.array([1.0] * 3 + [1.0 / LEVER] * 3)  # q = d z, z in metres
    k = -(jac * d[None, :]) * d[:, None]  # rows: forces and moments per LEVER
    eig = np.linalg.eigvals(k)
    low = float(eig.real.min())
    top = float(np.abs(eig).max())
    if low <= 1e-9 * top:
        k = k + (0.1 * top - low) * np.eye(6)
    try:
        z = np.linalg.solve(k, r * d)
    except np.linalg.LinAlgError:
        z = np.linalg.lstsq(k, r * d, rcond=None)[0]
    return z * d


def _newton(groups, weight, scale, r, jac) -> np.ndarray | None:
    """The motion (6,) towards balance of the linearised contact laws within the trust region
    (`_size` at most STEP, where the linearisation holds), from no motion (where the balance is
    `r` with Jacobian `jac`): Newton's method with a backtracking line search on the scaled
    residual, stopping at the region's edge, or scipy's bounded least squares where it stalls;
    None when neither gives a finite motion."""
    q = np.zeros(6)
    size = np.linalg.norm(r * scale)
    for _ in range(60):
        if size < 1e-10:
            return q
        step = _descent_step(jac, r)
        t, edge = 1.0, False
        if _size(q + step) > STEP:  # walk to the region's edge, no further
            lo, hi = 0.0, 1.0
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if _size(q + mid * step) <= STEP else (lo, mid)
            t, edge = lo, True
        while t > 1e-3:
            trial = q + t * step
            r_t, jac_t = _balance(trial, groups, weight)
            size_t = np.linalg.norm(r_t * scale)
            if np.isfinite(size_t) and size_t < (1 - 1e-4 * t) * size:
                break
            t *= 0.5
            edge = False
        else:
            return _least_squares(q, groups, weight, scale)
        q, r, jac, size = trial, r_t, jac_t, size_t
        if edge:
            return q
    return q if size < 1e-6 else _least_squares(q, groups, weight, scale)


def _least_squares(q, groups, weight, scale) -> np.ndarray | None:
    """Where Newton's steps stall on a change of contact (a body tipping onto its feet): the
    motion of least imbalance within the trust region (a box of STEP, STEP / LEVER for the
    turn), by scipy's bounded trust-region least squares; None when it is not finite."""
    from scipy.optimize import least_squares

    last = {}

    def both(z):  # the solver asks for the residual and then the Jacobian at the same point
        key = z.tobytes()
        if key not in last:
            last.clear()
            last[key] = _balance(z, groups, weight)
        return last[key]

    box = np.array([STEP] * 3 + [STEP / LEVER] * 3) / np.sqrt(3.0)
    sol = least_squares(lambda z: both(z)[0] * scale, np.clip(q, -box, box),
                        jac=lambda z: both(z)[1] * scale[:, None], bounds=(-box, box),
                        method="trf", x_scale=np.array([0.01] * 3 + [0.02] * 3), xtol=1e-12,
                        ftol=1e-12, gtol=1e-12, max_nfev=60)
    return sol.x if np.all(np.isfinite(sol.x)) else None


def _tips(jac: np.ndarray) -> bool:
    """Whether a rest is unstable: the stiffness K = -d(balance)/d(motion), with the turning of
    the contact forces' arms that gravity drives, has an eigenvalue with a negative real part
    (a direction in which the body gives way and does not come back: it tips). Friction makes K
    unsymmetric; its eigenvalues' real parts, not its symmetric part's, decide divergence. The
    turn is measured at LEVER."""
    d = np.array([1.0] * 3 + [1.0 / LEVER] * 3)
    k = -(jac * d[None, :]) * d[:, None]
    eig = np.linalg.eigvals(k)
    return bool(eig.real.min() < -1e-6 * np.abs(eig).max())


def _too_far(q: np.ndarray) -> str | None:
    """Why a settle that moved the body by q = (u, theta) has gone further than a rest can be,
    or None."""
    turn, shift = np.degrees(np.linalg.norm(q[3:])), np.linalg.norm(q[:3])
    if turn > np.degrees(MAX_TURN) or (shift > MAX_SHIFT and turn > 10.0):
        return f"tips over (turns {turn:.0f} degrees, moves {shift * 100:.0f} cm)"
    if shift > MAX_SHIFT:
        return f"slides off or sinks through (moves {shift * 100:.0f} cm)"
    return None


def _unsettled(reason, x, c0, shift, rot, weight) -> Settled:
    """A settle that found no rest: where it stopped, and why."""
    size = float(np.linalg.norm(weight))
    return Settled(False, reason, x, shift, Rotation.from_matrix(rot).as_rotvec(), c0, [],
                   np.full(3, np.nan), np.full(3, np.nan), size, gravity=weight / size)


def _settled(x, c0, shift, rot, groups, supports, residual, weight, outer) -> Settled:
    """The body at rest: its contacts per support part and the balance left over."""
    contacts = []
    for cand, foam, area, arm, slip0 in groups:
        on, _, _, fn, ft = _laws(np.zeros(6), cand, foam, area, arm, slip0)
        contacts += _contacts(supports[cand.support], cand, area, on, fn, ft)
    size = float(np.linalg.norm(weight))
    return Settled(True, None, x, shift, Rotation.from_matrix(rot).as_rotvec(), c0, contacts,
                   residual[:3].copy(), residual[3:].copy(), size, outer, weight / size)


def _contacts(s: Support, cand: _Candidates, area, on, fn, ft) -> list[SupportContact]:
    """The loaded contacts (`on`, with normal forces `fn` and friction `ft`, over their
    footprints `area`) of one support, one per part where the support names them."""
    idx = np.flatnonzero(on)
    loaded = fn > 0
    parts = [(s.name, loaded)]
    if s.parts is not None:
        names = np.asarray(s.parts(cand.index[idx], cand.normal[idx]))
        parts = [(str(n), loaded & (names == n)) for n in dict.fromkeys(names.tolist())]
    out = []
    for name, m in parts:
        if m.any():
            i = idx[m]
            out.append(SupportContact(name, cand.index[i], fn[m], ft[m], cand.normal[i],
                                      cand.point[i], cand.face[i], area[i]))
    return out
