"""Mesh writers: every file read back by trimesh (an independent reader) gives the geometry,
faces and colours written, in the unit and up axis asked for."""

import numpy as np
import pytest

from solver.io.export import ExportError, write_mesh


@pytest.fixture
def quads():
    rng = np.random.default_rng(3)
    verts = rng.normal(size=(30, 3))
    every = np.arange(32).reshape(8, 4) % 30  # each vertex used (readers drop unused ones)
    faces = np.concatenate([every, [rng.choice(30, 4, replace=False) for _ in range(12)]])
    colors = rng.uniform(size=(30, 3))
    return verts, faces, colors


def _triangles(faces):
    return np.concatenate([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]])


@pytest.mark.parametrize("suffix", [".ply", ".glb"])
def test_binary_meshes_read_back_with_trimesh(tmp_path, quads, suffix):
    import trimesh

    verts, faces, colors = quads
    path = write_mesh(tmp_path / f"m{suffix}", verts, faces, vertex_colors=colors)
    mesh = trimesh.load(path, process=False, force="mesh")
    np.testing.assert_allclose(mesh.vertices, verts, atol=1e-6)  # float32
    np.testing.assert_array_equal(mesh.faces, _triangles(faces))
    np.testing.assert_array_equal(mesh.visual.vertex_colors[:, :3],
                                  (colors * 255).astype(np.uint8))


def test_ply_states_its_frame_and_turns_to_z_up_in_millimetres(tmp_path, quads):
    import trimesh

    verts, faces, _ = quads
    path = write_mesh(tmp_path / "m.ply", verts, faces, unit="mm", up="z")
    assert b"comment units: mm; up: +Z" in path.read_bytes()[:400]
    mesh = trimesh.load(path, process=False)
    expected = 1000 * np.stack([verts[:, 0], -verts[:, 2], verts[:, 1]], axis=1)
    np.testing.assert_allclose(mesh.vertices, expected, rtol=1e-6, atol=1e-3)


def test_glb_is_valid_gltf_with_its_statement(tmp_path, quads):
    import json
    import struct

    verts, faces, _ = quads
    data = write_mesh(tmp_path / "m.glb", verts, faces).read_bytes()
    magic, version, total = struct.unpack("<4sII", data[:12])
    assert (magic, version, total) == (b"glTF", 2, len(data))
    length, kind = struct.unpack("<I4s", data[12:20])
    assert kind == b"JSON" and length % 4 == 0
    gltf = json.loads(data[20:20 + length])
    assert gltf["asset"]["extras"]["sitrelax"].startswith("units: m; up: +Y")
    assert gltf["accessors"][1]["count"] == len(verts)


def test_obj_keeps_quads_and_reads_back(tmp_path, quads):
    import trimesh

    verts, faces, _ = quads
    path = write_mesh(tmp_path / "m.obj", verts, faces)
    text = path.read_text()
    assert text.count("\nf ") == len(faces) and text.split("\nf ")[1].count(" ") == 3
    mesh = trimesh.load(path, process=False)
    np.testing.assert_allclose(mesh.vertices, verts, atol=1e-6)


def test_colours_of_the_wrong_count_are_refused(tmp_path, quads):
    verts, faces, colors = quads
    with pytest.raises(ExportError, match="vertex colours"):
        write_mesh(tmp_path / "m.ply", verts, faces, vertex_colors=colors[:5])
