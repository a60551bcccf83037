"""Solids: closed, manifold (trimesh and manifold3d say so), the asked thickness, folds found,
files in millimetres with Z up."""

import io
import zipfile

import numpy as np
import pytest
import trimesh

from solver.io.solid import (SolidError, boundary_edges, check_solid, model_3mf, plinth,
                             self_intersections, thicken, workshop_vertices, write_3mf,
                             write_stl)
from solver.mesh import quad_triangles, voronoi_areas

from .conftest import bent_grid, underside_distances


def test_boundary_edges_of_one_quad_run_its_way():
    edges = boundary_edges(np.array([[0, 1, 2, 3]]))
    assert sorted(map(tuple, edges)) == [(0, 1), (1, 2), (2, 3), (3, 0)]


def test_boundary_edges_refuse_a_flipped_neighbour():
    with pytest.raises(SolidError, match="consistently oriented"):
        boundary_edges(np.array([[0, 1, 2], [0, 1, 3]]))


def test_offset_of_a_trough_is_watertight_manifold_and_as_thick_as_asked(trough):
    vertices, quads, _ = trough
    solid = thicken(vertices, quads, 0.005)
    check = check_solid(solid)
    assert check.ok, check.problem()
    assert check.watertight and check.winding_consistent and check.manifold_status == "NoError"
    assert abs(check.thickness_min_m - 0.005) <= 1e-4
    assert abs(check.thickness_max_m - 0.005) <= 1e-4
    # a shell over the trough's hollow grows outwards: a little over thickness x area
    area = voronoi_areas(vertices, quad_triangles(quads)).sum()
    assert 0.005 * area < check.volume_m3 < 1.05 * 0.005 * area


def test_plain_offset_deeper_than_a_ridge_radius_folds_and_is_refused(ridge):
    vertices, quads, _ = ridge
    assert check_solid(thicken(vertices, quads, 0.006)).ok  # under the 12 mm radius
    check = check_solid(thicken(vertices, quads, 0.02, check=False, trim=False))
    assert check.watertight and check.folded_faces > 0 and not check.ok
    assert "fold over" in check.problem()
    assert check.intersecting_pairs > 0  # the exact test sees the fold cross itself too


@pytest.mark.parametrize("thickness", [0.02, pytest.param(0.03, marks=pytest.mark.slow)])
def test_offset_deeper_than_a_ridge_radius_is_trimmed_into_a_sound_solid(ridge, thickness):
    """Under a 12 mm ridge the plain offset folds; trimmed, the solid is closed and manifold
    (trimesh, manifold3d), crosses nowhere, keeps the surface as its top, and its underside
    lies the thickness from the surface within 0.1 mm by trimesh's own distance query."""
    vertices, quads, _ = ridge
    solid = thicken(vertices, quads, thickness)
    check = check_solid(solid)
    assert check.ok, check.problem()
    assert solid.trimmed > 0 and check.trimmed == solid.trimmed
    mesh = trimesh.Trimesh(solid.vertices, solid.triangles, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert check.intersecting_pairs == 0 and check.folded_faces == 0
    assert np.array_equal(solid.vertices[:len(vertices)], vertices)
    # the top is the surface: the triangles lying on it cover its area exactly
    surface = trimesh.Trimesh(vertices, quad_triangles(quads), process=False)
    on_top = np.abs(trimesh.proximity.signed_distance(
        surface, solid.vertices[solid.triangles].mean(axis=1))) < 1e-9
    assert mesh.area_faces[on_top].sum() == pytest.approx(surface.area, rel=1e-9)
    at_vertices, at_middles = underside_distances(solid)
    assert len(at_vertices) > 100 and len(at_middles) > 100
    for dist in (at_vertices, at_middles):
        assert np.all(np.abs(dist - thickness) <= 1e-4), (dist.min(), dist.max())
    # the trimmed shell holds less than thickness x area (the ridge's inside is shared)
    area = voronoi_areas(vertices, quad_triangles(quads)).sum()
    assert 0.7 * thickness * area < check.volume_m3 < thickness * area
    # few slivers where the merged pieces meet (under 1 um high: 327 of 3,840 triangles at
    # 2 cm and 1,227 of 7,262 at 3 cm before they were flipped and collapsed away, 67 of 3,652
    # and 353 of 6,662 after)
    corners = solid.vertices[solid.triangles]
    longest = np.linalg.norm(np.roll(corners, -1, axis=1) - corners, axis=2).max(axis=1)
    low = 2 * mesh.area_faces / longest < 1e-6
    assert low.sum() < 0.07 * len(solid.triangles), (low.sum(), len(solid.triangles))


def test_trimmed_solid_keeps_nothing_in_front_of_a_tight_ridge():
    """Over a 3 mm ridge in coarse quads (no edge folds past 90 degrees) the 1 cm offset is
    trimmed into one convex piece per triangle, swept along the normals of the faces around
    its corners. Those turn further than 90 degrees from a triangle near the ridge, and the
    pieces stood through the top in front of it: 0.1 mm in front of 20 of the 48 triangles
    lay inside the solid, one of them inside only the piece of a triangle 80 degrees away
    that shares a single corner with it. With the region in front of the surface cut away,
    0.1 mm in front of every triangle lies outside (trimesh's ray test and the module's
    winding number), the top is still the surface, and the solid passes every check."""
    vertices, quads, _ = bent_grid(radius=0.003, bend=-1.0, columns=13, rows=3, width=0.04,
                                   length=0.01)
    solid = thicken(vertices, quads, 0.01, check=False)
    check = check_solid(solid)
    assert solid.trimmed > 0 and check.surface_folds == 0
    assert check.over_surface == 0 and check.ok, check.problem()
    mesh = trimesh.Trimesh(solid.vertices, solid.triangles, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    surface = trimesh.Trimesh(vertices, quad_triangles(quads), process=False)
    probes = surface.triangles_center + 1e-4 * surface.face_normals
    assert not mesh.contains(probes).any()
    # (a few slivers the cut left on the top, a fraction of a square millimetre, lie up to
    # a tenth of a micrometre off it)
    on_top = np.abs(trimesh.proximity.signed_distance(
        surface, solid.vertices[solid.triangles].mean(axis=1))) < 1e-7
    assert mesh.area_faces[on_top].sum() == pytest.approx(surface.area, rel=1e-6)


def test_crossing_triangles_are_found_and_neighbours_are_not():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],  # flat
                         [0.2, 0.2, -0.5], [0.2, 0.2, 0.5], [0.3, 0.25, 0.0],  # through it
                         [2, 0, 0], [3, 0, 0], [2, 1, 0.0]])  # apart, coplanar
    pairs = self_intersections(vertices, np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8],
                                                   [1, 6, 2]]))
    assert pairs.tolist() == [[0, 1]]


