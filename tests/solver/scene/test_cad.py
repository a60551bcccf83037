"""The fit's CAD surface: the limit surface as a mesh and as NURBS, in scene.3dm; on every
example scenario (slow) the NURBS within 0.05 mm of the limit, measured independently."""

import json
from pathlib import Path

import numpy as np
import pytest

rhino3dm = pytest.importorskip("rhino3dm")

from solver.io.export import frame_matrix  # noqa: E402
from solver.scene.cad import cad_surface, write_scene_3dm  # noqa: E402
from solver.surface.fit import FitResult  # noqa: E402
from solver.surface.nurbs import grid_layout  # noqa: E402
from solver.surface.subdivision import grid_mesh, subdivide_once, subdivision  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"


def _result(resolution=(8, 6), level=3):
    v, f = grid_mesh((0.5, 0.6), resolution, 0.42)
    v[:, 1] += 0.05 * np.sin(4 * v[:, 0]) * np.cos(5 * v[:, 2])
    sub = subdivision(len(v), f, level)
    return FitResult(v, f, sub.apply(v), sub.faces, 0, "test", [], {}, 0.0, [], sub)


def _surface_nurbs(path):
    model = rhino3dm.File3dm.Read(str(path))
    names = [layer.Name for layer in model.Layers]
    return model, [o.Geometry for o in model.Objects
                   if names[o.Attributes.LayerIndex] == "surface"]


def _independent_limit(control, faces, creases=None):
    """The limit at the level-2 vertices from levels 4 and 5 of the control net (which keep
    the level-2 vertices' indices), extrapolated at the regular rate 1/4 (crease curves and
    boundaries converge at it too): no limit mask used."""
    level2 = subdivision(len(control), faces, 2)
    picked = grid_layout(level2.matrix.shape[0], level2.faces)
    n, f, points, levels = len(control), faces, np.asarray(control, float), {}
    for level in range(1, 6):
        step = subdivide_once(n, f, creases)
        points, f, n, creases = step.matrix @ points, step.faces, step.matrix.shape[0], \
            step.creases
        if level >= 4:
            levels[level] = points[picked]
    return (4 * levels[5] - levels[4]) / 3, picked.shape


def _nurbs_gaps_mm(nurbs, control, faces):
    limit, shape = _independent_limit(control, faces)
    limit_mm = limit @ frame_matrix("mm", "z").T
    points = [nurbs.PointAt(i / 4, j / 4) for i in range(shape[0]) for j in range(shape[1])]
    rhino = np.array([[p.X, p.Y, p.Z] for p in points]).reshape(shape + (3,))
    return np.linalg.norm(rhino - limit_mm, axis=-1)


def test_cad_surface_of_a_grid_is_nurbs_and_the_limit(tmp_path):
    result = _result((6, 4))
    cad = cad_surface(result)
    assert cad.figures["kind"] == "nurbs" and cad.figures["nurbs_to_limit_max_mm"] < 1e-6
    assert 0.01 < cad.figures["level_to_limit_max_mm"] < 10
    write_scene_3dm(tmp_path / "scene.3dm", result, cad, [], [])
    model, surfaces = _surface_nurbs(tmp_path / "scene.3dm")
    assert model.Settings.ModelUnitSystem == rhino3dm.UnitSystem.Millimeters
    assert len(surfaces) == 1 and isinstance(surfaces[0], rhino3dm.NurbsSurface)
    assert _nurbs_gaps_mm(surfaces[0], result.control, result.faces).max() < 0.05


def _creased(creases, level=2):
    v, f = grid_mesh((0.5, 0.6), (4, 4), 0.42)
    v[:, 1] += 0.05 * np.sin(4 * v[:, 0]) * np.cos(5 * v[:, 2])
    sub = subdivision(len(v), f, level, creases)
    return FitResult(v, f, sub.apply(v), sub.faces, 0, "test", [], {}, 0.0, [], sub)


def test_a_crease_along_a_whole_grid_line_gives_two_nurbs(tmp_path):
    creases = [[10, 11], [11, 12], [12, 13], [13, 14]]  # the line x = 0, boundary to boundary
    result = _creased(creases, 3)
    cad = cad_surface(result, creases)
    assert cad.figures["patches"] == 2 and cad.figures["nurbs_to_limit_max_mm"] < 1e-9
    write_scene_3dm(tmp_path / "scene.3dm", result, cad, [], [])
    _, surfaces = _surface_nurbs(tmp_path / "scene.3dm")
    assert len(surfaces) == 2 and all(isinstance(s, rhino3dm.NurbsSurface) for s in surfaces)
    limit, shape = _independent_limit(result.control, result.faces, creases)
    frame = frame_matrix("mm", "z")
    for srf, rows in zip(surfaces, (slice(0, 9), slice(8, 17))):  # u along z, v along x
        part = limit[:, rows] @ frame.T
        rhino = np.array([[_xyz(srf.PointAt(i / 4, j / 4)) for j in range(part.shape[1])]
                          for i in range(part.shape[0])])
        assert np.linalg.norm(rhino - part, axis=-1).max() < 0.05


