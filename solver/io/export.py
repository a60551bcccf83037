"""Writing meshes for CAD and viewers: OBJ (quads kept, Rhino-ready), PLY, GLB."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from capture.files import write_atomic

from solver.mesh import quad_triangles

MESH_FORMATS = (".obj", ".ply", ".glb")


class ExportError(ValueError):
    """A mesh that cannot be written as asked."""


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
               comment: str | None = None) -> Path:
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

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ExportError
        If the vertices or faces have the wrong shape, are not finite or index out of range,
        or the suffix is not one of `MESH_FORMATS`.
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
    if suffix == ".obj":
        write_atomic(path, obj_text(vertices, faces, normals, comment).encode())
        return path
    if suffix not in MESH_FORMATS:
        raise ExportError(f"Expected a mesh file ending in {MESH_FORMATS}, got {path.name!r}")
    import trimesh

    tris = faces if faces.shape[1] == 3 else quad_triangles(faces)
    colors = None
    if vertex_colors is not None:
        colors = (np.clip(np.asarray(vertex_colors, dtype=float), 0, 1) * 255).astype(np.uint8)
    mesh = trimesh.Trimesh(vertices, tris, vertex_colors=colors, process=False)
    write_atomic(path, mesh.export(file_type=suffix[1:]))
    return path