def test_plinth_fills_down_to_the_floor(trough):
    vertices, quads, _ = trough
    solid = plinth(vertices, quads)
    check = check_solid(solid)
    assert check.ok, check.problem()
    tris = quad_triangles(quads)
    # the volume under a height field: each triangle's shadow area times its mean height
    corners = vertices[tris]
    shadow = 0.5 * np.abs(np.cross(corners[:, 1] - corners[:, 0],
                                   corners[:, 2] - corners[:, 0])[:, 1])
    assert check.volume_m3 == pytest.approx((shadow * corners[:, :, 1].mean(axis=1)).sum(),
                                            rel=1e-5)
    assert solid.vertices[solid.n_surface:, 1].max() == 0.0


@pytest.mark.parametrize("thickness", [0.0, -0.01, float("nan")])
def test_bad_thickness_is_named(trough, thickness):
    with pytest.raises(SolidError, match="thickness > 0"):
        thicken(trough[0], trough[1], thickness)


def test_plinth_needs_the_surface_above_the_floor_and_no_overhang(trough, ridge):
    vertices, quads, _ = trough
    with pytest.raises(SolidError, match="above the floor"):
        plinth(vertices - [0.0, 0.2, 0.0], quads)
    folded = vertices.copy()
    folded[:, 0] = np.where(folded[:, 0] > 0.02, 0.04 - folded[:, 0], folded[:, 0])
    with pytest.raises(SolidError, match="overhangs"):
        plinth(folded, quads)


def test_bad_faces_are_named(trough):
    with pytest.raises(SolidError, match="face indices"):
        thicken(trough[0], trough[1] + 10_000, 0.01)


def test_workshop_frame_is_millimetres_z_up_and_not_mirrored():
    assert np.allclose(workshop_vertices([[1.0, 2.0, 3.0]]), [[1000.0, -3000.0, 2000.0]])
    assert np.linalg.det(workshop_vertices(np.eye(3))) > 0


