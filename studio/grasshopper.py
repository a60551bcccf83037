"""sitrelax in Rhino 8: a Grasshopper script component (Python 3) that fits a supporting
surface through `sitrelax serve` and returns it as an editable SubD.

`sitrelax grasshopper` prints this file; paste it into a Rhino 8 Script component (or save it
and point the component at it). It needs only the Python standard library and RhinoCommon.

Component inputs (names as below; set "List Access" where a list is said)
    control   : the designer's control net, a quad Mesh or a SubD (its control net is sent,
                its crease edges become the fit's creases)
    poses     : list of str, one pose per person, as the API takes them: `db:NAME` (the
                server's --db) or `bvh:bundled:NAME#frame=N`
    positions : list of Point3d, where each person stands (document units), default origin
    headings  : list of float, degrees about the document's Z (up) axis, counter-clockwise
                seen from above; 0 faces the person towards -Y (the Front view's camera)
    support   : str, the body regions that must be supported, comma separated: regions
                (head, upper_back, lower_back, pelvis, thighs, calves, feet, upper_arms,
                forearms, hands), parts (torso, arms, legs) or a use (seat, stool, chair,
                lounger, bed, floor); default "seat" (pelvis and thighs)
    facing    : str, "front" (each recording's pelvis first turned to face forward) or
                "capture" (the capture room's heading)
    creases   : list of Line, extra control edges to keep sharp (matched to control vertices
                within the document's tolerance)
    settings  : str, JSON of fit parameters, e.g. {"level": 3, "sigma": 0.003, "margin": 30};
                lengths (margin, pull_range, step) in document units, others as in the TOML
                scenario; "fixed": [control vertex indices]; "body": {shape parameters}
    url       : str, the server (default http://127.0.0.1:8765)
    run       : bool, fit when true (again whenever an input changes)

Component outputs
    subd      : the fitted control net as an editable SubD, with its creases
    surface   : the server's subdivided surface as a quad Mesh
    net       : the fitted control net as a quad Mesh
    report    : one line per person (coverage, peak pressure, flat-seat baseline)
    status    : "idle", "fitting ...", "done in ... s" or the server's error

Conventions. Rhino documents are Z up in their model unit (usually millimetres); sitrelax is
Y up in metres. With `scale` the metres per document unit, a document point (x, y, z) is the
sitrelax point (x, z, -y) * scale and back (x, y, z) -> (x, -z, y) / scale: rotations of -90
and +90 degrees about x (determinant +1, so right-handed frames stay right-handed), which send
Rhino's up (+Z) to sitrelax's up (+Y) and sitrelax's forward (+Z, where a body in rest pose
faces) to Rhino's -Y. A turn about Rhino's Z by h degrees is a turn about sitrelax's Y by h
degrees (rotation_deg [0, h, 0]).

A fit runs on a background thread, so the canvas never waits for the server: the component
answers at once with the last result and "fitting ...", and when the reply comes the thread
asks Rhino's UI thread (`Rhino.RhinoApp.InvokeOnUiThread`) to expire the component
(`ghenv.Component.ExpireSolution(True)`), which solves again and shows the new result. State
between solutions lives in `scriptcontext.sticky` under the component's id.

Everything above the Rhino section imports nothing from Rhino and is tested without it. The
Rhino section relies on these RhinoCommon members (Rhino 7.7 or later; not run here, where
there is no Rhino): `Mesh.CreateFromSubDControlNet`, `SubD.CreateFromMesh(mesh,
SubDCreationOptions)` with `InterpolateMeshVertices = False` (the net's points are control
points), `ConvexCornerTest = AtMeshCorner`, `MaximumConvexCornerEdgeCount = 2` and
`MaximumConvexCornerAngleRadians = pi` (every single-face boundary vertex a corner, as
sitrelax's subdivision makes it), `SubDEdge.Tag = SubDEdgeTag.Crease` on the edges whose end
points are a crease's (matched by position, so the SubD's own numbering does not matter) and
`SubD.UpdateAllTagsAndSectorCoefficients()`; `RhinoMath.UnitScale` for the document's unit;
`RhinoApp.InvokeOnUiThread(System.Action(...))` and `GH_Component.ExpireSolution(True)` from
the fit's thread; `scriptcontext.sticky` for the state between solutions.
"""

import json
import math
import threading
import urllib.error
import urllib.request

