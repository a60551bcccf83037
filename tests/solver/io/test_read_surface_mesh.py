"""`read_surface_mesh` reads back what `write_mesh` writes, in every format and frame."""

import numpy as np
import pytest

from solver.io.export import write_mesh
from solver.io.obj import MeshFileError, read_surface_mesh

QUAD = np.array([[0.0, 0.4, 0.0], [0.5, 0.4, 0.0], [0.5, 0.45, 0.5], [0.0, 0.45, 0.5]])


@pytest.mark.parametrize("suffix, unit, up", [(".obj", "mm", "z"), (".ply", "mm", "z"),
                                              (".ply", "in", "y"), (".glb", "m", "y")])
def test_a_written_surface_reads_back_in_metres_y_up(tmp_path, suffix, unit, up):
    path = write_mesh(tmp_path / f"surface{suffix}", QUAD, np.array([[0, 1, 2, 3]]),
                      unit=unit, up=up)
    vertices, faces = read_surface_mesh(path)
    np.testing.assert_allclose(vertices, QUAD, atol=1e-6)
    expected = [[0, 1, 2, 3]] if suffix == ".obj" else [[0, 1, 2], [0, 2, 3]]
    np.testing.assert_array_equal(faces, expected)


def test_a_surface_file_of_another_format_is_refused_by_name(tmp_path):
    with pytest.raises(MeshFileError, match=r"expected a surface file ending in \.obj, \.ply, "
                                            r"\.glb, got .*seat\.stl"):
        read_surface_mesh(tmp_path / "seat.stl")
