"""The design sheet's pieces: two-sided drawing, square-on elevations with their dimensions, and
the sheet itself."""

import numpy as np
import pytest

from solver.io.drawing import DrawingError, draw_elevation, overall_dimensions, section
from solver.io.raster import Canvas
from solver.io.render import MeshView, Panel, draw_meshes, render_png
from solver.io.sheet import render_sheet


BOX = (10, 30, 190, 190)  # a drawing's place on a 200 x 200 canvas


def _canvas() -> Canvas:
    return Canvas.blank(200, 200)


def _coloured_pixels(path) -> int:
    from PIL import Image

    with Image.open(path) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=float) / 255
    return int(np.sum(np.any(np.abs(rgb - 1.0) > 0.05, axis=-1)))


QUAD = (np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1.0]]), np.array([[0, 3, 2, 1]]))


def test_a_face_turned_away_shows_only_with_a_back_colour(tmp_path):
    """One quad facing +y seen from below: culled, unless its back is coloured."""
    verts, quad = QUAD
    culled = render_png(tmp_path / "culled.png", [MeshView(verts, quad, (0.2, 0.3, 0.8))],
                        view="below", size=(120, 120))
    shown = render_png(tmp_path / "shown.png", [MeshView(verts, quad, (0.2, 0.3, 0.8),
                                                         back_color=(0.8, 0.2, 0.2))],
                       view="below", size=(120, 120))
    assert _coloured_pixels(culled) == 0
    assert _coloured_pixels(shown) > 1000


def test_elevations_write_the_overall_dimensions_of_a_tilted_sheet():
    """A 0.6 x 0.4 sheet, its far edge 0.3 m higher, 0.45 m up: each square-on view writes the
    two extents it shows, in mm, and they are `overall_dimensions`' (checked by hand too)."""
    verts = np.array([[-0.3, 0.45, 0.2], [0.3, 0.45, 0.2], [0.3, 0.75, -0.2],
                      [-0.3, 0.75, -0.2]])
    quad = np.array([[0, 1, 2, 3]])
    expected = {"width_mm": 600.0, "depth_mm": 400.0, "height_mm": 750.0}
    assert overall_dimensions(verts) == pytest.approx(expected)
    for view, shown in (("front", ("600", "750")), ("side", ("400", "750")),
                        ("top", ("600", "400"))):
        canvas = _canvas()
        assert draw_elevation(canvas, BOX, verts, quad, view) == pytest.approx(expected)
        title, *texts = canvas.texts  # the title names both too
        assert sorted(texts) == sorted(shown), (view, texts)
        assert all(f" {t}" in title for t in shown), title


def test_an_unknown_elevation_is_refused():
    with pytest.raises(DrawingError, match="Expected a view from"):
        draw_elevation(_canvas(), BOX, *QUAD, "below")


def test_draw_meshes_fits_the_picture_to_its_box_with_five_per_cent_around():
    """A 2 x 2 quad seen from above in a 180 x 160 box: its 2 m (and 10 % more) take the box's
    160 pixels, centred in it."""
    verts, quad = QUAD
    canvas = _canvas()
    proj = draw_meshes(canvas, BOX, [MeshView(verts * 2.0, quad, back_color=(0.5, 0.5, 0.5))],
                       (0, 1, 0))
    corners = proj.pixels(verts * 2.0)
    np.testing.assert_allclose(np.ptp(corners, axis=0), [160 / 1.1, 160 / 1.1])
    np.testing.assert_allclose(corners.mean(axis=0), [100, 110])
    drawn = np.asarray(canvas.image)[..., 0] < 250
    assert drawn[110, 100] and not drawn[110, 20] and not drawn[35, 100]


def test_a_sheet_has_a_row_of_views_then_the_sections_and_pressures_three_a_row(tmp_path):
    verts, quad = QUAD
    verts = verts + [0.0, 0.4, 0.0]
    sec = section("one", [0.5, 0.4, 0.5], [0, 0, 1], {"SURFACE": (verts, quad)})
    body = MeshView(np.array([[0, 0.5, 0], [1, 0.5, 0], [0, 0.5, 1.0]]), np.array([[0, 2, 1]]))
    path = render_sheet(tmp_path / "sheet.png", verts, quad, [sec, sec, sec],
                        [Panel([body], (0, -1, 0), "pressed")], title="test",
                        notes=["a note"], problems=["a problem", "another"],
                        colorbar=("kPa", 0.0, 1.0))
    from PIL import Image

    with Image.open(path) as im:
        width, height = im.size
    assert width == 1500  # three panels of 5 inches at 100 dpi
    with Image.open(render_sheet(tmp_path / "short.png", verts, quad, [sec], [],
                                 title="test")) as im:
        one_row = im.size[1]
    # four panels take two rows under the views, one panel one: 3.7 inches, and three more
    # lines of notes and problems (0.2 inches each)
    assert height - one_row == 370 + 60
    with pytest.raises(DrawingError, match="at least 3 columns"):
        render_sheet(tmp_path / "x.png", verts, quad, [], [], title="t", columns=2)
