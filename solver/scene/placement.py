"""People placed in a scene: posed bodies with their pressure fields, ready to be supported."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from solver.body.model import Body, make_body
from solver.contact.supported import SupportedBody
from solver.body.poses import load_pose, retarget_captured
from solver.body.retarget import place
from solver.contact.pressure import pressure_field, reachable
from solver.mesh import triangle_mesh
from solver.body.rig import RigMotion
from solver.scene.scenario import PersonSpec, Scenario, ScenarioError, template_error
from solver.body.skinning import skin


@dataclass(frozen=True, eq=False, kw_only=True)
class PlacedPerson(SupportedBody):
    """A person in the scene: the posed skin with its support fields (`SupportedBody`: vertices,
    unit normals, Voronoi areas, importance, the supported parts' mask, mass), the scenario's
    person, the body and its rig posed in the scene frame before `transform`, and the heading
    (radians about +Y) that ``facing = "front"`` turns it by, whether or not it was turned."""

    spec: PersonSpec
    body: Body
    motion: RigMotion
    transform: np.ndarray  # (4, 4) scene placement applied after posing
    heading: float = 0.0


def placement(position, rotation_deg) -> np.ndarray:
    """(4, 4) rotation about world x, then y, then z (degrees), then translation."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", rotation_deg, degrees=True).as_matrix()
    m[:3, 3] = position
    return m


def facing_heading(motion: RigMotion) -> float:
    """The turn about the vertical (radians about +Y) that makes the posed body (frame 0) face
    +Z: its hip axis, right hip to left, along +X; where the hip axis stands near vertical
    (lying on a side), the pelvis's forward axis along +Z instead."""
    body, world = motion.body, motion.world
    hips = world.positions[0, [body.joint_index("LeftUpLeg"), body.joint_index("RightUpLeg")]]
    left = hips[0] - hips[1]
    if np.hypot(left[0], left[2]) >= 0.3 * np.linalg.norm(left):
        return float(np.arctan2(left[2], left[0]))
    forward = world.rotmats[0, 0] @ [0.0, 0.0, 1.0]
    return float(np.arctan2(-forward[0], forward[2]))


def person_frame(person) -> tuple[np.ndarray, np.ndarray]:
    """Where a placed person's sections go.

    Parameters
    ----------
    person : PlacedPerson

    Returns
    -------
    pelvis : (3,) float
        The rig's root (pelvis) in the scene frame, metres.
    forward : (3,) float
        Horizontal unit direction the person faces: the hip axis (right to left) turned a
        quarter about the vertical, or the pelvis's own forward axis where the hip axis
        stands near vertical (lying on a side).
    """
    body, world = person.body, person.motion.world
    rot, shift = person.transform[:3, :3], person.transform[:3, 3]
    pelvis = rot @ world.positions[0, 0] + shift
    hips = world.positions[0, [body.joint_index("LeftUpLeg"), body.joint_index("RightUpLeg")]]
    left = rot @ (hips[0] - hips[1])
    forward = np.cross(left, [0.0, 1.0, 0.0])
    if np.hypot(forward[0], forward[2]) < 0.3 * np.linalg.norm(left):
        forward = rot @ world.rotmats[0, 0] @ [0.0, 0.0, 1.0]
    forward[1] = 0.0
    return pelvis, forward / np.linalg.norm(forward)


