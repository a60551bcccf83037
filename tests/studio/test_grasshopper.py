"""The Rhino 8 Grasshopper script (`sitrelax grasshopper`), its pure part run without Rhino:
unit and axis conversion, the request, a fit through a real server, the reply in Rhino units."""

from __future__ import annotations

import json
import socket
import threading

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver.scene.placement import placement
from studio import grasshopper as gh
from studio.api import ApiThread
from studio.cli import main

POSE = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


def _rhino_of_metres(points) -> np.ndarray:
    """Written out independently of the script: Y-up metres -> Z-up millimetres."""
    p = np.asarray(points, dtype=float)
    return np.column_stack([p[:, 0], -p[:, 2], p[:, 1]]) * 1000.0


def _grid_mm(nx: int = 8, ny: int = 6, size=(500.0, 600.0), height=420.0):
    """A flat control grid in a Rhino document: millimetres, Z up, quads facing +Z."""
    xs = np.linspace(-size[0] / 2, size[0] / 2, nx + 1)
    ys = np.linspace(-size[1] / 2, size[1] / 2, ny + 1)
    vertices = [[x, y, height] for y in ys for x in xs]
    faces = [[j * (nx + 1) + i, j * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i + 1,
              (j + 1) * (nx + 1) + i] for j in range(ny) for i in range(nx)]
    return vertices, faces


def test_the_axis_mapping_is_a_rotation_taking_up_to_up_and_round_trips():
    frame = np.array([gh.to_sitrelax(e, 1.0) for e in np.eye(3)]).T
    assert np.allclose(frame @ frame.T, np.eye(3)) and np.isclose(np.linalg.det(frame), 1.0)
    assert gh.to_sitrelax((0, 0, 1000)) == [0.0, 1.0, 0.0]  # Rhino's up, 1 m
    assert gh.to_sitrelax((0, -1000, 0)) == [0.0, 0.0, 1.0]  # Rhino's -Y: where a body faces
    points = np.random.default_rng(7).uniform(-5e4, 5e4, (1000, 3))  # mm, within 50 m
    for scale in gh.UNIT_SCALES.values():
        back = np.array([gh.to_rhino(gh.to_sitrelax(p, scale), scale) for p in points])
        assert np.abs(back - points).max() < 1e-9
    metres = np.array([gh.to_sitrelax(p) for p in points])
    assert np.allclose(_rhino_of_metres(metres), points, atol=1e-9)


@pytest.mark.parametrize("heading", [0.0, 30.0, 90.0, -135.0])
def test_a_heading_turns_about_rhinos_up_axis_as_the_placement_does(heading):
    # the person's placement (solver) turns sitrelax's forward (+Z); seen in Rhino it is the
    # Front view's direction (-Y) turned counter-clockwise about +Z by the heading
    turned = placement([0.0, 0.0, 0.0], gh.heading_rotation(heading))[:3, :3] @ [0, 0, 1]
    in_rhino = gh.to_rhino(turned, 1.0)
    expected = Rotation.from_euler("z", heading, degrees=True).apply([0.0, -1.0, 0.0])
    assert np.allclose(in_rhino, expected)


def test_the_default_support_is_the_scenario_schema_s_and_a_use_goes_as_written():
    """The script cannot import the solver, so its default is written out: the same use."""
    from posedb.regions import support_regions
    from solver.scene import schema

    assert gh.DEFAULT_SUPPORT == schema.default(schema.Person, "support")
    assert support_regions(gh.DEFAULT_SUPPORT) == ("pelvis", "thighs")
    assert gh.person_request(POSE)["support"] == "seat"
    assert gh.person_request(POSE, support=("chair", "head"))["support"] == ["chair", "head"]
    people = gh._people({"poses": [POSE], "support": " lounger, calves "}, 0.001)
    assert people[0]["support"] == ["lounger", "calves"]


