"""Writing meshes for CAD and viewers: OBJ (quads kept, Rhino-ready), PLY, GLB.

Geometry comes in sitrelax's frame (metres, right-handed, Y up) and is written in the unit and
up axis asked for, stated in the file: OBJ in a header comment, PLY in a header `comment`
line, GLB in its asset's `extras`. Z up is the rotation (x, y, z) -> (x, -z, y) (+90 degrees
about X: Y up becomes Z up, handedness kept, a body facing +Z faces -Y, towards Rhino's Front
view). GLB is always metres and Y up, as glTF 2.0 defines it.
"""

from __future__ import annotations

import os
import struct
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
    parts = [f"# {line}\n" for line in (comment or "").splitlines()]
    # one format string a block, applied to the flattened array: the formatting runs in C
    parts.append(_rows("v %.6f %.6f %.6f\n", np.asarray(vertices, dtype=np.float64)))
    one = np.asarray(faces, dtype=np.int64) + 1
    if normals is not None:
        parts.append(_rows("vn %.5f %.5f %.5f\n", np.asarray(normals, dtype=np.float64)))
        parts.append(_rows("f" + " %d//%d" * one.shape[1] + "\n", np.repeat(one, 2, axis=1)))
    else:
        parts.append(_rows("f" + " %d" * one.shape[1] + "\n", one))
    return "".join(parts)


def _rows(line: str, values: np.ndarray) -> str:
    """`line` % row for every row of a 2-D array, joined."""
    return (line * len(values)) % tuple(values.ravel().tolist())


