"""Contact coverage counts the importance touching the surface, not all within the margin."""

import numpy as np
import trimesh

from solver.contact.evaluate import evaluate_person, flat_surface
from solver.contact.settle import Foam
from solver.contact.supported import SupportedBody
from solver.mesh import triangle_mesh


def _ball(bottom: float) -> SupportedBody:
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    v = np.asarray(sphere.vertices) + [0.0, bottom + 0.1, 0.0]
    t = np.asarray(sphere.faces)
    areas, normals = triangle_mesh(t, len(v)).measures(v)
    importance = np.where(v[:, 1] < bottom + 0.04, 1.0, 0.0)  # its lowest 4 cm
    return SupportedBody(v, normals, importance, "ball", t, areas, mass_kg=5.0)


def test_a_ball_hovering_2_cm_up_is_covered_but_not_in_contact():
    plane = flat_surface(0.0, np.zeros(3))
    hovering, _ = evaluate_person(plane, _ball(0.02), 0.03, Foam(200e3), floor=None)
    resting, _ = evaluate_person(plane, _ball(-0.002), 0.03, Foam(200e3), floor=None)
    assert hovering["coverage"] > 0.1 and hovering["contact_coverage"] == 0.0
    assert resting["contact_coverage"] > 0.0
    assert resting["contact_coverage"] <= resting["coverage"]
