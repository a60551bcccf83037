"""The rasteriser and the pictures' pieces, checked against independent geometry (matplotlib's
point-in-polygon test, its viridis colour map) rather than against themselves."""

import numpy as np
import pytest

from solver.io.raster import (Canvas, RasterError, nice_ticks, rasterize, tick_label, viridis,
                              viridis_table)
from solver.io.render import MeshView, draw_meshes, field_colors


def _pixel_centres(width: int, height: int) -> np.ndarray:
    rows, cols = np.mgrid[0:height, 0:width]
    return np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], axis=1)


def test_a_triangle_covers_the_pixels_whose_centres_it_contains():
    from matplotlib.path import Path

    corners = np.array([[[3.2, 4.1], [41.7, 9.3], [17.4, 33.8]]])
    rgb, covered = rasterize(corners, np.zeros((1, 3)), np.full((1, 3, 3), 0.2), 50, 40)
    inside = Path(corners[0]).contains_points(_pixel_centres(50, 40)).reshape(40, 50)
    # pixels whose centre lies on an edge may go either way: none is that close here
    assert (covered == inside).all()
    assert np.allclose(rgb[covered], 0.2) and np.allclose(rgb[~covered], 1.0)


def test_the_nearest_triangle_wins_whatever_the_order():
    square = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0]])
    corners = np.stack([square, square])
    colors = np.stack([np.full((3, 3), 0.1), np.full((3, 3), 0.9)])
    for order in ([0, 1], [1, 0]):
        depth = np.array([[1.0] * 3, [2.0] * 3])[order]
        rgb, _ = rasterize(corners, depth, colors[order], 20, 20)
        assert np.allclose(rgb[2, 2], 0.9)


def test_corner_colours_blend_barycentrically():
    corners = np.array([[[0.0, 0.0], [60.0, 0.0], [0.0, 60.0]]])
    colors = np.array([[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]])
    rgb, _ = rasterize(corners, np.zeros((1, 3)), colors, 60, 60)
    # the pixel centred at (15.5, 20.5): weights 1 - x/60 - y/60, x/60, y/60
    np.testing.assert_allclose(rgb[20, 15], [1 - 36 / 60, 15.5 / 60, 20.5 / 60], atol=1e-6)


def test_a_rendered_triangle_lands_where_its_projection_says():
    """A triangle seen from the three-quarter view: the pixels drawn are those inside its
    projected corners (matplotlib's test of the polygon), but for its edge."""
    from matplotlib.path import Path

    verts = np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 0.0], [0.3, 1.0, 0.4]])
    tri = np.array([[0, 1, 2]])
    canvas = Canvas.blank(160, 120)
    proj = draw_meshes(canvas, (0, 0, 160, 120), [MeshView(verts, tri, (0.1, 0.2, 0.7),
                                                           back_color=(0.1, 0.2, 0.7))],
                       "three-quarter")
    drawn = np.any(np.asarray(canvas.image) < 250, axis=-1)
    corners = proj.pixels(verts)
    inside = Path(corners).contains_points(_pixel_centres(160, 120)).reshape(120, 160)
    near_edge = Path(corners).contains_points(_pixel_centres(160, 120), radius=2.0) != \
        Path(corners).contains_points(_pixel_centres(160, 120), radius=-2.0)
    assert inside.sum() > 3000
    assert (drawn == inside)[~near_edge.reshape(120, 160)].all()


def test_rasterize_refuses_mismatched_shapes():
    with pytest.raises(RasterError, match="Expected corners"):
        rasterize(np.zeros((2, 3, 2)), np.zeros((2, 3)), np.zeros((1, 3, 3)), 10, 10)


def test_the_viridis_table_is_matplotlibs():
    from matplotlib import colormaps

    values = np.linspace(-0.2, 1.2, 1001)
    np.testing.assert_allclose(viridis(values), colormaps["viridis"](np.clip(values, 0, 1))[:, :3])
    np.testing.assert_allclose(field_colors(values * 5, 0, 5),
                               colormaps["viridis"](np.clip(values, 0, 1))[:, :3])
    assert viridis_table().shape == (256, 3)


@pytest.mark.parametrize("low, high, expected", [
    (0.0, 12.8, [0, 2.5, 5, 7.5, 10, 12.5]), (-21.0, 36.0, [-20, -10, 0, 10, 20, 30]),
    (0.0, 1.0, [0, 0.2, 0.4, 0.6, 0.8, 1.0])])
def test_nice_ticks(low, high, expected):
    np.testing.assert_allclose(nice_ticks(low, high), expected)


def test_tick_labels_carry_the_decimals_their_step_needs():
    assert [tick_label(v, 2.5) for v in (0.0, 2.5, 10.0)] == ["0.0", "2.5", "10.0"]
    assert tick_label(-0.0, 10.0) == "0" and tick_label(400.0, 200.0) == "400"
