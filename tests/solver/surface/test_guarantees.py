"""The guarantees report on hand-made surfaces: each check finds what it is for."""

import numpy as np
import pytest
import trimesh

from solver.contact.evaluate import penetration_depth
from solver.mesh import quad_triangles, self_intersections
from solver.surface import guarantees
from solver.surface.guarantees import barycentric_samples, crossing_pairs, disk_border, \
    fold_angles, neighbour_faces, one_to_one_over_plane, quad_normals, surface_guarantees


def grid(n: int = 4, size: float = 2.0, height: float = 0.5, offset=(0.0, 0.0)):
    """A flat n x n quad sheet at y = height over [-size/2, size/2]^2 (x, z), facing +Y."""
    t = np.linspace(-size / 2, size / 2, n + 1)
    x, z = np.meshgrid(t + offset[0], t + offset[1], indexing="ij")
    v = np.stack([x.ravel(), np.full(x.size, height), z.ravel()], axis=1)
    k = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    quads = np.stack([k[:-1, :-1], k[:-1, 1:], k[1:, 1:], k[1:, :-1]], axis=-1).reshape(-1, 4)
    return v, quads


def box(half: float = 0.2, centre=(0.0, 0.0, 0.0)):
    mesh = trimesh.creation.box(extents=[2 * half] * 3)
    return np.asarray(mesh.vertices) + np.asarray(centre), np.asarray(mesh.faces)


def test_a_flat_grid_is_ok():
    v, q = grid()
    g = surface_guarantees(v, q, [], margin=0.03)
    assert g["self_intersections"] == 0 and g["folds"] == 0
    assert g["max_fold_deg"] == pytest.approx(0.0, abs=1e-6)
    assert g["min_height_m"] == pytest.approx(0.5) and not g["below_floor"]
    assert g["max_penetration_dense_m"] == 0.0 and g["ok"]


def test_a_vertex_pulled_through_folds_the_grid():
    v, q = grid(n=4, size=2.0)
    centre = int(np.argmin(np.linalg.norm(v[:, [0, 2]], axis=1)))
    v[centre] += [1.2, 0.0, 0.0]  # through its neighbour at x = 0.5: the quads flip
    g = surface_guarantees(v, q, [], margin=0.03)
    assert g["folds"] > 0 and g["max_fold_deg"] > 150 and not g["ok"]


def test_a_crease_is_no_fold():
    v, q = grid(n=2, size=2.0)
    v[v[:, 0] > 0.5, 1] += 2.0  # the last column of quads stands up along x = 0
    edge = np.flatnonzero(np.isclose(v[:, 0], 0.0))
    sharp = np.stack([edge[:-1], edge[1:]], axis=1)
    assert fold_angles(v, q).max() > 60
    assert fold_angles(v, q, sharp).max() == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("turn_deg, slit", [(100.0, False), (145.0, False), (160.0, True)])
def test_a_crease_folded_back_on_itself_is_a_slit(turn_deg, slit):
    """Faces across a crease may turn sharply (a seat meets its back), not fold back onto
    each other: past 150 degrees between their normals (30 between the faces) the check
    counts a slit and the surface is not ok; the other guarantees leave creases alone."""
    v, q = grid(n=2, size=2.0)
    a = np.radians(turn_deg)
    far = v[:, 0] > 0.5  # the last column of quads, turned about the line x = 0
    v[far, 0], v[far, 1] = np.cos(a) * v[far, 0], 0.5 + np.sin(a) * v[far, 0]
    edge = np.flatnonzero(np.isclose(v[:, 0], 0.0) & np.isclose(v[:, 1], 0.5))
    sharp = np.stack([edge[:-1], edge[1:]], axis=1)
    g = surface_guarantees(v, q, [], margin=0.03, floor=None, sharp_edges=sharp)
    assert g["folds"] == 0 and g["max_crease_deg"] == pytest.approx(turn_deg, abs=1e-6)
    assert (g["slits"] > 0) == slit and g["ok"] == (not slit)


