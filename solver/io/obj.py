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
    from solver.io.export import UNITS, UP_AXES

    path = Path(path)
    with open(path, errors="replace") as fh:
        for no, line in enumerate(fh, start=1):
            if not line.startswith("#"):
                break
            fields = dict(part.strip().split(":", 1) for part in line[1:].split(";")
                          if ":" in part)
            if "units" in fields and "up" in fields:
                unit, up = fields["units"].strip(), fields["up"].strip().lstrip("+").lower()
                if unit not in UNITS or up not in UP_AXES:
                    raise MeshFileError(f"{path}:{no}: expected a unit in {sorted(UNITS)} and "
                                        f"an up axis in {UP_AXES}, got {line.strip()!r}")
                return unit, up
    return "m", "y"