DEFAULT_URL = "http://127.0.0.1:8765"
TIMEOUT = 180.0  # seconds to wait for a reply (the server stops a fit after its --time-limit)
# metres per model unit, for a document unit name
UNIT_SCALES = {"mm": 0.001, "cm": 0.01, "m": 1.0, "in": 0.0254, "ft": 0.3048}
LENGTH_SETTINGS = ("margin", "pull_range", "step")  # fit parameters given in document units
DEFAULT_SUPPORT = "seat"  # the scenario schema's default (posedb.regions.DEFAULT_SUPPORT)


class SitrelaxError(ValueError):
    """A request that cannot be built, a server's refusal, or a reply that does not fit."""


# ---------------------------------------------------------------- units and axes (pure)

def to_sitrelax(point, scale=0.001):
    """A document point in sitrelax's frame.

    Parameters
    ----------
    point : (3,) float, (x, y, z) in document units, Z up.
    scale : metres per document unit (0.001 for millimetres).

    Returns
    -------
    list of 3 float : (x, z, -y) * scale, metres, Y up.
    """
    x, y, z = (float(c) for c in point)
    return [x * scale, z * scale, -y * scale]


def to_rhino(point, scale=0.001):
    """A sitrelax point in the document's frame (the inverse of `to_sitrelax`).

    Parameters
    ----------
    point : (3,) float, (x, y, z) in metres, Y up.
    scale : metres per document unit.

    Returns
    -------
    list of 3 float : (x, -z, y) / scale, document units, Z up.
    """
    x, y, z = (float(c) for c in point)
    return [x / scale, -z / scale, y / scale]


def heading_rotation(heading_deg):
    """sitrelax's `rotation_deg` of a turn about the document's up axis.

    Parameters
    ----------
    heading_deg : float, degrees about Rhino's +Z, counter-clockwise seen from above.

    Returns
    -------
    list of 3 float : [0, heading_deg, 0], degrees about sitrelax's x, y, z.
    """
    return [0.0, float(heading_deg), 0.0]


# ---------------------------------------------------------------- the request (pure)

def control_net(vertices, faces, scale=0.001):
    """The API's inline control mesh of a document control net.

    Parameters
    ----------
    vertices : (V, 3) float, document units.
    faces : (F, 4) int, quads (a Rhino triangle repeats its last index and is refused).

    Returns
    -------
    dict : {"vertices": (V, 3) metres Y up, "faces": (F, 4)}.
    """
    quads = [[int(i) for i in f] for f in faces]
    for k, f in enumerate(quads):
        if len(f) != 4 or len(set(f)) != 4:
            raise SitrelaxError(f"expected quad faces (four distinct vertices), got face {k} "
                                f"= {f}: the control net must be all quads")
        if min(f) < 0 or max(f) >= len(vertices):
            raise SitrelaxError(f"expected vertex indices in 0..{len(vertices) - 1}, got face "
                                f"{k} = {f}")
    return {"vertices": [to_sitrelax(v, scale) for v in vertices], "faces": quads}


def mesh_edges(faces):
    """The edges of a face list, as sorted vertex index pairs.

    Parameters
    ----------
    faces : (F, k) int.

    Returns
    -------
    dict : (i, j) with i < j -> how many faces share that edge.
    """
    edges = {}
    for f in faces:
        for a, b in zip(f, list(f[1:]) + [f[0]]):
            key = (min(a, b), max(a, b))
            edges[key] = edges.get(key, 0) + 1
    return edges


def crease_pairs(vertices, faces, segments, tolerance):
    """Control edges [i, j] of crease segments given by their end points.

    Parameters
    ----------
    vertices : (V, 3) float, document units.
    faces : (F, 4) int.
    segments : (C, 2, 3) float, each a crease's two end points, document units.
    tolerance : float, document units an end point may lie from its vertex.

    Returns
    -------
    list of [i, j] : sorted interior edges (boundary edges are sharp already, so dropped).
    """
    edges = mesh_edges(faces)

    def nearest(p):
        best = min(range(len(vertices)), key=lambda k: sum((vertices[k][c] - p[c]) ** 2
                                                           for c in range(3)))
        if math.dist(vertices[best], p) > tolerance:
            raise SitrelaxError(f"expected a crease end on a control vertex (within "
                                f"{tolerance:g}), got {list(p)}")
        return best

    pairs = []
    for p, q in segments:
        key = tuple(sorted((nearest(p), nearest(q))))
        if key not in edges:
            raise SitrelaxError(f"expected a crease along a control edge, got vertices {key}")
        if edges[key] == 2 and list(key) not in pairs:
            pairs.append(list(key))
    return pairs


