"""The .3dm writer read back with rhino3dm, and the unit and up axis of mesh files."""

import json
import struct

import numpy as np
import pytest

rhino3dm = pytest.importorskip("rhino3dm")

from solver.io.export import ExportError, frame_matrix, write_mesh  # noqa: E402
from solver.io.obj import obj_frame, read_quad_obj  # noqa: E402
from solver.io.rhino import write_3dm  # noqa: E402
from solver.surface.limit import limit_positions  # noqa: E402
from solver.surface.nurbs import bspline_of_grid, grid_layout  # noqa: E402
from solver.surface.subdivision import grid_mesh, subdivision  # noqa: E402


def _scene():
    v, f = grid_mesh((0.5, 0.6), (8, 6), 0.42)
    v[:, 1] += 0.04 * np.sin(3 * v[:, 0]) * np.cos(4 * v[:, 2])
    body = np.array([[0.0, 0.5, 0.0], [0.1, 0.5, 0.0], [0.0, 1.2, 0.1]])
    return v, f, [(body, np.array([[0, 1, 2]])), (body + [0.3, 0, 0], np.array([[0, 1, 2]]))]


def _xyz(point):
    return [point.X, point.Y, point.Z]


def _by_layer(model):
    names = [layer.Name for layer in model.Layers]
    found = {}
    for obj in model.Objects:
        found.setdefault(names[obj.Attributes.LayerIndex], []).append(obj.Geometry)
    return names, found


def test_3dm_reads_back_with_layers_millimetres_and_z_up(tmp_path):
    v, f, bodies = _scene()
    srf = bspline_of_grid(v, grid_layout(len(v), f))
    path = write_3dm(tmp_path / "scene.3dm", v, f, srf, bodies, body_names=["ann", "bob"])
    model = rhino3dm.File3dm.Read(str(path))
    # a Rhino 7 file: Rhino 7 opens it, and Rhino 8 (a version 8 file Rhino 7 cannot read)
    assert rhino3dm.File3dm.ReadArchiveVersion(str(path)) == 70
    assert model.Settings.ModelUnitSystem == rhino3dm.UnitSystem.Millimeters
    assert model.Settings.ModelAbsoluteTolerance == pytest.approx(0.01)
    names, found = _by_layer(model)
    assert names == ["control net", "surface", "ann", "bob"]
    control = found["control net"][0]
    assert isinstance(control, rhino3dm.Mesh) and control.Faces.QuadCount == 48
    nurbs = found["surface"][0]
    assert isinstance(nurbs, rhino3dm.NurbsSurface) and nurbs.Degree(0) == nurbs.Degree(1) == 3
    # Z up, millimetres: the seat at 420 mm, the head of the body above it, the normal up
    assert nurbs.PointAt(0, 0).Z == pytest.approx(v[0, 1] * 1000)
    assert found["bob"][0].GetBoundingBox().Max.Z == pytest.approx(1200)
    assert nurbs.NormalAt(3.5, 4.5).Z > 0.9
    assert found["ann"][0].GetBoundingBox().Min.X == pytest.approx(0.0)
    assert found["bob"][0].GetBoundingBox().Min.X == pytest.approx(300.0)