def test_stl_reads_back_closed_in_millimetres_with_z_up(tmp_path, trough):
    solid = thicken(trough[0], trough[1], 0.005)
    mesh = trimesh.load(write_stl(tmp_path / "solid.stl", solid))
    assert mesh.is_watertight and mesh.is_winding_consistent
    hi = mesh.bounds[1]
    assert hi[2] == pytest.approx(solid.vertices[:, 1].max() * 1000, abs=1e-3)  # height -> Z
    assert hi[1] == pytest.approx(-solid.vertices[:, 2].min() * 1000, abs=1e-3)
    assert mesh.volume == pytest.approx(check_solid(solid).volume_m3 * 1e9, rel=1e-4)


def test_3mf_reads_back_with_lib3mf_in_millimetres(tmp_path, trough):
    import lib3mf

    solid = thicken(trough[0], trough[1], 0.005)
    path = write_3mf(tmp_path / "solid.3mf", solid)
    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    model.QueryReader("3mf").ReadFromFile(str(path))
    assert model.GetUnit() == lib3mf.ModelUnit.MilliMeter
    objects = model.GetMeshObjects()
    assert objects.MoveNext()
    mesh = objects.GetCurrentMeshObject()
    assert (mesh.GetVertexCount(), mesh.GetTriangleCount()) == (
        len(np.unique(solid.triangles)), len(solid.triangles))
    names = zipfile.ZipFile(io.BytesIO(model_3mf(solid))).namelist()
    assert "3D/3dmodel.model" in names


def _sphere():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    return np.array(mesh.vertices), np.array(mesh.faces, dtype=np.int64)


def _sound(vertices, triangles):
    """trimesh's and manifold3d's word on a closed mesh."""
    import manifold3d

    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    status = manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(vertices),
        tri_verts=np.ascontiguousarray(triangles, dtype=np.uint64))).status().name
    return mesh.is_watertight and mesh.is_winding_consistent and status == "NoError"


def test_short_edges_of_the_underside_collapse_and_the_mesh_stays_closed():
    from solver.io.solid import _collapse_short

    v, t = _sphere()
    a, b = t[0, 0], t[0, 1]
    v[b] = v[a] + 1e-4 * (v[b] - v[a]) / np.linalg.norm(v[b] - v[a])  # a 0.1 mm edge
    up = trimesh.Trimesh(v, t, process=False).face_normals
    movable = np.ones(len(v), dtype=bool)
    out_v, out_t, keep, alive = _collapse_short(v, t, movable, ~movable, v, up, 3e-4)
    assert (len(out_v), len(out_t)) == (len(v) - 1, len(t) - 2)
    assert keep.sum() == len(out_v) and alive.sum() == len(out_t)
    assert _sound(out_v, out_t)
    edges = np.concatenate([out_t[:, [0, 1]], out_t[:, [1, 2]], out_t[:, [2, 0]]])
    assert np.linalg.norm(out_v[edges[:, 0]] - out_v[edges[:, 1]], axis=1).min() > 3e-4
    # an edge between vertices that may not move stays
    movable[:] = False
    assert len(_collapse_short(v, t, movable, ~movable, v, up, 3e-4)[0]) == len(v)


def test_snapping_moves_vertices_but_never_turns_a_face_over():
    from solver.io.solid import _snap
    from solver.mesh import face_cross

    v, t = _sphere()
    up = -trimesh.Trimesh(v, t, process=False).face_normals  # "bodies" at the centre
    movable = np.ones(len(v), dtype=bool)
    grown = _snap(v, t.copy(), 1.002 * v, movable, up)
    np.testing.assert_allclose(grown, 1.002 * v, atol=1e-12)
    # one vertex asked through the sphere to its far side: it may not go all the way
    target = v.copy()
    target[0] = -0.5 * v[0]
    tris = t.copy()
    moved = _snap(v, tris, target, movable, up)
    before, after = face_cross(v, t), face_cross(moved, tris)
    ring = (t == 0).any(axis=1)
    assert np.all(np.einsum("ij,ij->i", before[ring], after[ring]) > 0)
    assert np.linalg.norm(moved[0] - target[0]) > 0.01
    assert _sound(moved, tris)


