"""Reading quad meshes from Wavefront OBJ files (control meshes, fitted surfaces)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np


class MeshFileError(ValueError):
    """A mesh file that cannot be read as a quad mesh; the message names the file (and line)."""


def read_quad_obj(path: str | os.PathLike, sitrelax_frame: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and quad faces of an OBJ file in which every face is a quad.

    Parameters
    ----------
    path : the OBJ file (faces 1-based or negative, `v/vt/vn` references allowed).
    sitrelax_frame : convert the vertices from the unit and up axis the file states
        (`obj_frame`) to metres, Y up; False: as written.

    Returns
    -------
    vertices : (V, 3) float, in the file's units (metres, Y up with `sitrelax_frame`);
    faces : (F, 4) int, 0-based.
    Raises MeshFileError with `file:line` for a malformed or non-finite vertex or a face that
    is no quad, and naming the file for faces out of range, with repeated corners or without
    area (`solver.mesh.faces_problem`).
    """
    from solver.mesh import faces_problem

    path = Path(path)
    if not path.exists():
        raise MeshFileError(f"no such file {path}")
    verts, faces = [], []
    for no, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            try:
                if len(parts) < 4:
                    raise ValueError
                xyz = [float(x) for x in parts[1:4]]
            except ValueError:
                raise MeshFileError(f"{path}:{no}: expected 'v x y z', got "
                                    f"{line.strip()!r}") from None
            if not all(math.isfinite(x) for x in xyz):
                raise MeshFileError(f"{path}:{no}: expected finite coordinates, got "
                                    f"{line.strip()!r}")
            verts.append(xyz)
        elif parts[0] == "f":
            try:
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                if 0 in idx:
                    raise ValueError
            except ValueError:
                raise MeshFileError(f"{path}:{no}: expected 'f' and vertex numbers (from 1, "
                                    f"or negative from the last), got {line.strip()!r}") from None
            if len(idx) != 4:
                raise MeshFileError(f"{path}:{no}: expected a quad control mesh, got a face "
                                    f"of {len(idx)} vertices")
            faces.append([i - 1 if i > 0 else len(verts) + i for i in idx])
    if not faces:
        raise MeshFileError(f"{path}: expected quad faces, found none")
    v, f = np.array(verts, dtype=float).reshape(-1, 3), np.array(faces, dtype=np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise MeshFileError(f"{path}: face indices out of range")
    problem = faces_problem(v, f)
    if problem:
        raise MeshFileError(f"{path}: {problem}")
    if sitrelax_frame:
        from solver.io.export import frame_matrix

        v = v @ np.linalg.inv(frame_matrix(*obj_frame(path))).T
    return v, f


def obj_frame(path: str | os.PathLike) -> tuple[str, str]:
    """The unit and up axis an OBJ file's header comment states (`write_mesh` writes
    ``# units: mm; up: +Z; ...``); ("m", "y") when it states none (sitrelax's own frame).

    Raises MeshFileError with `file:line` for a stated unit or axis that is not known.
    """
    path = Path(path)
    with open(path, errors="replace") as fh:
        for no, line in enumerate(fh, start=1):
            if not line.startswith("#"):
                break
            frame = stated_frame(line[1:], line, f"{path}:{no}")
            if frame is not None:
                return frame
    return "m", "y"


def stated_frame(text: str, line: str, where: str) -> tuple[str, str] | None:
    """The unit and up axis a header comment's `text` states as `write_mesh` writes them
    (``units: mm; up: +Z; ...``), None when it states not both; MeshFileError naming `where`
    and the whole `line` for a unit or axis that is not known."""
    from solver.io.export import UNITS, UP_AXES

    fields = dict(part.strip().split(":", 1) for part in text.split(";") if ":" in part)
    if "units" not in fields or "up" not in fields:
        return None
    unit, up = fields["units"].strip(), fields["up"].strip().lstrip("+").lower()
    if unit not in UNITS or up not in UP_AXES:
        raise MeshFileError(f"{where}: expected a unit in {sorted(UNITS)} and an up axis in "
                            f"{UP_AXES}, got {line.strip()!r}")
    return unit, up


# what `read_surface_mesh` reads: every mesh format `write_mesh` writes
SURFACE_SUFFIXES = (".obj", ".ply", ".glb")


def read_surface_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """A surface as `solver.io.export.write_mesh` writes it (and CAD exports it), in metres,
    Y up: OBJ (quads or triangles), PLY or GLB.

    Parameters
    ----------
    path : a file ending in one of `SURFACE_SUFFIXES`. OBJ and PLY are converted from the unit
        and up axis their header states (`obj_frame`, `ply_frame`; metres and Y up when they
        state none), GLB is metres and Y up (glTF 2.0).

    Returns
    -------
    vertices : (V, 3) float, metres, Y up;
    faces : (F, 4) int quads (an OBJ of quads only) or (F, 3) int triangles, 0-based.
    Raises MeshFileError naming the file for a missing or unreadable file, another suffix, no
    faces, coordinates that are not finite, or faces out of range, with repeated corners or
    without area.
    """
    from solver.io.export import frame_matrix
    from solver.mesh import faces_problem

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SURFACE_SUFFIXES:
        raise MeshFileError(f"expected a surface file ending in {', '.join(SURFACE_SUFFIXES)}, "
                            f"got {path}")
    if not path.is_file():
        raise MeshFileError(f"no such file {path}" if not path.exists() else
                            f"expected a surface file, got the folder {path}")
    if suffix == ".obj":
        try:
            return read_quad_obj(path, sitrelax_frame=True)
        except MeshFileError as exc:
            if "expected a quad control mesh" not in str(exc):
                raise
        frame = obj_frame(path)  # triangles (or a mix): read as triangles
    else:
        frame = ply_frame(path) if suffix == ".ply" else ("m", "y")
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh", process=False)
        vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    except Exception as exc:  # (trimesh's loaders raise what their parsers raise)
        raise MeshFileError(f"{path} cannot be read as a mesh ({type(exc).__name__}: "
                            f"{exc})") from None
    if not len(faces):
        raise MeshFileError(f"{path}: expected faces, found none")
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if len(bad):
        raise MeshFileError(f"{path}: expected finite coordinates, got vertex {bad[0] + 1} at "
                            f"{vertices[bad[0]].tolist()}" +
                            (f" and {len(bad) - 1} more" if len(bad) > 1 else ""))
    problem = faces_problem(vertices, faces)
    if problem:
        raise MeshFileError(f"{path}: {problem}")
    return vertices @ np.linalg.inv(frame_matrix(*frame)).T, faces


def ply_frame(path: str | os.PathLike) -> tuple[str, str]:
    """The unit and up axis a PLY header's `comment` states (as `write_mesh` writes it,
    ``comment units: mm; up: +Z; ...``); ("m", "y") when it states none.

    Raises MeshFileError naming the file for a stated unit or axis that is not known, or a
    header that does not end.
    """
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(65536)
    if b"end_header" not in head:
        raise MeshFileError(f"{path}: expected a PLY header ending in 'end_header'")
    for line in head.split(b"end_header")[0].decode("ascii", "replace").splitlines():
        frame = stated_frame(line[7:], line, str(path)) if line.startswith("comment") else None
        if frame is not None:
            return frame
    return "m", "y"