def person_request(pose, position=(0.0, 0.0, 0.0), heading_deg=0.0, support=DEFAULT_SUPPORT,
                   facing="front", body=None, scale=0.001):
    """The API's person of a pose placed in the document.

    Parameters
    ----------
    pose : str, `db:NAME` or `bvh:bundled:NAME#frame=N`.
    position : (3,) float, document units.
    heading_deg : float, degrees about the document's up axis (see `heading_rotation`).
    support : str or sequence of str, a use or the body regions to support.
    facing : "front" or "capture".
    body : dict or None, shape parameters in [0, 1].
    scale : metres per document unit.

    Returns
    -------
    dict : the person as /api/fit takes it.
    """
    person = {"pose": str(pose), "position": to_sitrelax(position, scale),
              "rotation_deg": heading_rotation(heading_deg),
              "support": support if isinstance(support, str) else [str(s) for s in support],
              "facing": str(facing)}
    if body:
        person["body"] = dict(body)
    return person


def fit_request(vertices, faces, people, creases=(), settings=None, scale=0.001):
    """The /api/fit request of a document control net and people.

    Parameters
    ----------
    vertices : (V, 3) float, document units.
    faces : (F, 4) int.
    people : list of dict, from `person_request`.
    creases : (C, 2) int, control edges kept sharp.
    settings : dict or None, fit parameters (`level`, `sigma`, `fixed`, ...); the lengths
        `LENGTH_SETTINGS` in document units.
    scale : metres per document unit.

    Returns
    -------
    dict : the scenario as JSON.
    """
    surface = {"control_mesh": control_net(vertices, faces, scale)}
    for name, value in dict(settings or {}).items():
        surface[name] = value * scale if name in LENGTH_SETTINGS else value
    if creases:
        surface["creases"] = [[int(a), int(b)] for a, b in creases]
    if not people:
        raise SitrelaxError("expected at least one pose, got none")
    return {"surface": surface, "person": list(people)}


# ---------------------------------------------------------------- the server (pure)