def test_the_request_is_in_metres_y_up_with_lengths_converted():
    vertices, faces = _grid_mm(2, 2)
    person = gh.person_request(POSE, (100.0, 200.0, 0.0), 90.0, ["legs"])
    assert person["position"] == [0.1, 0.0, -0.2] and person["rotation_deg"] == [0, 90, 0]
    req = gh.fit_request(vertices, faces, [person], [[1, 4]],
                         {"margin": 30.0, "level": 2, "fixed": [0]})
    surface = req["surface"]
    assert surface["margin"] == pytest.approx(0.03) and surface["level"] == 2
    assert surface["creases"] == [[1, 4]] and surface["fixed"] == [0]
    assert np.allclose(surface["control_mesh"]["vertices"][4], [0.0, 0.42, 0.0])
    json.dumps(req)  # plain JSON
    with pytest.raises(gh.SitrelaxError, match="expected quad faces"):
        gh.control_net(vertices, [[0, 1, 4, 4]])  # a Rhino triangle
    with pytest.raises(gh.SitrelaxError, match="expected vertex indices in 0..8"):
        gh.control_net(vertices, [[0, 1, 4, 9]])
    with pytest.raises(gh.SitrelaxError, match="at least one pose"):
        gh.fit_request(vertices, faces, [])


def test_crease_segments_become_interior_control_edges():
    vertices, faces = _grid_mm(2, 2)  # 3 x 3 vertices, 0..8
    v = vertices
    pairs = gh.crease_pairs(v, faces, [(v[1], v[4]), (v[4], v[7]), (v[0], v[1])], 1e-3)
    assert pairs == [[1, 4], [4, 7]]  # 0-1 is on the boundary, sharp already
    with pytest.raises(gh.SitrelaxError, match="on a control vertex"):
        gh.crease_pairs(v, faces, [([1.0, 2.0, 3.0], v[4])], 1e-3)
    with pytest.raises(gh.SitrelaxError, match="along a control edge"):
        gh.crease_pairs(v, faces, [(v[0], v[4])], 1e-3)
    assert gh.edge_key(v[1], v[4]) in gh.crease_keys(v, [[4, 1]])


def test_an_absent_server_is_named():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nobody listens there
    with pytest.raises(gh.SitrelaxError, match="is `sitrelax serve` running"):
        gh.post_fit(f"http://127.0.0.1:{port}", {"surface": {}}, timeout=5)


@pytest.fixture(scope="module")
def api():
    server = ApiThread()
    yield server
    server.stop()


LIGHT = {"level": 2, "max_iterations": 10, "sigma": 0.003}  # about 1.5 s, cold
FULL = {"level": 3, "sigma": 0.003, "margin": 30.0}  # the defaults' 50 iterations, ~2-8 s


@pytest.mark.parametrize("settings, people", [
    (LIGHT, [((0.0, 100.0, 0.0), 0.0)]),
    pytest.param(FULL, [((-100.0, 0.0, 0.0), 90.0)],
                 marks=pytest.mark.slow)])
def test_a_fit_on_a_background_thread_comes_back_in_rhino_units(api, settings, people):
    vertices, faces = _grid_mm()
    crease_row = [(vertices[k], vertices[k + 1]) for k in range(3 * 9 + 2, 3 * 9 + 6)]
    creases = gh.crease_pairs(vertices, faces, crease_row, 1e-6)
    persons = [gh.person_request(POSE, at, heading, ["seat"]) for at, heading in people]
    request = gh.fit_request(vertices, faces, persons, creases, settings)
    state, finished = {}, threading.Event()
    thread = gh.start_fit(state, api.url, request, finished.set, timeout=60)
    assert state["running"]  # the caller goes on at once
    assert finished.wait(60), "the fit did not come back within 60 s"
    thread.join(5)
    assert state["error"] is None and not state["running"], state["error"]
    reply = state["reply"]
    fit = gh.parse_fit(reply)
    # vertices in millimetres, Z up: the API's metres, Y up, mapped (rounded to 10 um there)
    assert np.allclose(fit["surface_vertices"], _rhino_of_metres(reply["surface"]["vertices"]),
                       rtol=0, atol=1e-9)
    assert np.allclose(fit["control_vertices"], _rhino_of_metres(reply["control"]["vertices"]),
                       rtol=0, atol=1e-9)
    side = 4 ** 0 * 2 ** settings["level"]
    assert len(fit["surface_vertices"]) == (8 * side + 1) * (6 * side + 1)
    assert len(fit["surface_faces"]) == 48 * side * side
    assert fit["control_faces"] == faces and fit["creases"] == creases
    assert np.abs(np.asarray(fit["control_vertices"]) - vertices).max() > 1.0  # mm: it moved
    heights = np.asarray(fit["surface_vertices"])[:, 2]
    assert 100.0 < np.median(heights) < 800.0  # a seat height in mm, not in metres
    assert len(fit["persons"]) == len(people)
    assert all(p["coverage"] >= 0.8 for p in fit["persons"]), gh.report_lines(fit["persons"])
    assert "coverage" in gh.report_lines(fit["persons"])[0]