def test_nurbs_point_at_is_the_limit_surface_within_0_05_mm(tmp_path):
    """rhino3dm's PointAt at each level-3 vertex's parameters against our limit masks (whose
    convergence tests/solver/surface/test_limit.py checks), in the document's millimetres."""
    v, f, bodies = _scene()
    grid = grid_layout(len(v), f)
    path = write_3dm(tmp_path / "scene.3dm", v, f, bspline_of_grid(v, grid), bodies)
    nurbs = _by_layer(rhino3dm.File3dm.Read(str(path)))[1]["surface"][0]
    sub = subdivision(len(v), f, 3)
    fine = grid_layout(sub.matrix.shape[0], sub.faces)
    limit = (limit_positions(v, f, 3) @ frame_matrix("mm", "z").T)[fine]
    rhino = np.array([[_xyz(nurbs.PointAt(i / 8, j / 8)) for j in range(fine.shape[1])]
                      for i in range(fine.shape[0])])
    gaps = np.linalg.norm(rhino - limit, axis=-1)
    assert gaps.max() < 0.05  # mm
    # distances: NURBS points at random parameters to the level-5 limit mesh (its chords
    # are about 2 mm long, so it lies within a few micrometres of the limit surface)
    import igl

    rng = np.random.default_rng(0)
    du, dw = nurbs.Domain(0), nurbs.Domain(1)
    (u0, u1), (w0, w1) = (du.T0, du.T1), (dw.T0, dw.T1)
    samples = np.array([_xyz(nurbs.PointAt(u, w)) for u, w in zip(
        rng.uniform(u0, u1, 300), rng.uniform(w0, w1, 300))])
    level5 = subdivision(len(v), f, 5)
    dense = limit_positions(v, f, 5) @ frame_matrix("mm", "z").T
    d2, _, _ = igl.point_mesh_squared_distance(samples, dense, level5.triangles)
    assert np.sqrt(d2).max() < 0.05  # mm


def test_body_names_rhino_refuses_become_layer_names_it_takes(tmp_path):
    """A name with a line break or a tab (which Rhino refuses: rhino3dm called that layer
    "Layer 03") and one with "::" (a sublayer's path to Rhino) are layers named as written
    on one line."""
    v, f, bodies = _scene()
    path = write_3dm(tmp_path / "scene.3dm", v, f, None, bodies,
                     body_names=["ann\nlee  smith", "bob::\tjr "])
    names, _ = _by_layer(rhino3dm.File3dm.Read(str(path)))
    assert names == ["control net", "surface", "ann lee smith", "bob: jr"]


def test_mesh_surface_and_metres_y_up(tmp_path):
    v, f, bodies = _scene()
    path = write_3dm(tmp_path / "mesh.3dm", v, f, (v, f), [], unit="m", up="y")
    model = rhino3dm.File3dm.Read(str(path))
    assert model.Settings.ModelUnitSystem == rhino3dm.UnitSystem.Meters
    mesh = _by_layer(model)[1]["surface"][0]
    assert mesh.GetBoundingBox().Max.Y == pytest.approx(v[:, 1].max())


@pytest.mark.parametrize("kwargs, match", [
    ({"unit": "furlong"}, "Expected a unit"), ({"up": "x"}, "Expected an up axis"),
    ({"body_names": ["a"]}, "distinct body names")])
def test_3dm_bad_options_are_named(tmp_path, kwargs, match):
    v, f, bodies = _scene()
    with pytest.raises(ExportError, match=match):
        write_3dm(tmp_path / "x.3dm", v, f, None, bodies, **kwargs)


def test_mesh_files_state_and_honour_unit_and_up(tmp_path):
    v, f, _ = _scene()
    path = write_mesh(tmp_path / "s.obj", v, f, unit="mm", up="z", comment="hello")
    assert obj_frame(path) == ("mm", "z")
    back, faces = read_quad_obj(path)
    assert np.allclose(back, np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1) * 1000, atol=1e-5)
    assert np.allclose(read_quad_obj(path, sitrelax_frame=True)[0], v, atol=1e-8)
    assert obj_frame(write_mesh(tmp_path / "m.obj", v, f)) == ("m", "y")
    ply = write_mesh(tmp_path / "s.ply", v, f, unit="cm", up="z").read_bytes()
    assert b"comment units: cm; up: +Z" in ply.split(b"end_header")[0]
    import trimesh

    mesh = trimesh.load(tmp_path / "s.ply", process=False)
    assert np.allclose(mesh.vertices[:, 2], v[:, 1] * 100)
    glb = write_mesh(tmp_path / "s.glb", v, f).read_bytes()
    header = json.loads(glb[20:20 + struct.unpack("<I", glb[12:16])[0]])
    assert header["asset"]["extras"]["sitrelax"].startswith("units: m; up: +Y")
    with pytest.raises(ExportError, match="metres and Y up for a GLB"):
        write_mesh(tmp_path / "s.glb", v, f, unit="mm")
