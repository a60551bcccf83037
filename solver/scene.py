"""People placed in a scene: posed bodies with their pressure fields, ready to be supported."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .body import Body, make_body
from .fit import BodyTarget
from .poses import load_pose, pose_body
from .pressure import pressure_field, reachable, triangle_mesh
from .retarget import RigMotion
from .scenario import PersonSpec
from .skinning import skin


@dataclass(frozen=True, eq=False)
class PlacedPerson:
    """A person in the scene: `vertices` (V, 3) m, unit `normals`, Voronoi `areas`, `importance`
    (zero outside the supported parts), the body and its rig posed in the scene."""

    spec: PersonSpec
    body: Body
    motion: RigMotion
    transform: np.ndarray  # (4, 4) scene placement applied after posing
    vertices: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    importance: np.ndarray
    label: str

    def target(self) -> BodyTarget:
        return BodyTarget(self.vertices, self.normals, self.importance, self.label,
                          self.body.triangles)


def placement(position, rotation_deg) -> np.ndarray:
    """(4, 4) rotation about world x, then y, then z (degrees), then translation."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", rotation_deg, degrees=True).as_matrix()
    m[:3, 3] = position
    return m


def place_person(spec: PersonSpec, db: str | os.PathLike | None = None,
                 index: int = 0) -> PlacedPerson:
    """Poses the person's body (lowest point on y = 0, pelvis over the origin), then places it."""
    body = make_body(spec.body)
    captured = load_pose(spec.pose, db)
    motion = pose_body(captured, body, lowest=0.0)
    verts, _ = skin(body, motion.frame(0), normals=False)
    pelvis = motion.world.positions[0, 0]
    centre = np.array([pelvis[0], 0.0, pelvis[2]])
    m = placement(spec.position, spec.rotation_deg)
    placed = (verts - centre) @ m[:3, :3].T + m[:3, 3]
    to_scene = m.copy()
    to_scene[:3, 3] = m[:3, 3] - m[:3, :3] @ centre
    areas, normals = triangle_mesh(body.triangles, len(placed)).measures(placed)
    parts = body.part_mask(spec.support)
    # a support can only reach skin whose outward normal does not run back into the body
    parts &= reachable(placed, body.triangles, normals, parts & (normals @ [0.0, -1.0, 0.0] > 0))
    field = pressure_field(placed, body.triangles, mask=parts, normals=normals, areas=areas)
    label = spec.name or f"person {index + 1}"
    return PlacedPerson(spec, body, motion, to_scene, placed, normals, areas, field.importance,
                        f"{label} ({captured.label})")