def place_person(spec: PersonSpec, db: str | os.PathLike | None = None,
                 index: int = 0) -> PlacedPerson:
    """Poses the person's body (lowest point on y = 0, pelvis over the origin), then places it.
    The captured skeleton and the rig are posed once and the skin skinned once.

    The placement turns the body to face +Z (``spec.facing == "front"``: `facing_heading`),
    rotates it about world x, then y, then z by `spec.rotation_deg` (degrees), then moves it by
    `spec.position` (metres). Importance is the pressure model's, restricted to the supported
    parts' vertices a support can reach.

    A library pose stored by a relaxation carries where the relaxation left it
    (`posedb.PosePlacement`, in the pose's own frame): with ``spec.placement == "stored"`` (the
    default) its offset is added to the standard placement before the turns and the move, and
    "front" turns it by the stored heading (that of the pose it was relaxed from) instead of
    one measured on it, so in the scenario it was relaxed in, at the same position and
    rotation, it stands where it was relaxed to; moved or turned, it moves and turns with its
    person. ``"standard"`` places it as any other pose. A pose without one places the same
    either way.

    Parameters
    ----------
    spec : PersonSpec
        The scenario's person: pose source, body shape, position (3,) in metres, rotation (3,)
        in degrees, supported parts and name.
    db : str or os.PathLike, optional
        The pose library, for a ``db:`` pose.
    index : int, default 0
        The person's 0-based place in the scenario, for the default label.

    Returns
    -------
    PlacedPerson
        The placed skin: vertices (V, 3) in metres, unit normals (V, 3), importance (V,),
        label, triangles (F, 3), Voronoi areas (V,) in m^2, supported parts (V,) bool and mass
        in kg; with the spec, the body, its rig motion (1 frame, before placement) and the
        (4, 4) transform from that frame to the scene.

    Raises
    ------
    PoseSourceError
        If the pose cannot be resolved.
    RetargetError
        If the captured skeleton cannot be retargeted.
    BodyShapeError
        If a supported part is unknown.
    """
    body = make_body(spec.body)
    captured = load_pose(spec.pose, db, joint_map=dict(spec.joint_map) or None)
    motion = place(retarget_captured(captured, body), lowest=0.0)
    verts, _ = skin(body, motion.frame(0), normals=False)  # the one full skinning
    pelvis = motion.world.positions[0, 0]
    centre = np.array([pelvis[0], 0.0, pelvis[2]])
    stored = captured.placement if spec.placement == "stored" else None
    heading = facing_heading(motion) if stored is None else stored.heading
    if stored is not None:  # where its relaxation left it, relative to the standard placement
        centre = centre - np.asarray(stored.offset, dtype=np.float64)
    m = placement(spec.position, spec.rotation_deg)
    if spec.facing == "front":  # turned to face +Z first, whatever the capture room's heading
        m[:3, :3] = m[:3, :3] @ Rotation.from_euler("y", heading).as_matrix()
    placed = (verts - centre) @ m[:3, :3].T + m[:3, 3]
    to_scene = m.copy()
    to_scene[:3, 3] = m[:3, 3] - m[:3, :3] @ centre
    areas, normals, importance = skin_support(body, spec.support, placed)
    parts = body.part_mask(spec.support)
    label = spec.name or f"person {index + 1}"
    return PlacedPerson(placed, normals, importance, f"{label} ({captured.label})",
                        body.triangles, areas, parts, body.mass_kg, body.regions,
                        m[:3, :3].copy(), spec=spec, body=body,
                        motion=motion, transform=to_scene, heading=heading)