def post_fit(url, request, timeout=TIMEOUT):
    """POSTs a fit request and returns the server's reply.

    Parameters
    ----------
    url : str, the server, e.g. http://127.0.0.1:8765.
    request : dict, from `fit_request`.
    timeout : seconds to wait.

    Returns
    -------
    dict : the reply of /api/fit; a refusal raises SitrelaxError with the server's detail.
    """
    data = json.dumps(request).encode("utf-8")
    req = urllib.request.Request(url.rstrip("/") + "/api/fit", data=data, method="POST",
                                 headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as response:
            return json.loads(response.read())
    except urllib.error.HTTPError as err:
        raise SitrelaxError(f"the server refused the fit ({err.code}): "
                            f"{_detail(err.read())}") from None
    except (urllib.error.URLError, OSError) as err:
        raise SitrelaxError(f"no answer from {url} ({getattr(err, 'reason', err)}): is "
                            "`sitrelax serve` running?") from None


def _detail(payload):
    try:
        detail = json.loads(payload)["detail"]
    except (ValueError, KeyError, TypeError):
        return payload[:300].decode("utf-8", "replace")
    if isinstance(detail, list):
        return "; ".join(".".join(str(p) for p in e.get("loc", [])[1:]) + ": " + e.get("msg", "")
                         for e in detail)
    return str(detail)


def parse_fit(reply, scale=0.001):
    """The fit's reply as plain lists in document units.

    Parameters
    ----------
    reply : dict, the reply of /api/fit.
    scale : metres per document unit.

    Returns
    -------
    dict : control_vertices (V, 3) and surface_vertices (S, 3) in document units, Z up;
        control_faces (F, 4), surface_faces (G, 4), creases (C, 2) of the control net;
        persons (the API's figures, SI units), iterations, stop_reason, seconds.
    """
    try:
        control, surface = reply["control"], reply["surface"]
        out = {"control_vertices": [to_rhino(v, scale) for v in control["vertices"]],
               "control_faces": [list(f) for f in control["faces"]],
               "creases": [list(c) for c in reply["parameters"]["creases"]],
               "surface_vertices": [to_rhino(v, scale) for v in surface["vertices"]],
               "surface_faces": [list(f) for f in surface["faces"]],
               "persons": list(reply["persons"]), "iterations": int(reply["iterations"]),
               "stop_reason": str(reply["stop_reason"]), "seconds": float(reply["seconds"])}
    except (KeyError, TypeError, ValueError) as exc:
        raise SitrelaxError(f"expected a reply of /api/fit, got one without {exc}") from None
    for name in ("control", "surface"):
        n = len(out[name + "_vertices"])
        if any(not 0 <= i < n for f in out[name + "_faces"] for i in f):
            raise SitrelaxError(f"expected {name} faces indexing its {n} vertices")
    edges = mesh_edges(out["control_faces"])
    if any(tuple(sorted(c)) not in edges for c in out["creases"]):
        raise SitrelaxError("expected the creases along control edges")
    return out


def report_lines(persons):
    """One line of figures per person of a fit's reply.

    Parameters
    ----------
    persons : list of dict, the reply's `persons` (a figure may be None: a body that did not
        settle has no pressure).

    Returns
    -------
    list of str.
    """
    def number(value, unit=""):
        return "n/a" if value is None else f"{value:.{2 if not unit else 1}f}{unit}"

    lines = []
    for p in persons:
        flat = (p.get("flat") or {}).get("peak_pressure_kpa")
        lines.append(f"{p.get('name', '?')}: coverage {number(p.get('coverage'))}, peak "
                     f"{number(p.get('peak_pressure_kpa'), ' kPa')} (flat seat "
                     f"{number(flat, ' kPa')})"
                     + ("" if p.get("supported", True) else ", does not settle"))
    return lines


def crease_keys(vertices, creases, digits=6):
    """Creases as pairs of rounded positions, to find them again among a SubD's edges.

    Parameters
    ----------
    vertices : (V, 3) float.
    creases : (C, 2) int.
    digits : decimals kept.

    Returns
    -------
    set of frozenset : each crease's two rounded end points.
    """
    return {edge_key(vertices[a], vertices[b], digits) for a, b in creases}


def edge_key(p, q, digits=6):
    """An edge's unordered pair of rounded end points (see `crease_keys`)."""
    return frozenset((tuple(round(float(c), digits) for c in p),
                      tuple(round(float(c), digits) for c in q)))


def start_fit(state, url, request, done=None, timeout=TIMEOUT):
    """Fits on a background thread; `state` receives the outcome.

    Parameters
    ----------
    state : dict, shared with the caller: "running" (bool), "sent" (the request's JSON),
        then "reply" (the reply) or "error" (str); "started" and "finished" are set too.
    url : str, the server.
    request : dict, from `fit_request`.
    done : callable or None, called with no argument on the thread once the outcome is in.
    timeout : seconds to wait for the server.

    Returns
    -------
    threading.Thread : already started (a daemon).
    """
    state.update(running=True, sent=json.dumps(request, sort_keys=True), error=None)

    def work():
        try:
            state["reply"], state["error"] = post_fit(url, request, timeout), None
        except SitrelaxError as exc:
            state["error"] = str(exc)
        finally:
            state["running"] = False
            if done is not None:
                done()

    thread = threading.Thread(target=work, name="sitrelax-fit", daemon=True)
    thread.start()
    return thread


# ---------------------------------------------------------------- Rhino (the glue)

try:
    import Rhino.Geometry  # only inside Rhino
except ImportError:
    Rhino = None


def _document_scale():
    doc = Rhino.RhinoDoc.ActiveDoc
    return (Rhino.RhinoMath.UnitScale(doc.ModelUnitSystem, Rhino.UnitSystem.Meters),
            doc.ModelAbsoluteTolerance)


def _point(p):
    return [p.X, p.Y, p.Z]


def _read_control(control, extra_creases, tolerance):
    """(vertices, quads, crease pairs) of a Mesh or SubD input, in document units."""
    rg = Rhino.Geometry
    segments = [(_point(line.From), _point(line.To)) for line in extra_creases or []]
    if isinstance(control, rg.SubD):
        segments += [(_point(e.VertexFrom.ControlNetPoint), _point(e.VertexTo.ControlNetPoint))
                     for e in control.Edges if e.Tag == rg.SubDEdgeTag.Crease]
        control = rg.Mesh.CreateFromSubDControlNet(control)
    if not isinstance(control, rg.Mesh):
        raise SitrelaxError(f"expected a quad Mesh or a SubD as control, got "
                            f"{type(control).__name__}")
    vertices = [_point(v) for v in control.Vertices]
    faces = [[f.A, f.B, f.C, f.D] for f in control.Faces]
    return vertices, faces, crease_pairs(vertices, faces, segments, tolerance)


def _rhino_subd(vertices, faces, creases):
    """An editable SubD of a control net: the net's points as its control points, single-face
    boundary vertices as corners (sitrelax's rule), the creases tagged as crease edges."""
    rg = Rhino.Geometry
    mesh = _rhino_mesh(vertices, faces)
    options = rg.SubDCreationOptions()
    options.InterpolateMeshVertices = False  # mesh points are control points, not limit points
    options.ConvexCornerTest = rg.SubDCreationOptions.ConvexCornerOption.AtMeshCorner
    options.MaximumConvexCornerEdgeCount = 2
    options.MaximumConvexCornerAngleRadians = math.pi
    subd = rg.SubD.CreateFromMesh(mesh, options)
    if subd is None:
        raise SitrelaxError("Rhino could not make a SubD of the fitted control net")
    keys = crease_keys(vertices, creases)
    for edge in subd.Edges:
        if edge_key(_point(edge.VertexFrom.ControlNetPoint),
                    _point(edge.VertexTo.ControlNetPoint)) in keys:
            edge.Tag = rg.SubDEdgeTag.Crease
    subd.UpdateAllTagsAndSectorCoefficients()
    return subd


def _rhino_mesh(vertices, faces):
    mesh = Rhino.Geometry.Mesh()
    for x, y, z in vertices:
        mesh.Vertices.Add(x, y, z)
    for a, b, c, d in faces:
        mesh.Faces.AddFace(a, b, c, d)
    mesh.Normals.ComputeNormals()
    return mesh


def _expire_later(component):
    """Asks Rhino's UI thread to solve `component` again (Grasshopper is not thread-safe)."""
    import System

    Rhino.RhinoApp.InvokeOnUiThread(System.Action(lambda: component.ExpireSolution(True)))


def _people(inputs, scale):
    poses = [p for p in inputs.get("poses") or [] if p]
    positions = list(inputs.get("positions") or [])
    headings = list(inputs.get("headings") or [])
    support = inputs.get("support") or DEFAULT_SUPPORT
    if isinstance(support, str):
        support = support.split(",")
    support = [s.strip() for s in support if s and s.strip()]
    body = inputs.get("body")
    return [person_request(pose, _point(positions[k]) if k < len(positions) else (0, 0, 0),
                           headings[k] if k < len(headings) else 0.0, support,
                           inputs.get("facing") or "front", body, scale)
            for k, pose in enumerate(poses)]


def solve_component(env, inputs):
    """One solution of the Grasshopper component: starts a fit when asked, returns the last
    result at once (subd, surface, net, report, status)."""
    import scriptcontext

    state = scriptcontext.sticky.setdefault("sitrelax:" + str(env.Component.InstanceGuid),
                                            {"running": False, "sent": None})
    scale, tolerance = _document_scale()
    try:
        settings = json.loads(inputs.get("settings") or "{}")
        if not isinstance(settings, dict):
            raise SitrelaxError(f"expected settings as a JSON object, got {settings!r:.60}")
        vertices, faces, creases = _read_control(inputs.get("control"), inputs.get("creases"),
                                                 tolerance)
        people = _people(dict(inputs, body=settings.pop("body", None)), scale)
        request = fit_request(vertices, faces, people, creases, settings, scale)
    except (SitrelaxError, ValueError) as exc:
        return None, None, None, "", f"error: {exc}"
    url = inputs.get("url") or DEFAULT_URL
    if not inputs.get("run"):
        state["sent"] = None  # run off and on again fits again
    elif not state["running"] and json.dumps(request, sort_keys=True) != state["sent"]:
        start_fit(state, url, request, lambda: _expire_later(env.Component))
    status = ("fitting ..." if state["running"] else
              f"error: {state['error']}" if state.get("error") else None)
    if state.get("reply") is None:
        return None, None, None, "", status or "idle (set run to true)"
    result = state.get("result")
    if result is None or result[0] is not state["reply"]:
        fit = parse_fit(state["reply"], scale)
        result = (state["reply"], fit,
                  _rhino_subd(fit["control_vertices"], fit["control_faces"], fit["creases"]),
                  _rhino_mesh(fit["surface_vertices"], fit["surface_faces"]),
                  _rhino_mesh(fit["control_vertices"], fit["control_faces"]))
        state["result"] = result
    fit = result[1]
    status = status or (f"done in {fit['seconds']:.1f} s ({fit['iterations']} iterations, "
                        f"{fit['stop_reason']})")
    return result[2], result[3], result[4], "\n".join(report_lines(fit["persons"])), status


if Rhino is not None and "ghenv" in globals():
    subd, surface, net, report, status = solve_component(ghenv, {  # noqa: F821
        name: globals().get(name) for name in ("control", "poses", "positions", "headings",
                                               "support", "facing", "creases", "settings",
                                               "url", "run")})