def test_a_vertex_left_short_of_the_thickness_is_mended_away(trough):
    """An underside vertex 0.15 mm short of the 5 mm thickness (a triangle of the sheet split at a
    point raised towards the surface) is collapsed into a neighbour; the solid stays closed,
    the surface's vertices stay where they are, and trimesh finds every underside vertex at
    the thickness."""
    from solver.io.solid import _mend
    from solver.mesh import SurfaceMesh

    vertices, faces, _ = trough
    solid = thicken(vertices, faces, 0.005)
    v, tris, n = solid.vertices, solid.triangles, solid.n_surface
    sheet = np.flatnonzero((tris >= n).all(axis=1))
    face = sheet[len(sheet) // 2]
    a, b, c = tris[face]
    centre = v[[a, b, c]].mean(axis=0)
    surface = SurfaceMesh.from_triangles(v[:n], solid.surface_triangles)
    dist, _, _, _, foot = surface.closest(centre[None])
    raised = foot[0] + (0.005 - 1.5e-4) * (centre - foot[0]) / dist[0]
    k = len(v)
    v = np.vstack([v, raised])
    tris = np.vstack([np.delete(tris, face, axis=0), [[a, b, k], [b, c, k], [c, a, k]]])
    assert _sound(v, tris)
    fixed = np.arange(len(v)) < n
    out_v, out_t, out_fixed = _mend(v, tris, fixed, surface,
                                    boundary_edges(solid.surface_triangles), 0.005)
    assert len(out_v) == len(v) - 1 and out_fixed.sum() == n
    np.testing.assert_array_equal(out_v[out_fixed], v[:n])
    assert _sound(out_v, out_t)
    query = trimesh.proximity.ProximityQuery(
        trimesh.Trimesh(v[:n], solid.surface_triangles, process=False))
    under = np.unique(out_t[(out_t >= n).all(axis=1)])
    assert np.abs(np.abs(query.signed_distance(out_v[under])) - 0.005).max() < 1e-4


def test_touching_corners_are_parted_so_single_precision_keeps_them_apart():
    """Three tetrahedra meeting at one point through three distinct corners (as merged pieces
    leave them): after parting, written as float32 millimetres the corners stay distinct and
    the welded mesh is still closed."""
    from solver.io.solid import _part_touching, workshop_vertices

    tip = np.array([0.3, 0.4, 0.5])
    vertices, triangles = [], []
    for k in range(3):
        angle = 2 * np.pi * k / 3
        out = np.array([np.cos(angle), 0.0, np.sin(angle)])
        side = np.cross(out, [0.0, 1.0, 0.0])
        base = tip + 0.01 * out
        corners = [tip, base + 0.005 * side, base - 0.005 * side, base + [0.0, 0.008, 0.0]]
        tet = trimesh.convex.convex_hull(np.array(corners))
        triangles.append(np.array(tet.faces) + 4 * k)
        vertices.extend(np.array(tet.vertices))
    vertices, triangles = np.array(vertices), np.vstack(triangles)
    fixed = np.zeros(len(vertices), dtype=bool)
    parted = _part_touching(vertices, triangles, fixed)
    single = workshop_vertices(parted).astype(np.float32)
    corners, weld = np.unique(single, axis=0, return_inverse=True)
    assert len(corners) == len(vertices)
    assert trimesh.Trimesh(corners, weld.ravel()[triangles], process=False).is_watertight
    # the untouched corners stay; the moved ones move by micrometres
    moved = np.linalg.norm(parted - vertices, axis=1)
    assert (moved > 0).sum() == 2 and moved.max() < 1e-4


def test_an_edge_too_short_for_single_precision_is_lengthened_along_the_sheet():
    """An edge of 0.04 um (which float32 millimetres would fuse) is lengthened to a quarter of
    `TINY_EDGE` by moving its end with fewer triangles towards its own neighbours: the mesh
    stays closed and its faces keep their directions."""
    from solver.io.solid import TINY_EDGE, _lengthen, workshop_vertices
    from solver.mesh import face_cross

    v, t = _sphere()
    p, q = t[0, 0], t[0, 1]
    v[q] = v[p] + 4e-8 * (v[q] - v[p]) / np.linalg.norm(v[q] - v[p])
    before = face_cross(v, t)
    out = _lengthen(v.copy(), t, p, q, np.zeros(len(v), dtype=bool))
    assert np.linalg.norm(out[p] - out[q]) > 0.2 * TINY_EDGE
    assert len(np.unique(workshop_vertices(out).astype(np.float32), axis=0)) == len(v)
    after = face_cross(out, t)
    big = np.linalg.norm(before, axis=1) > 1e-12
    assert np.all(np.einsum("ij,ij->i", before[big], after[big]) > 0)
    assert _sound(out, t)


def test_lengthening_never_turns_a_sliver_over():
    """Where the move towards its own neighbours would take the end across a sliver's far
    edge (2 um away), the end moves off the sheet along its normal instead (as far, a quarter
    of `TINY_EDGE`), which turns no face over."""
    from solver.io.solid import TINY_EDGE, _lengthen
    from solver.mesh import face_cross

    p, q = [0.0, 2e-6, 0.0], [0.0, 2.04e-6, 0.0]
    v = np.array([p, q, [1e-3, 0, 0], [-1e-3, 0, 0], [0, 1e-3, 0], [1e-3, 1e-3, 0],
                  [-1e-3, 1e-3, 0]])
    t = np.array([[0, 3, 2], [1, 0, 4], [1, 4, 5], [1, 6, 4]])
    out = _lengthen(v.copy(), t, 0, 1, np.zeros(len(v), dtype=bool))
    moved = np.flatnonzero(np.any(out != v, axis=1))
    assert len(moved) == 1
    shift = out[moved[0]] - v[moved[0]]
    np.testing.assert_allclose(shift[:2], 0.0, atol=1e-15)  # off the sheet (z), not along it
    assert abs(shift[2]) == pytest.approx(0.25 * TINY_EDGE)
    before, after = face_cross(v, t), face_cross(out, t)
    big = np.linalg.norm(before, axis=1) > 0
    assert np.all(np.einsum("ij,ij->i", before[big], after[big]) > 0)


@pytest.mark.parametrize("thickness, fine", [(0.1, True), (0.001, True), (0.3, False),
                                             (float("inf"), False), (1e-9, False)])
def test_the_fit_command_bounds_the_solid_it_will_trim(tmp_path, capsys, thickness, fine):
    """An offset 0.1 m thick takes about half a minute to trim on a seat that bends; a thicker
    one, or one under a millimetre, is refused before anything is fitted, saying so and
    pointing to the plinth."""
    from solver.scene.workshop import MAX_SOLID_THICKNESS, WorkshopOptions

    assert MAX_SOLID_THICKNESS == 0.1
    if fine:
        assert WorkshopOptions(solid_thickness=thickness).any
        return
    from pathlib import Path

    from solver.cli import main

    example = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios" / "single_seated.toml"
    out = tmp_path / "out"
    assert main(["fit", str(example), "--out", str(out),
                 "--solid", str(thickness)]) == 2
    err = capsys.readouterr().err
    assert "solid thickness in [0.001, 0.1] m" in err and "--plinth" in err, err
    assert not out.exists()


@pytest.mark.parametrize("radius", ["1e308", "0", "-0.01", "nan"])
def test_fit_refuses_a_tool_radius_past_any_cutter_before_fitting(tmp_path, capsys, radius):
    """`--tool-radius` is bounded as `--solid` is: the command stops before fitting, naming the
    bound, and writes nothing."""
    from pathlib import Path

    from solver.cli import main

    example = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios" / "single_seated.toml"
    out = tmp_path / "out"
    assert main(["fit", str(example), "--out", str(out), "--tool-radius", radius]) == 2
    assert "tool radius in (0, 0.1] m" in capsys.readouterr().err
    assert not out.exists()


def test_a_hollow_right_behind_the_top_is_found(trough):
    """A solid watertight and consistently wound, but with a cavity just behind its top (as
    a trim that cut under a ridge left one): the winding number 0.1 mm behind the surface
    finds it (the underside's distances do not), and the solid is refused."""
    from dataclasses import replace

    vertices, quads, _ = trough
    solid = thicken(vertices, quads, 0.02)
    assert check_solid(solid).ok and check_solid(solid).hollow_under == 0
    # a closed box 0.05-2 mm behind the top around the middle of one of its triangles, 1 mm
    # wide (it crosses nothing), wound inwards (a cavity)
    top = solid.vertices[:solid.n_surface]
    tri = top[solid.surface_triangles[len(solid.surface_triangles) // 2]]
    middle = tri.mean(axis=0)
    normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    normal /= np.linalg.norm(normal)
    box = trimesh.creation.box(extents=(0.001, 0.001, 0.00195))
    frame = np.eye(4)
    frame[:3, :3] = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], normal)[:3, :3]
    frame[:3, 3] = middle - (0.00005 + 0.00195 / 2) * normal
    box.apply_transform(frame)
    hollow = replace(solid, vertices=np.concatenate([solid.vertices, box.vertices]),
                     triangles=np.concatenate([solid.triangles,
                                               box.faces[:, ::-1] + len(solid.vertices)]))
    check = check_solid(hollow)
    assert check.watertight and check.winding_consistent and check.intersecting_pairs == 0
    assert check.hollow_under == 1 and check.over_surface == 0
    assert replace(check, hollow_under=0).ok  # (nothing else would refuse it)
    assert not check.ok and "hollow right behind the surface" in check.problem()