def _xyz(point):
    return [point.X, point.Y, point.Z]


def test_cad_surface_with_a_partial_crease_is_a_limit_mesh(tmp_path):
    creases = [[11, 12], [12, 13]]
    result = _creased(creases)
    cad = cad_surface(result, creases)
    assert cad.nurbs == () and cad.figures["kind"] == "limit mesh"
    write_scene_3dm(tmp_path / "scene.3dm", result, cad, [], [])
    _, surfaces = _surface_nurbs(tmp_path / "scene.3dm")
    assert isinstance(surfaces[0], rhino3dm.Mesh) and surfaces[0].Faces.QuadCount == 256


@pytest.mark.slow
def test_fit_command_writes_3dm_in_millimetres_z_up(tmp_path):
    """`sitrelax fit --format 3dm,obj --unit mm --up z`: the files in millimetres, Z up."""
    from solver.cli import main
    from solver.io.obj import obj_frame, read_quad_obj

    out = tmp_path / "out"
    assert main(["fit", str(EXAMPLES / "single_seated.toml"), "--out", str(out), "--format",
                 "3dm,obj", "--unit", "mm", "--up", "z", "--json"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["files"]["scene_3dm"] == "scene.3dm" and "surface_ply" not in report["files"]
    assert obj_frame(out / "surface.obj") == ("mm", "z")
    surface, _ = read_quad_obj(out / "surface.obj")
    assert 300 < np.median(surface[:, 2]) < 600  # a seat about 42 cm up, in mm along Z
    model, surfaces = _surface_nurbs(out / "scene.3dm")
    names = [layer.Name for layer in model.Layers]
    assert names[:2] == ["control net", "surface"] and names[2].startswith("person 1")
    assert isinstance(surfaces[0], rhino3dm.NurbsSurface)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(p.stem for p in EXAMPLES.glob("*.toml")))
def test_every_example_nurbs_within_0_05_mm_of_the_limit(name, tmp_path):
    from solver.io.obj import read_quad_obj
    from solver.scene.run import run_fit

    report = run_fit(EXAMPLES / f"{name}.toml", tmp_path, formats=("obj", "3dm"))
    assert report["surface_limit"]["kind"] == "nurbs"
    control, faces = read_quad_obj(tmp_path / "control.obj")
    _, surfaces = _surface_nurbs(tmp_path / "scene.3dm")
    gaps = _nurbs_gaps_mm(surfaces[0], control, faces)
    assert gaps.max() < 0.05


@pytest.mark.parametrize("kwargs, match", [({"formats": ("stl",)}, "surface formats"),
                                           ({"unit": "furlong"}, "Expected a unit")])
def test_run_fit_refuses_bad_export_options_before_fitting(tmp_path, kwargs, match):
    from solver.io.export import ExportError
    from solver.scene.run import run_fit

    with pytest.raises(ExportError, match=match):
        run_fit(tmp_path / "no-such.toml", tmp_path / "out", **kwargs)


def test_a_control_net_with_an_extraordinary_vertex_gives_the_limit_mesh(tmp_path):
    """Five quads around a valence-5 vertex: no grid, so the limit points of level 3 go to
    the .3dm as a mesh; they are the limit (level 6 of the net comes within 0.3 mm of them)."""
    k = np.arange(5)
    ring = np.stack([np.cos(2 * np.pi * k / 5), 0.1 * np.sin(4 * np.pi * k / 5),
                     np.sin(2 * np.pi * k / 5)], axis=1) * 0.4
    v = np.concatenate([[[0.0, 0.05, 0.0]], ring, 0.45 * (ring + np.roll(ring, -1, axis=0))])
    f = np.stack([np.zeros(5, int), 6 + np.roll(k, 1), 1 + k, 6 + k], axis=1)
    sub = subdivision(len(v), f, 3)
    result = FitResult(v, f, sub.apply(v), sub.faces, 0, "test", [], {}, 0.0, [], sub)
    cad = cad_surface(result)
    assert cad.nurbs == () and cad.figures["kind"] == "limit mesh"
    dense = subdivision(len(v), f, 6).apply(v)[:len(cad.vertices)]  # level-3 vertices first
    assert np.linalg.norm(dense - cad.vertices, axis=1).max() < 3e-4
    write_scene_3dm(tmp_path / "scene.3dm", result, cad, [], [])
    _, surfaces = _surface_nurbs(tmp_path / "scene.3dm")
    assert isinstance(surfaces[0], rhino3dm.Mesh) and surfaces[0].Faces.QuadCount == 5 * 64


def _rounded_box():
    """An open quad net with extraordinary vertices: a cube's net subdivided twice (its corners
    stay valence 3), the faces near the top left out, the vertices jittered."""
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4],
                      [1, 5, 7, 3]])
    twice = subdivision(8, quads, 2)
    v, f = twice.apply(cube), twice.faces
    f = f[v[f].mean(axis=1)[:, 1] < 0.9]
    used = np.unique(f)
    index = np.full(len(v), -1)
    index[used] = np.arange(len(used))
    v = v[used] * 0.5 + np.random.default_rng(1).normal(0.0, 0.005, (len(used), 3))
    return v, index[f]