def test_a_refusal_comes_back_with_the_servers_reason(api):
    vertices, faces = _grid_mm()
    far = gh.person_request(POSE, (3000.0, 0.0, 0.0), 0.0, ["legs"])
    with pytest.raises(gh.SitrelaxError, match="refused the fit \\(400\\).*outside"):
        gh.post_fit(api.url, gh.fit_request(vertices, faces, [far]), timeout=60)
    bad = gh.fit_request(vertices, faces, [far], settings={"level": 9})
    with pytest.raises(gh.SitrelaxError, match="\\(422\\).*surface.level"):
        gh.post_fit(api.url, bad, timeout=60)


def test_parse_fit_refuses_a_reply_that_does_not_fit():
    reply = {"control": {"vertices": [[0, 0, 0]] * 4, "faces": [[0, 1, 2, 3]]},
             "surface": {"vertices": [[0, 0, 0]] * 4, "faces": [[0, 1, 2, 4]]},
             "parameters": {"creases": []}, "persons": [], "iterations": 1,
             "stop_reason": "x", "seconds": 0.1}
    with pytest.raises(gh.SitrelaxError, match="surface faces indexing its 4 vertices"):
        gh.parse_fit(reply)
    reply["surface"]["faces"] = [[0, 1, 2, 3]]
    reply["parameters"]["creases"] = [[0, 2]]
    with pytest.raises(gh.SitrelaxError, match="creases along control edges"):
        gh.parse_fit(reply)
    with pytest.raises(gh.SitrelaxError, match="without 'control'"):
        gh.parse_fit({})


def test_sitrelax_grasshopper_prints_the_script(capsys, tmp_path):
    from pathlib import Path

    assert main(["grasshopper"]) == 0
    text = capsys.readouterr().out
    assert text == Path(gh.__file__).read_text()
    assert main(["grasshopper", "-o", str(tmp_path / "gh.py")]) == 0
    assert (tmp_path / "gh.py").read_text() == text
    namespace = {"ghenv": object()}  # as Grasshopper runs it, but without Rhino: no glue runs
    exec(compile(text, "grasshopper", "exec"), namespace)  # noqa: S102
    assert namespace["Rhino"] is None and "subd" not in namespace


def _fake_rhino(expired: threading.Event):
    """Just enough of RhinoCommon, Grasshopper's ghenv and scriptcontext to run the script's
    glue as Grasshopper would: it checks the glue's flow, not Rhino's own behaviour."""
    import types

    class Point3d:
        def __init__(self, x, y, z):
            self.X, self.Y, self.Z = x, y, z

    class Line:
        def __init__(self, a, b):
            self.From, self.To = Point3d(*a), Point3d(*b)

    class Face:
        def __init__(self, a, b, c, d):
            self.A, self.B, self.C, self.D = a, b, c, d

    class Mesh:
        def __init__(self):
            self.Vertices = types.SimpleNamespace(items=[])
            self.Vertices.Add = lambda x, y, z: self.Vertices.items.append(Point3d(x, y, z))
            self.Faces = types.SimpleNamespace(items=[])
            self.Faces.AddFace = lambda *q: self.Faces.items.append(Face(*q))
            self.Normals = types.SimpleNamespace(ComputeNormals=lambda: True)

    class Vertex:
        def __init__(self, p):
            self.ControlNetPoint = p

    class SubD:
        @staticmethod
        def CreateFromMesh(mesh, options):
            assert options.MaximumConvexCornerEdgeCount == 2
            subd, points = SubD(), mesh.Vertices.items
            subd.options, subd.updated = options, False
            edges = gh.mesh_edges([[f.A, f.B, f.C, f.D] for f in mesh.Faces.items])
            subd.Edges = [types.SimpleNamespace(VertexFrom=Vertex(points[a]),
                                                VertexTo=Vertex(points[b]), Tag="Smooth",
                                                pair=(a, b)) for a, b in edges]
            return subd

        def UpdateAllTagsAndSectorCoefficients(self):
            self.updated = True

    geometry = types.ModuleType("Rhino.Geometry")
    geometry.__dict__.update(
        Mesh=Mesh, SubD=SubD, Point3d=Point3d, Line=Line,
        SubDEdgeTag=types.SimpleNamespace(Crease="Crease", Smooth="Smooth"),
        SubDCreationOptions=type("SubDCreationOptions", (), {
            "ConvexCornerOption": types.SimpleNamespace(AtMeshCorner="AtMeshCorner")}))
    rhino = types.ModuleType("Rhino")
    rhino.__dict__.update(
        Geometry=geometry, UnitSystem=types.SimpleNamespace(Meters="m"),
        RhinoDoc=types.SimpleNamespace(ActiveDoc=types.SimpleNamespace(
            ModelUnitSystem="mm", ModelAbsoluteTolerance=0.01)),
        RhinoMath=types.SimpleNamespace(UnitScale=lambda a, b: 0.001 if a == "mm" else 1.0),
        RhinoApp=types.SimpleNamespace(InvokeOnUiThread=lambda action: action()))
    system = types.ModuleType("System")
    system.Action = lambda fn: fn
    sticky = types.ModuleType("scriptcontext")
    sticky.sticky = {}
    component = types.SimpleNamespace(InstanceGuid="guid-1",
                                      ExpireSolution=lambda recompute: expired.set())
    return {"Rhino": rhino, "Rhino.Geometry": geometry, "System": system,
            "scriptcontext": sticky}, types.SimpleNamespace(Component=component), Mesh, Line