def test_two_crossing_sheets_intersect():
    a, qa = grid(n=2, height=0.5)
    b, qb = grid(n=2, height=0.5)
    b = b[:, [1, 0, 2]]  # the same sheet turned upright, in the plane x = 0.5
    b[:, 0] -= 0.25
    b[:, 1] += 0.5  # spans y 0.5 +- 1, crossing the first sheet along x = 0.25
    v = np.concatenate([a, b])
    q = np.concatenate([qa, qb + len(a)])
    g = surface_guarantees(v, q, [], margin=0.03)
    assert g["self_intersections"] > 0 and not g["ok"]
    assert surface_guarantees(a, qa, [], margin=0.03)["self_intersections"] == 0


def test_a_sheet_below_the_floor():
    v, q = grid(height=-0.024)
    g = surface_guarantees(v, q, [], margin=0.03, floor=0.0)
    assert g["below_floor"] and g["min_height_m"] == pytest.approx(-0.024) and not g["ok"]
    assert not surface_guarantees(v, q, [], margin=0.03, floor=None)["below_floor"]
    assert not surface_guarantees(v, q, [], 0.03, floor=-0.0235)["below_floor"]  # within 1 mm


def test_dense_penetration_finds_a_cut_between_vertices():
    v, q = grid(n=3, size=2.0, height=0.05)  # vertices at x, z in {-1, -1/3, 1/3, 1}
    body = box(half=0.2)  # between the vertices: none of them is inside
    triangles = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    assert penetration_depth(v, *body) == 0.0  # the vertex-only check misses it
    g = surface_guarantees(v, q, [body], margin=0.03)
    assert g["max_penetration_dense_m"] == pytest.approx(0.15, abs=0.02)
    assert not g["ok"]
    assert len(barycentric_samples(v, triangles)) == 15 * len(triangles)
    far = box(half=0.2, centre=(0.0, 1.0, 0.0))
    assert surface_guarantees(v, q, [far], margin=0.03)["max_penetration_dense_m"] == 0.0


def test_bad_shapes_are_refused():
    v, q = grid()
    with pytest.raises(ValueError, match=r"quads \(F, 4\), got"):
        surface_guarantees(v, q[:, :3], [], margin=0.03)
    with pytest.raises(ValueError, match="margin >= 0"):
        surface_guarantees(v, q, [], margin=-1.0)


def test_disk_border_is_the_grids_rim_and_none_for_other_meshes():
    v, q = grid(n=4)
    border = disk_border(q, len(v))
    assert len(border) == 16 and set(border) == set(np.flatnonzero(
        np.isclose(np.abs(v[:, [0, 2]]).max(axis=1), 1.0)))
    assert np.all(np.abs(np.diff(v[np.r_[border, border[0]]][:, [0, 2]], axis=0)).sum(axis=1)
                  == pytest.approx(0.5))  # in order round the rim
    flipped = q.copy()
    flipped[5] = flipped[5, ::-1]  # one quad the other way round
    assert disk_border(flipped, len(v)) is None
    k = np.arange(25).reshape(5, 5)  # the grid's last column glued to its first: a tube
    k[:, -1] = k[:, 0]
    tube = np.stack([k[:-1, :-1], k[:-1, 1:], k[1:, 1:], k[1:, :-1]], axis=-1).reshape(-1, 4)
    _, tube = np.unique(tube, return_inverse=True)  # the 20 vertices left, numbered afresh
    assert disk_border(tube.reshape(-1, 4), 20) is None
    assert disk_border(np.concatenate([q, q + len(v)]), 2 * len(v)) is None  # two pieces


