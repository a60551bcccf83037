"""Writing a Rhino document (.3dm) with rhino3dm: the control net, the surface, the bodies.

Geometry comes in sitrelax's frame (metres, right-handed, Y up) and is written in the
document's unit (millimetres by default) with Rhino's Z up: (x, y, z) -> (x, -z, y), a
rotation of +90 degrees about X that keeps handedness (a body facing +Z faces -Y, towards
Rhino's Front view). `up="y"` keeps the axes as they are.

Layers: "control net" (the quad control mesh), "surface" (NURBS surfaces and/or meshes), and
one per body, named after it. rhino3dm cannot build a SubD: the exact limit surface goes in as
NURBS where the control net is a regular grid, as a dense mesh of limit points elsewhere. (Rhino's
`ToSubD` of the control net is a Catmull-Clark SubD too, but its boundary and corner options
have not been checked against our rules here.)
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np

from solver.io.export import ExportError, frame_matrix, frame_note

_RHINO_UNITS = {"m": "Meters", "cm": "Centimeters", "mm": "Millimeters", "in": "Inches",
                "ft": "Feet"}
_COLOURS = {"control net": (90, 90, 90, 255), "surface": (70, 130, 190, 255),
            "body": (215, 170, 140, 255)}


def _rhino3dm():
    try:
        import rhino3dm
    except ImportError as err:  # pragma: no cover - a dependency, but fail clearly
        raise ExportError("Writing .3dm needs the rhino3dm package (pip install rhino3dm)"
                          ) from err
    return rhino3dm


def _checked_mesh(vertices, faces, what: str) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.isfinite(vertices).all():
        raise ExportError(f"Expected finite {what} vertices (V, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] not in (3, 4) or faces.min(initial=0) < 0 or \
            faces.max(initial=-1) >= len(vertices):
        raise ExportError(f"Expected {what} faces (F, 3|4) indexing {len(vertices)} vertices, "
                          f"got {faces.shape}")
    return vertices, faces


def _mesh(r, vertices: np.ndarray, faces: np.ndarray):
    mesh = r.Mesh()
    mesh.Vertices.UseDoublePrecisionVertices = True
    for x, y, z in vertices.tolist():
        mesh.Vertices.Add(x, y, z)
    for face in faces.tolist():
        mesh.Faces.AddFace(*face)
    mesh.Normals.ComputeNormals()
    mesh.Compact()
    return mesh


def _nurbs(r, surface, frame: np.ndarray):
    points = np.asarray(surface.points, dtype=np.float64)
    degree = int(surface.degree)
    knots_u, knots_v = np.asarray(surface.knots_u, float), np.asarray(surface.knots_v, float)
    if points.ndim != 3 or points.shape[2] != 3 or not np.isfinite(points).all():
        raise ExportError(f"Expected NURBS control points (Nu, Nv, 3), got {points.shape}")
    nu, nv = points.shape[:2]
    if len(knots_u) != nu + degree - 1 or len(knots_v) != nv + degree - 1:
        raise ExportError(f"Expected {nu + degree - 1} and {nv + degree - 1} knots (Rhino's "
                          f"convention), got {len(knots_u)} and {len(knots_v)}")
    srf = r.NurbsSurface.Create(3, False, degree + 1, degree + 1, nu, nv)
    moved = points @ frame.T
    for i in range(nu):
        for j in range(nv):
            srf.Points[i, j] = r.Point4d(*moved[i, j].tolist(), 1.0)
    for k, value in enumerate(knots_u.tolist()):
        srf.KnotsU[k] = value
    for k, value in enumerate(knots_v.tolist()):
        srf.KnotsV[k] = value
    if not srf.IsValid:
        raise ExportError("rhino3dm says the NURBS surface is not valid")
    return srf


def write_3dm(path: str | os.PathLike, control_vertices: np.ndarray, control_faces: np.ndarray,
              surface=None, bodies: Sequence[tuple[np.ndarray, np.ndarray]] = (), *,
              body_names: Sequence[str] | None = None, unit: str = "mm", up: str = "z",
              notes: str | None = None) -> Path:
    """Writes a Rhino 8 document: control net, surface(s) and bodies on their own layers.

    Parameters
    ----------
    path : str or os.PathLike
        The .3dm file to write (atomically).
    control_vertices : (n, 3) float
        The control net's vertices, metres, Y up.
    control_faces : (F, 4) or (F, 3) int
        Its faces (quads stay quads).
    surface : a B-spline, a mesh, or a list of them, optional
        A B-spline has `points` (Nu, Nv, 3) metres, `knots_u` (Nu + degree - 1,), `knots_v`
        and `degree` (as `solver.surface.nurbs.BSplineSurface`); a mesh is a (vertices (V, 3)
        metres, faces (F, 3|4) int) pair.
    bodies : sequence of (vertices (V, 3) metres, faces (F, 3|4) int)
        The posed bodies, one layer each.
    body_names : sequence of str, optional
        Their layer names (default "person 1", "person 2", ...).
    unit : str, default "mm"
        The document's unit: "m", "cm", "mm", "in" or "ft".
    up : str, default "z"
        "z" turns sitrelax's Y up into Rhino's Z up; "y" keeps the axes.
    notes : str, optional
        Text kept as every object's user string "sitrelax.notes" (each also carries
        "sitrelax.frame", its unit and axes).

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ExportError
        For a bad unit, up axis, mesh, B-spline or name count, or when rhino3dm cannot write.
    """
    r = _rhino3dm()
    frame = frame_matrix(unit, up)
    if unit not in _RHINO_UNITS:
        raise ExportError(f"Expected a unit in {sorted(_RHINO_UNITS)}, got {unit!r}")
    names = _layer_names(body_names, len(bodies))
    model = r.File3dm()
    model.Settings.ModelUnitSystem = getattr(r.UnitSystem, _RHINO_UNITS[unit])
    model.Settings.ModelAbsoluteTolerance = 1e-5 * frame_matrix(unit)[0, 0]  # 0.01 mm
    note = frame_note(unit, up)

    def layer(name: str, colour) -> "object":
        lay = r.Layer()
        lay.Name, lay.Color = name, colour
        attrs = r.ObjectAttributes()
        attrs.LayerIndex = model.Layers.Add(lay)
        attrs.Name = name
        attrs.SetUserString("sitrelax.frame", note)
        if notes:
            attrs.SetUserString("sitrelax.notes", notes)
        return attrs

    cv, cf = _checked_mesh(control_vertices, control_faces, "control")
    model.Objects.AddMesh(_mesh(r, cv @ frame.T, cf), layer("control net", _COLOURS["control net"]))
    attrs = layer("surface", _COLOURS["surface"])
    pieces = [] if surface is None else surface if isinstance(surface, list) else [surface]
    for piece in pieces:
        if hasattr(piece, "points"):
            model.Objects.AddSurface(_nurbs(r, piece, frame), attrs)
        else:
            sv, sf = _checked_mesh(*piece, "surface")
            model.Objects.AddMesh(_mesh(r, sv @ frame.T, sf), attrs)
    for name, (bv, bf) in zip(names, bodies):
        bv, bf = _checked_mesh(bv, bf, f"body {name!r}")
        model.Objects.AddMesh(_mesh(r, bv @ frame.T, bf), layer(name, _COLOURS["body"]))
    return _write(model, Path(path))


# Rhino names no layer with one of these first (nor with nothing): rhino3dm gave such a layer
# a name of its own ("Layer 03"), and the body's name was lost
_NOT_FIRST_IN_NAME = "()[]{}"


def _layer_names(body_names, count: int) -> list[str]:
    """The bodies' layer names: each run of whitespace (a line break, a tab) one space and
    none at either end (Rhino refuses a layer name with control characters: rhino3dm named
    such a layer "Layer 03"), "::" one colon (Rhino reads it as a sublayer's path). An empty
    name, or one beginning with a bracket or parenthesis, is refused."""
    names = [" ".join(str(n).split()).replace("::", ":") for n in body_names] \
        if body_names is not None else [f"person {k}" for k in range(1, count + 1)]
    if len(names) != count or len(set(names)) != len(names) or \
            {"control net", "surface"} & set(names):
        raise ExportError(f"Expected {count} distinct body names other than the "
                          f"'control net' and 'surface' layers, got {names}")
    refused = [n for n in names if not n or n[0] in _NOT_FIRST_IN_NAME]
    if refused:
        raise ExportError(f"Expected body names Rhino takes as layer names (not empty, not "
                          f"beginning with one of {_NOT_FIRST_IN_NAME}), got {refused}")
    return names


def _write(model, path: Path) -> Path:
    """Writes through a temporary file in the same folder, then renames it into place."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    os.close(fd)
    try:
        if not model.Write(tmp, 7):  # (Rhino 7 and later open it)
            raise ExportError(f"rhino3dm could not write {path}")
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would keep the document from others
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path