def test_the_glue_fits_in_the_background_and_builds_a_creased_subd(api, monkeypatch):
    import sys
    from pathlib import Path

    expired = threading.Event()
    modules, ghenv, Mesh, Line = _fake_rhino(expired)
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    vertices, faces = _grid_mm()
    control = Mesh()
    for v in vertices:
        control.Vertices.Add(*v)
    for f in faces:
        control.Faces.AddFace(*f)
    control.Vertices = control.Vertices.items  # iterable, as RhinoCommon's lists are
    control.Faces = control.Faces.items
    inputs = {"control": control, "poses": [POSE], "positions": [], "headings": [0.0],
              "support": "legs", "facing": None, "settings": json.dumps(LIGHT),
              "creases": [Line(vertices[29], vertices[30])], "url": api.url, "run": True}
    code = compile(Path(gh.__file__).read_text(), "grasshopper", "exec")

    def solve() -> dict:
        namespace = {"ghenv": ghenv, **inputs}
        exec(code, namespace)  # noqa: S102
        return namespace

    first = solve()
    assert first["status"] == "fitting ..." and first["subd"] is None
    assert expired.wait(60), "the background fit never asked for a new solution"
    second = solve()
    assert second["status"].startswith("done in"), second["status"]
    creased = [e.pair for e in second["subd"].Edges if e.Tag == "Crease"]
    assert creased == [(29, 30)] and second["subd"].updated
    assert len(second["surface"].Faces.items) == 48 * 16
    assert "coverage" in second["report"]
    inputs["poses"] = []
    assert solve()["status"].startswith("error: expected at least one pose")


def test_a_subd_control_gives_its_net_and_its_interior_creases(monkeypatch):
    import sys
    import types
    from pathlib import Path

    modules, _, Mesh, _ = _fake_rhino(threading.Event())
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    namespace: dict = {}  # no ghenv: the script defines its functions only
    exec(compile(Path(gh.__file__).read_text(), "grasshopper", "exec"), namespace)  # noqa: S102
    vertices, faces = _grid_mm(2, 2)
    net = Mesh()
    for v in vertices:
        net.Vertices.Add(*v)
    for f in faces:
        net.Faces.AddFace(*f)
    subd = modules["Rhino.Geometry"].SubD.CreateFromMesh(
        net, types.SimpleNamespace(MaximumConvexCornerEdgeCount=2))
    for e in subd.Edges:  # Rhino tags the boundary as creases too
        e.Tag = "Crease" if e.pair in {(1, 4), (0, 1)} else "Smooth"
    net.Vertices, net.Faces = net.Vertices.items, net.Faces.items
    monkeypatch.setattr(modules["Rhino.Geometry"].Mesh, "CreateFromSubDControlNet",
                        staticmethod(lambda s: net), raising=False)
    got_vertices, got_faces, creases = namespace["_read_control"](subd, [], 0.01)
    assert got_vertices == vertices and got_faces == faces and creases == [[1, 4]]
    with pytest.raises(namespace["SitrelaxError"], match="expected a quad Mesh or a SubD"):
        namespace["_read_control"]("a curve", [], 0.01)