def write_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, *,
               normals: np.ndarray | None = None, vertex_colors: np.ndarray | None = None,
               comment: str | None = None, unit: str = "m", up: str = "y") -> Path:
    """Writes a mesh atomically; the format follows the suffix (.obj, .ply or .glb).

    OBJ keeps the faces as given (quads stay quads) and writes `normals` and `comment`; PLY
    (binary) and GLB (`ply_bytes`, `glb_bytes`) split quads into triangles and carry
    `vertex_colors`.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write; its suffix picks the format.
    vertices : (V, 3) float
        Finite vertex positions, metres.
    faces : (F, 3) or (F, 4) int
        0-based triangles or quads indexing the vertices.
    normals : (V, 3) float, optional
        Finite vertex normals (OBJ only; checked whatever the format).
    vertex_colors : (V, 3) or (V, 4) float, optional
        Finite colours in [0, 1] (clipped), written as 8-bit (PLY and GLB only).
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
        If the vertices, faces, normals or colours have the wrong shape, the vertices,
        normals or colours are not finite, the faces index out of range,
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
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        # a short array would leave faces naming normals the file lacks; NaN would be written
        if normals.shape != vertices.shape or not np.isfinite(normals).all():
            raise ExportError(f"Expected finite vertex normals ({len(vertices)}, 3), got "
                              f"{normals.shape} with {int(np.sum(~np.isfinite(normals)))} "
                              f"values that are not finite")
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
            normals = normals @ (frame.T / UNITS[unit])
        text = obj_text(vertices, faces, normals, f"{comment}\n{note}" if comment else note)
        write_atomic(path, text.encode())
        return path
    tris = np.ascontiguousarray(faces if faces.shape[1] == 3 else quad_triangles(faces))
    colors = None
    if vertex_colors is not None:
        colors = np.asarray(vertex_colors, dtype=float)
        if colors.shape not in ((len(vertices), 3), (len(vertices), 4)) or \
                not np.isfinite(colors).all():
            raise ExportError(f"Expected finite vertex colours ({len(vertices)}, 3|4), got "
                              f"{colors.shape} with {int(np.sum(~np.isfinite(colors)))} "
                              f"values that are not finite")
        colors = _rgba8(colors)
    if suffix == ".ply":
        data = ply_bytes(vertices, tris, colors, note)
    else:  # glTF's asset carries the statement in its extras
        data = glb_bytes(vertices, tris, colors, {"sitrelax": note})
    write_atomic(path, data)
    return path


def _rgba8(colors: np.ndarray) -> np.ndarray:
    """(V, 4) uint8 of colours in [0, 1] (clipped), opaque where no alpha is given."""
    rgba = np.full((len(colors), 4), 255, dtype=np.uint8)
    rgba[:, :colors.shape[1]] = (np.clip(colors, 0, 1) * 255).astype(np.uint8)
    return rgba


def ply_bytes(vertices: np.ndarray, triangles: np.ndarray, colors: np.ndarray | None = None,
              comment: str | None = None) -> bytes:
    """A binary little-endian PLY of triangles: float32 x, y, z (and uint8 red, green, blue,
    alpha when `colors` (V, 4) uint8 is given), faces as a uchar count and int32 indices."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        fields += [(c, "u1") for c in ("red", "green", "blue", "alpha")]
    vert = np.empty(len(vertices), dtype=fields)
    for k, axis in enumerate("xyz"):
        vert[axis] = vertices[:, k]
    if colors is not None:
        for k, c in enumerate(("red", "green", "blue", "alpha")):
            vert[c] = colors[:, k]
    face = np.empty(len(triangles), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"] = 3
    face["i"] = triangles
    names = {"<f4": "float", "u1": "uchar"}
    head = ["ply", "format binary_little_endian 1.0"]
    head += [f"comment {comment}"] if comment else []
    head += [f"element vertex {len(vert)}"]
    head += [f"property {names[t]} {n}" for n, t in fields]
    head += [f"element face {len(face)}", "property list uchar int vertex_indices",
             "end_header"]
    return "\n".join(head).encode() + b"\n" + vert.tobytes() + face.tobytes()


def glb_bytes(vertices: np.ndarray, triangles: np.ndarray, colors: np.ndarray | None = None,
              extras: dict | None = None) -> bytes:
    """A binary glTF 2.0 (GLB) of one triangle mesh: float32 positions, uint32 indices and,
    with `colors` (V, 4) uint8, normalised COLOR_0; `extras` go in the asset."""
    import json

    index = np.ascontiguousarray(triangles, dtype="<u4").ravel()
    position = np.ascontiguousarray(vertices, dtype="<f4")
    blobs = [index.tobytes(), position.tobytes()]
    accessors = [
        {"bufferView": 0, "componentType": 5125, "count": int(index.size), "type": "SCALAR",
         "min": [int(index.min(initial=0))], "max": [int(index.max(initial=0))]},
        {"bufferView": 1, "componentType": 5126, "count": len(position), "type": "VEC3",
         "min": position.min(axis=0).tolist(), "max": position.max(axis=0).tolist()}]
    attributes = {"POSITION": 1}
    if colors is not None:
        blobs.append(np.ascontiguousarray(colors, dtype=np.uint8).tobytes())
        accessors.append({"bufferView": 2, "componentType": 5121, "normalized": True,
                          "count": len(colors), "type": "VEC4"})
        attributes["COLOR_0"] = 2
    views, offset = [], 0
    for k, blob in enumerate(blobs):
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(blob),
                      "target": 34963 if k == 0 else 34962})  # element or vertex array
        offset += len(blob) + (-len(blob) % 4)  # every view starts 4-byte aligned
    binary = b"".join(blob + b"\0" * (-len(blob) % 4) for blob in blobs)
    gltf = {"asset": {"version": "2.0", "generator": "sitrelax",
                      **({"extras": extras} if extras else {})},
            "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": attributes, "indices": 0, "mode": 4}]}],
            "accessors": accessors, "bufferViews": views,
            "buffers": [{"byteLength": len(binary)}]}
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # the JSON chunk is padded with spaces
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join([struct.pack("<4sII", b"glTF", 2, total),
                     struct.pack("<I4s", len(text), b"JSON"), text,
                     struct.pack("<I4s", len(binary), b"BIN\0"), binary])
