"""The design sheet's pieces: two-sided drawing, square-on elevations with their dimensions, and
the sheet itself."""

import numpy as np
import pytest

from solver.io.drawing import DrawingError, draw_elevation, overall_dimensions, section
from solver.io.render import MeshView, Panel, draw_meshes, render_png
from solver.io.sheet import render_sheet


def _figure():
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 4), dpi=50)
    FigureCanvasAgg(fig)
    return fig


def _coloured_pixels(path) -> int:
    import matplotlib.image as mpimg

    rgb = mpimg.imread(path)[..., :3]
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
        ax = _figure().add_subplot()
        assert draw_elevation(ax, verts, quad, view) == pytest.approx(expected)
        texts = [t.get_text() for t in ax.texts if t.get_text()]  # arrows have none
        assert sorted(texts) == sorted(shown), (view, texts)


def test_an_unknown_elevation_is_refused():
    with pytest.raises(DrawingError, match="Expected a view from"):
        draw_elevation(_figure().add_subplot(), *QUAD, "below")


def test_draw_meshes_fits_the_axes_to_the_picture():
    verts, quad = QUAD
    ax = _figure().add_subplot()
    draw_meshes(ax, [MeshView(verts * 2.0, quad, back_color=(0.5, 0.5, 0.5))], (0, 1, 0))
    lo, hi = ax.get_xlim()
    assert lo < 0.0 and 2.0 < hi < 2.5


def test_a_sheet_has_a_row_of_views_then_the_sections_and_pressures_three_a_row(tmp_path):
    verts, quad = QUAD
    verts = verts + [0.0, 0.4, 0.0]
    sec = section("one", [0.5, 0.4, 0.5], [0, 0, 1], {"SURFACE": (verts, quad)})
    body = MeshView(np.array([[0, 0.5, 0], [1, 0.5, 0], [0, 0.5, 1.0]]), np.array([[0, 2, 1]]))
    path = render_sheet(tmp_path / "sheet.png", verts, quad, [sec, sec, sec],
                        [Panel([body], (0, -1, 0), "pressed")], title="test",
                        notes=["a note"], problems=["a problem", "another"],
                        colorbar=("kPa", 0.0, 1.0))
    import matplotlib.image as mpimg

    height, width = mpimg.imread(path).shape[:2]
    assert width == 1500  # three panels of 5 inches at 100 dpi
    one_row = mpimg.imread(render_sheet(tmp_path / "short.png", verts, quad, [sec], [],
                                        title="test")).shape[0]
    # four panels take two rows under the views, one panel one: 3.7 inches, and three more
    # lines of notes and problems (0.2 inches each)
    assert height - one_row == 370 + 60
    with pytest.raises(DrawingError, match="at least 3 columns"):
        render_sheet(tmp_path / "x.png", verts, quad, [], [], title="t", columns=2)