def skin_support(body: Body, support, placed: np.ndarray, clear: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What `place_person` measures on a body's skin where it is placed, `placed` (V, 3)
    metres: the Voronoi areas (V,), the unit normals (V, 3) and the importance (V,) of the
    `support` asked for (`pressure_field` over the skin a support can reach). `clear` (V,)
    bool: which vertices' outward normals do not run back into the body (`reachable` asked of
    every vertex), when known: it is the same wherever the body is moved without turning, and
    its inside tests are the costly part."""
    areas, normals = triangle_mesh(body.triangles, len(placed)).measures(placed)
    # the importance asks for none of the thighs' skin beside the calves in this pose (the
    # rim stays clear of the calves), though it is part of the thighs that may be touched
    asked = body.part_mask(support, placed)
    # a support can only reach skin whose outward normal does not run back into the body
    facing_down = asked & (normals @ [0.0, -1.0, 0.0] > 0)
    reach = asked & (reachable(placed, body.triangles, normals, facing_down) if clear is None
                     else facing_down & clear)
    field = pressure_field(placed, body.triangles, mask=reach, normals=normals, areas=areas)
    return areas, normals, field.importance


def relaxed_placement(person: PlacedPerson, vertices: np.ndarray,
                      root: np.ndarray) -> tuple[tuple[float, float, float], float]:
    """Where a placed person's relaxed body stands relative to the standard placement of the
    relaxed pose, in the pose's own frame (the frame of `person.motion`, which the relaxed pose
    is stored in): what `place_person` adds back (`posedb.PosePlacement`).

    Parameters
    ----------
    person : PlacedPerson
        The person as placed for the relaxation.
    vertices : (V, 3) float
        The relaxed skin in the scene frame, metres.
    root : (3,) float
        The relaxed rig's root (pelvis) in the scene frame, metres.

    Returns
    -------
    offset : (x, y, z) metres: the relaxed pelvis's horizontal place and its lowest skin
        point's height, less those of the standard placement of the pose it came from.
    heading : radians about +Y, the turn to face +Z of the pose it came from.
    """
    rot, shift = person.transform[:3, :3], person.transform[:3, 3]
    own = (np.asarray(vertices, dtype=np.float64) - shift) @ rot
    pelvis = rot.T @ (np.asarray(root, dtype=np.float64) - shift)
    # the centre the person was placed about: position = rot @ centre + shift
    centre = rot.T @ (np.asarray(person.spec.position, dtype=np.float64) - shift)
    offset = np.array([pelvis[0], own[:, 1].min(), pelvis[2]]) - centre
    return (float(offset[0]), float(offset[1]), float(offset[2])), float(person.heading)


def place_scene(scenario: Scenario, db: str | os.PathLike | None = None, *,
                place: Callable[[PersonSpec, int], PlacedPerson] | None = None
                ) -> tuple[Scenario, list[PlacedPerson]]:
    """Places every person of a scenario and, for a template surface, builds its control mesh
    around them (`solver.scene.furnish.furnish`): the one place a scenario's people are placed
    for a fit.

    Parameters
    ----------
    scenario : the scenario as read.
    db : the pose library for ``db:`` poses.
    place : optional place(spec, index) -> PlacedPerson instead of `place_person` (a cache).

    Returns
    -------
    scenario : the scenario with its control mesh (for a template: built, its full parameters
        under `surface.template.built`; otherwise the same object).
    people : the placed people, in the scenario's order.
    """
    place = place or (lambda spec, k: place_person(spec, db, k))
    people = [place(p, k) for k, p in enumerate(scenario.persons)]
    return furnished(scenario, people), people


def furnished(scenario: Scenario, people: list[PlacedPerson]) -> Scenario:
    """The scenario with its template surface built around the placed people (the scenario
    itself when its surface is no template, or is built already)."""
    surface = scenario.surface
    if surface.template is None or surface.vertices is not None:
        return scenario
    from solver.scene.furnish import furnish  # loaded for a template only
    from solver.surface.templates import TemplateError

    try:
        mesh = furnish(surface.template.kind, surface.template.given, people)
    except TemplateError as exc:
        raise template_error(exc, scenario.path or "<scenario>",
                             surface.template.given) from None
    if not np.array_equal(mesh.quads, surface.faces):  # the topology never depends on people
        raise ScenarioError(f"{scenario.path}: surface.template: the template built around "
                            f"the people has other faces than the one read")
    built = dataclasses.replace(surface.template, built=mesh.params)
    return dataclasses.replace(scenario, surface=dataclasses.replace(
        surface, vertices=mesh.vertices, source=mesh.source, template=built))


def scene_posture(person: PlacedPerson) -> str:
    """The posture of a placed person as the scene holds it (`solver.body.posture`): its joints
    placed as its skin is, set down with the lowest skin point on the floor; so a seated pose
    turned back in the scene reads as reclined, one laid on a bed as lying."""
    from solver.body.posture import classify_posture, posture_figures

    joints = person.motion.world.positions[0] @ person.transform[:3, :3].T + \
        person.transform[:3, 3]
    joints[:, 1] -= person.vertices[:, 1].min()
    return classify_posture(posture_figures(joints, person.body.joint_names))
