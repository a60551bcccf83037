"""A review of what the mesh writers accept: normals and colours that would put NaN or
dangling references into a file are refused before anything is written (read back by trimesh
and by the text itself), and report.json's figures for a refused plinth."""

import numpy as np
import pytest

from solver.io.export import ExportError, frame_matrix, write_mesh


@pytest.fixture
def square():
    vertices = np.array([[0.0, 0.4, 0.0], [0.5, 0.4, 0.0], [0.5, 0.4, 0.5], [0.0, 0.4, 0.5]])
    faces = np.array([[0, 3, 2, 1]])  # counter-clockwise seen from above: normal +Y
    return vertices, faces


@pytest.mark.parametrize("normals", [
    np.full((4, 3), np.nan),
    np.array([[0.0, 1.0, 0.0]] * 3 + [[np.inf, 0.0, 0.0]]),
    np.array([[0.0, 1.0, 0.0]] * 2),  # fewer than the vertices: faces would name vn 3 and 4
    np.array([[0.0, 1.0]] * 4),
])
def test_obj_normals_that_are_not_finite_or_not_one_a_vertex_are_refused(tmp_path, square,
                                                                        normals):
    vertices, faces = square
    with pytest.raises(ExportError, match=r"Expected finite vertex normals \(4, 3\)"):
        write_mesh(tmp_path / "s.obj", vertices, faces, normals=normals)
    assert not (tmp_path / "s.obj").exists()


def test_obj_normals_turn_with_the_frame_and_read_back(tmp_path, square):
    import trimesh

    vertices, faces = square
    normals = np.tile([0.0, 1.0, 0.0], (4, 1))
    path = write_mesh(tmp_path / "s.obj", vertices, faces, normals=normals, unit="mm", up="z")
    text = path.read_text()
    assert "nan" not in text.lower()
    assert text.count("\nvn ") == 4
    mesh = trimesh.load(path, process=False)
    np.testing.assert_allclose(mesh.vertices, vertices @ frame_matrix("mm", "z").T, atol=1e-6)
    np.testing.assert_allclose(mesh.vertex_normals, np.tile([0.0, 0.0, 1.0], (4, 1)),
                               atol=1e-6)  # Y up became Z up, still unit length


@pytest.mark.parametrize("suffix", [".ply", ".glb"])
def test_colours_that_are_not_finite_are_refused(tmp_path, square, suffix):
    vertices, faces = square
    colors = np.full((4, 3), 0.5)
    colors[2, 1] = np.nan
    with pytest.raises(ExportError, match=r"Expected finite vertex colours \(4, 3\|4\)"):
        write_mesh(tmp_path / f"s{suffix}", vertices, faces, vertex_colors=colors)
    assert not (tmp_path / f"s{suffix}").exists()


def test_a_refused_plinth_reports_no_thickness(tmp_path, square):
    """`--solid 0.02 --plinth`: the plinth replaces the offset, so a refused plinth (here a
    surface under the floor) reports no thickness, as a written plinth does."""
    from solver.scene.workshop import WorkshopOptions, export_workshop

    vertices, faces = square
    vertices = vertices + [0.0, -0.5, 0.0]
    files, fab = export_workshop(tmp_path, vertices, faces, [],
                                 WorkshopOptions(solid_thickness=0.02, plinth=True))
    assert fab["solid"]["kind"] == "plinth" and fab["solid"]["ok"] is False
    assert fab["solid"]["thickness_m"] is None
    assert "above the floor" in fab["solid"]["problem"]
    assert not files
