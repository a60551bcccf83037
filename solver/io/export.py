"""Writing meshes for CAD and viewers: OBJ (quads kept, Rhino-ready), PLY, GLB.

Geometry comes in sitrelax's frame (metres, right-handed, Y up) and is written in the unit and
up axis asked for, stated in the file: OBJ in a header comment, PLY in a header `comment`
line, GLB in its asset's `extras`. Z up is the rotation (x, y, z) -> (x, -z, y) (+90 degrees
about X: Y up becomes Z up, handedness kept, a body facing +Z faces -Y, towards Rhino's Front
view). GLB is always metres and Y up, as glTF 2.0 defines it.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from capture.files import write_atomic

from solver.mesh import quad_triangles

MESH_FORMATS = (".obj", ".ply", ".glb")
UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0, "in": 1.0 / 0.0254, "ft": 1.0 / 0.3048}
UP_AXES = ("y", "z")


class ExportError(ValueError):
    """A mesh that cannot be written as asked."""


def frame_matrix(unit: str = "m", up: str = "y") -> np.ndarray:
    """(3, 3) the map from sitrelax's frame (metres, Y up) to a file's unit and up axis:
    ``file_points = points @ frame_matrix(unit, up).T``.

    Parameters
    ----------
    unit : one of `UNITS` ("m", "cm", "mm", "in", "ft").
    up : "y" (kept) or "z" ((x, y, z) -> (x, -z, y), a rotation).

    Raises
    ------
    ExportError
        If the unit or the up axis is none of those.
    """
    if unit not in UNITS:
        raise ExportError(f"Expected a unit in {sorted(UNITS)}, got {unit!r}")
    if up not in UP_AXES:
        raise ExportError(f"Expected an up axis in {UP_AXES}, got {up!r}")
    rot = np.eye(3) if up == "y" else np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    return UNITS[unit] * rot


def frame_note(unit: str = "m", up: str = "y") -> str:
    """One line stating a file's unit and up axis (and the conversion from sitrelax's)."""
    frame_matrix(unit, up)
    turn = "" if up == "y" else "; (x, y, z) -> (x, -z, y) from sitrelax's Y up"
    return f"units: {unit}; up: +{up.upper()}; right-handed{turn}"


def obj_text(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None,
             comment: str | None = None) -> str:
    """Wavefront OBJ text; faces (F, 3) or (F, 4), 0-based, are written as they are."""
    buf = io.StringIO()
    if comment:
        for line in comment.splitlines():
            buf.write(f"# {line}\n")
    np.savetxt(buf, vertices, fmt="v %.6f %.6f %.6f")
    if normals is not None:
        np.savetxt(buf, normals, fmt="vn %.5f %.5f %.5f")
        one = np.asarray(faces) + 1
        pairs = np.repeat(one, 2, axis=1)
        fmt = "f" + " %d//%d" * one.shape[1]
        np.savetxt(buf, pairs, fmt=fmt)
    else:
        np.savetxt(buf, np.asarray(faces) + 1, fmt="f" + " %d" * np.asarray(faces).shape[1])
    return buf.getvalue()


def write_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, *,
               normals: np.ndarray | None = None, vertex_colors: np.ndarray | None = None,
               comment: str | None = None, unit: str = "m", up: str = "y") -> Path:
    """Writes a mesh atomically; the format follows the suffix (.obj, .ply or .glb).

    OBJ keeps the faces as given (quads stay quads) and writes `normals` and `comment`; PLY and
    GLB go through trimesh, quads split into triangles, and carry `vertex_colors`.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write; its suffix picks the format.
    vertices : (V, 3) float
        Finite vertex positions, metres.
    faces : (F, 3) or (F, 4) int
        0-based triangles or quads indexing the vertices.
    normals : (V, 3) float, optional
        Vertex normals (OBJ only).
    vertex_colors : (V, 3) or (V, 4) float, optional
        Colours in [0, 1] (clipped), written as 8-bit (PLY and GLB only).
    comment : str, optional
        Header comment lines (OBJ only).
    unit : str, default "m"
        The file's length unit (see `UNITS`); OBJ and PLY state it in their header, GLB in
        `asset.extras.sitrelax`.
    up : str, default "y"
        The file's up axis, "y" or "z" (see `frame_matrix`).

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ExportError
        If the vertices or faces have the wrong shape, are not finite or index out of range,
        the suffix is not one of `MESH_FORMATS`, the unit or up axis is unknown, or a GLB is
        asked for in anything but metres and Y up.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.isfinite(vertices).all():
        raise ExportError(f"Expected finite vertices (V, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] not in (3, 4) or faces.min(initial=0) < 0 or \
            faces.max(initial=-1) >= len(vertices):
        raise ExportError(f"Expected faces (F, 3|4) indexing {len(vertices)} vertices")
    if suffix not in MESH_FORMATS:
        raise ExportError(f"Expected a mesh file ending in {MESH_FORMATS}, got {path.name!r}")
    if suffix == ".glb" and (unit, up) != ("m", "y"):
        raise ExportError(f"Expected metres and Y up for a GLB (glTF 2.0 defines them), got "
                          f"unit {unit!r}, up {up!r}")
    frame = frame_matrix(unit, up)
    note = frame_note(unit, up)
    vertices = vertices @ frame.T
    if suffix == ".obj":
        if normals is not None:
            normals = np.asarray(normals, dtype=np.float64) @ (frame.T / UNITS[unit])
        text = obj_text(vertices, faces, normals, f"{comment}\n{note}" if comment else note)
        write_atomic(path, text.encode())
        return path
    import trimesh

    tris = faces if faces.shape[1] == 3 else quad_triangles(faces)
    colors = None
    if vertex_colors is not None:
        colors = (np.clip(np.asarray(vertex_colors, dtype=float), 0, 1) * 255).astype(np.uint8)
    mesh = trimesh.Trimesh(vertices, tris, vertex_colors=colors, process=False)
    if suffix == ".ply":
        data = _ply_comment(mesh.export(file_type="ply"), note)
    else:  # glTF's asset carries the statement in its extras
        data = mesh.export(file_type="glb", tree_postprocessor=lambda tree: tree["asset"].update(
            extras={"sitrelax": note}))
    write_atomic(path, data)
    return path


def _ply_comment(data: bytes, note: str) -> bytes:
    """A PLY file's bytes with a `comment` line after its `format` line."""
    head, sep, rest = data.partition(b"\n")  # "ply"
    fmt, sep2, body = rest.partition(b"\n")
    if head.strip() != b"ply" or not fmt.startswith(b"format") or not sep2:
        raise AssertionError("trimesh wrote no PLY header")
    return head + sep + fmt + sep2 + f"comment {note}\n".encode() + body