def test_a_general_net_gets_a_nurbs_patch_per_regular_face(tmp_path):
    """A net with valence-3 vertices and a border: each face whose four corners are inner
    vertices of four quads is an exact bicubic patch in the .3dm, the rest the limit mesh.
    rhino3dm's `PointAt` on each patch, at the face's level-1 points (corners, edge middles,
    centre), against the limit extrapolated from levels 4 and 5 of the net (no limit mask)."""
    from solver.surface.nurbs import regular_face_patches

    v, f = _rounded_box()
    sub = subdivision(len(v), f, 3)
    result = FitResult(v, f, sub.apply(v), sub.faces, 0, "test", [], {}, 0.0, [], sub)
    cad = cad_surface(result)
    found, _ = regular_face_patches(len(v), f)
    inner = np.ones(len(v), dtype=bool)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 3]], f[:, [3, 0]]])
    keys, count = np.unique(np.sort(edges, axis=1), axis=0, return_counts=True)
    inner[keys[count == 1].ravel()] = False
    valence = np.bincount(f.ravel(), minlength=len(v))
    expected = np.flatnonzero((inner & (valence == 4))[f].all(axis=1))
    np.testing.assert_array_equal(found, expected)
    assert 0 < len(found) < len(f)
    assert cad.figures["kind"] == "nurbs and limit mesh"
    assert cad.figures["patches"] == len(found)
    assert cad.figures["mesh_faces"] == 64 * (len(f) - len(found))
    write_scene_3dm(tmp_path / "scene.3dm", result, cad, [], [])
    _, surfaces = _surface_nurbs(tmp_path / "scene.3dm")
    patches = [s for s in surfaces if isinstance(s, rhino3dm.NurbsSurface)]
    meshes = [s for s in surfaces if isinstance(s, rhino3dm.Mesh)]
    assert len(patches) == len(found) and len(meshes) == 1
    assert meshes[0].Faces.QuadCount == cad.figures["mesh_faces"]
    # the limit at level 1's points, followed down to levels 4 and 5 (indices kept)
    n, faces, points, levels = len(v), f, v, {}
    for level in range(1, 6):
        step = subdivide_once(n, faces)
        if level == 1:
            first = step.faces
        points, faces, n = step.matrix @ points, step.faces, step.matrix.shape[0]
        if level >= 4:
            levels[level] = points
    kept = len(levels[4])  # a step keeps its vertices' indices first
    limit = ((4 * levels[5][:kept] - levels[4]) / 3) @ frame_matrix("mm", "z").T
    face_point = first[:, 2].min()
    uv = [(0, 0), (1, 0), (1, 1), (0, 1), (0.5, 0), (1, 0.5), (0.5, 1), (0, 0.5), (0.5, 0.5)]
    worst = 0.0
    for face, patch in zip(found.tolist(), patches):
        corners = f[face].tolist()
        quads = first[first[:, 2] == face_point + face]
        after = {int(q[0]): int(q[1]) for q in quads}
        index = corners + [after[c] for c in corners] + [face_point + face]
        got = np.array([[p.X, p.Y, p.Z] for p in (patch.PointAt(a, b) for a, b in uv)])
        worst = max(worst, float(np.linalg.norm(got - limit[index], axis=1).max()))
    assert worst < 0.05, worst  # mm
