"""Body layer names in a .3dm that Rhino keeps, read back with rhino3dm."""

import numpy as np
import pytest

rhino3dm = pytest.importorskip("rhino3dm")

from solver.io.export import ExportError  # noqa: E402
from solver.io.rhino import write_3dm  # noqa: E402

QUAD = (np.array([[0.0, 0.4, 0.0], [0.1, 0.4, 0.0], [0.1, 0.4, 0.1], [0.0, 0.4, 0.1]]),
        np.array([[0, 1, 2, 3]]))


@pytest.mark.parametrize("name", ["(guest)", "[A]", "{x}", ")", "]b", "}c", "", " \t "])
def test_a_body_name_rhino_would_rename_is_refused_and_nothing_written(tmp_path, name):
    """rhino3dm named a layer "(guest)" or "" "Layer 03" instead: the body's name was lost."""
    path = tmp_path / "scene.3dm"
    with pytest.raises(ExportError, match="not empty, not beginning with one of"):
        write_3dm(path, *QUAD, None, [QUAD], body_names=[name])
    assert not list(tmp_path.iterdir())


def test_names_with_brackets_inside_keep_their_layer_names(tmp_path):
    names = ["person 1: (guest)", "x(", "a [b] {c}", "#1"]
    path = write_3dm(tmp_path / "scene.3dm", *QUAD, None, [QUAD] * len(names),
                     body_names=names)
    model = rhino3dm.File3dm.Read(str(path))
    assert [layer.Name for layer in model.Layers] == ["control net", "surface", *names]
