"""A ball resting on a seat: the fit tests' small body (importance from the pressure model)."""

import numpy as np
import pytest
import trimesh

from solver.contact.pressure import pressure_field
from solver.mesh import triangle_mesh


@pytest.fixture(scope="module")
def ball():
    """Vertices, triangles, normals, areas and importance of a 0.2 m ball 0.62 m up."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
    v = np.asarray(sphere.vertices) + [0.0, 0.62, 0.0]
    t = np.asarray(sphere.faces)
    areas, normals = triangle_mesh(t, len(v)).measures(v)
    importance = pressure_field(v, t, normals=normals, areas=areas).importance
    return v, t, normals, areas, importance