def test_one_to_one_over_a_plane_means_no_crossing():
    """Bumpy sheets that lie one-to-one over a plane cross nowhere (as the exact test finds),
    nor does one whose edge leans back past upright (one-to-one over a tilted plane); a sheet
    folded over itself, or a ramp wound over itself, is not one-to-one."""
    rng = np.random.default_rng(5)
    v, q = grid(n=8)
    triangles, border = quad_triangles(q), disk_border(q, len(v))
    for _ in range(20):
        bumpy = v + rng.normal(scale=[0.02, 0.2, 0.02], size=v.shape)
        assert one_to_one_over_plane(bumpy, triangles, border)
        assert len(self_intersections(bumpy, triangles)) == 0
    leaning = v.copy()  # the last columns stand up and lean back over the sheet, past upright
    rise = np.maximum(v[:, 0] - 0.5, 0.0)
    leaning[:, 0] = np.minimum(v[:, 0], 0.5) - 0.1 * rise
    leaning[:, 1] += rise
    assert np.min(quad_normals(leaning, q)[:, 1]) < 0  # not one-to-one over the floor, ...
    assert one_to_one_over_plane(leaning, triangles, border)  # but over a tilted plane
    assert len(self_intersections(leaning, triangles)) == 0
    folded = v.copy()
    folded[v[:, 0] > 0.6] *= [-1.0, 1.0, 1.0]  # the last columns laid back over the others
    folded[v[:, 0] > 0.6, 1] += 0.1
    assert not one_to_one_over_plane(folded, triangles, border)
    angle = np.linspace(0.0, 3.0 * np.pi, 9)[:, None]  # a ramp one and a half turns round
    radius = np.linspace(1.0, 2.0, 9)[None, :]
    ramp = np.stack([radius * np.cos(angle), 0.5 * angle + 0.0 * radius,
                     radius * np.sin(angle)], axis=-1).reshape(-1, 3)
    assert len(self_intersections(ramp, triangles)) == 0
    assert not one_to_one_over_plane(ramp, triangles, border)


def _figure_eight(n: int = 60, m: int = 12):
    """A strip swept along a figure of eight (x, y) = (cos t, sin t cos t) and across z: it
    passes through itself along the line x = y = 0. n x m quads."""
    t = np.linspace(0.15, 2 * np.pi - 0.15, n + 1)[:, None]
    z = np.linspace(-0.5, 0.5, m + 1)[None, :]
    v = np.stack([np.cos(t) + 0 * z, np.sin(t) * np.cos(t) + 0 * z, z + 0 * t],
                 axis=-1).reshape(-1, 3)
    k = np.arange((n + 1) * (m + 1)).reshape(n + 1, m + 1)
    quads = np.stack([k[:-1, :-1], k[:-1, 1:], k[1:, 1:], k[1:, :-1]], axis=-1).reshape(-1, 4)
    return v, quads


@pytest.mark.parametrize("leaf", [8, 64, 512])
def test_crossing_pairs_are_the_exact_tests_pairs(monkeypatch, leaf):
    """The search by pieces finds the very pairs that the exact test over all pairs finds: on a
    strip swept along a figure of eight (it passes through itself), a bumpy sheet folded back
    over itself and pierced by its own flap, two sheets crossing each other (no disk) and
    bumpy sheets that cross nowhere (each piece one-to-one over a plane); with small pieces,
    so that cuts pass through the crossings, and large."""
    monkeypatch.setattr(guarantees, "CROSSING_LEAF", leaf)
    rng = np.random.default_rng(7)
    cases = []
    v, q = _figure_eight()
    cases.append((v, quad_triangles(q), 1))
    v, q = grid(n=24)
    folded = v + rng.normal(scale=[0.0, 0.01, 0.0], size=v.shape)
    back = v[:, 0] > 0.3  # the last columns laid back over the others, dipping through them
    folded[back, 0] = 0.6 - v[back, 0]
    folded[back, 1] += 0.05 - 0.3 * (v[back, 0] - 0.3)
    cases.append((folded, quad_triangles(q), 1))
    a, qa = grid(n=10, height=0.5)
    b = a[:, [1, 0, 2]] + [-0.25, 0.5, 0.0]  # upright, crossing the first along x = 0.25
    cases.append((np.concatenate([a, b]), quad_triangles(np.concatenate([qa, qa + len(a)])), 1))
    for _ in range(3):
        cases.append((v + rng.normal(scale=[0.01, 0.1, 0.01], size=v.shape), quad_triangles(q),
                      0))
    kept = {}  # the pieces' topology, kept per triangulation across the cases and calls
    for vertices, triangles, crossing in cases:
        exact = self_intersections(vertices, triangles)
        exact = np.sort(exact, axis=1)
        exact = exact[np.lexsort((exact[:, 1], exact[:, 0]))]
        assert (len(exact) > 0) == bool(crossing)  # the premise
        np.testing.assert_array_equal(crossing_pairs(vertices, triangles), exact)
        np.testing.assert_array_equal(crossing_pairs(vertices, triangles, whole_tried=True),
                                      exact)
        pieces = kept.setdefault(triangles.tobytes(), {})
        for _ in range(2):  # filling the cache, then from it (other geometry, same pieces)
            np.testing.assert_array_equal(crossing_pairs(vertices, triangles, pieces=pieces),
                                          exact)
    # the four sheets of one grid share their pieces' topology: the cache served them
    assert len(kept) == 3 and all(len(p) <= guarantees.PIECES_KEPT for p in kept.values())


def test_the_pieces_kept_are_bounded(monkeypatch):
    """With room for two pieces the cache is emptied when full, and the pairs stay exact."""
    monkeypatch.setattr(guarantees, "CROSSING_LEAF", 8)
    monkeypatch.setattr(guarantees, "PIECES_KEPT", 2)
    v, q = _figure_eight()
    triangles = quad_triangles(q)
    exact = np.sort(self_intersections(v, triangles), axis=1)
    exact = exact[np.lexsort((exact[:, 1], exact[:, 0]))]
    pieces = {}
    for _ in range(2):
        np.testing.assert_array_equal(crossing_pairs(v, triangles, pieces=pieces), exact)
        assert 1 <= len(pieces) <= 2


def test_neighbour_faces_of_triangles_are_trimesh_s_face_adjacency():
    """Triangles (a bumpy sheet's quads split) give the neighbour pairs trimesh finds."""
    rng = np.random.default_rng(3)
    v, q = grid(n=6)
    v = v + rng.normal(scale=[0.0, 0.05, 0.0], size=v.shape)
    t = quad_triangles(q)
    mine = {tuple(sorted(p)) for p in neighbour_faces(t)}
    theirs = {tuple(sorted(p)) for p in trimesh.Trimesh(v, t, process=False).face_adjacency}
    assert mine == theirs and len(mine) == 2 * 6 * 5 + 36  # inner edges, and each diagonal


def test_dense_penetration_finds_a_cut_deeper_between_its_samples():
    # a ball pressed 35 mm through a flat quad's middle, which no sample of the 4-part grid
    # is near: at 15 samples a triangle the cut looked 29 mm deep (within the 30 mm margin and
    # its 1 mm tolerance), as a side-lying body's lounger cut 32.0 mm and was reported 30.5
    s = 0.2  # the quad's side: samples 5 cm apart
    v = np.array([[0.0, 0.0, 0.0], [s, 0.0, 0.0], [s, 0.0, s], [0.0, 0.0, s]])
    q = np.array([[0, 3, 2, 1]])  # (facing +y)
    triangles = quad_triangles(q)
    foot = np.array([s * 0.375, 0.0, s * 0.125])  # between samples of the triangle it is in
    ball = trimesh.creation.icosphere(subdivisions=5, radius=0.1)
    body = (np.asarray(ball.vertices) + foot + [0.0, 0.065, 0.0], np.asarray(ball.faces))
    coarse = penetration_depth(barycentric_samples(v, triangles), *body)
    assert coarse < 0.031  # what the samples alone see
    g = surface_guarantees(v, q, [body], margin=0.03, floor=None)
    assert g["max_penetration_dense_m"] == pytest.approx(0.035, abs=0.001)
    assert not g["ok"]
    shallow = (body[0] + [0.0, 0.03, 0.0], body[1])  # 5 mm deep
    g = surface_guarantees(v, q, [shallow], margin=0.03, floor=None)
    assert g["max_penetration_dense_m"] == pytest.approx(0.005, abs=0.001) and g["ok"]
    far = (body[0] + [0.0, 0.2, 0.0], body[1])  # clear of it
    assert guarantees.penetration_between_samples(v, triangles, [far], 0.03) == 0.0
