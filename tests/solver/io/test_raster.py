"""The rasteriser and the pictures' pieces, checked against independent geometry (matplotlib's
point-in-polygon test, its viridis colour map) rather than against themselves."""

import numpy as np
import pytest

from solver.io.raster import (Canvas, RasterError, nice_ticks, png_bytes, rasterize, tick_label,
                              viridis, viridis_table)
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


def test_many_triangles_match_a_pixel_by_pixel_z_buffer(monkeypatch):
    """Overlapping triangles of every size, each pixel judged against every triangle at once
    (float64, no boxes): the same picture wherever no pixel centre lies on an edge or two
    depths tie; and the same again when the candidates are split into many small chunks."""
    import solver.io.raster as raster

    rng = np.random.default_rng(7)
    width, height, count = 64, 48, 120
    centres = rng.uniform([-4, -4], [width + 4, height + 4], (count, 1, 2))
    corners = centres + rng.normal(0, 1, (count, 3, 2)) * rng.uniform(0.5, 12, (count, 1, 1))
    depth = rng.uniform(0, 1, (count, 3))
    colors = rng.uniform(0, 1, (count, 3, 3))
    rgb, covered = rasterize(corners, depth, colors, width, height)

    p = _pixel_centres(width, height)[:, None, :]  # (P, 1, 2) against (T, ...)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]

    def cross(u, v, q):
        return (v[..., 0] - u[..., 0]) * (q[..., 1] - u[..., 1]) - \
            (v[..., 1] - u[..., 1]) * (q[..., 0] - u[..., 0])

    area = cross(a, b, c)
    w = np.stack([cross(b, c, p), cross(c, a, p), cross(a, b, p)], axis=-1) / area[:, None]
    inside = (w >= 0).all(axis=-1)
    z = np.where(inside, np.einsum("ptk,tk->pt", w, depth), -np.inf)
    nearest = np.argmax(z, axis=1)
    expected = np.where(inside.any(axis=1)[:, None],
                        np.einsum("pk,pkc->pc", w[np.arange(len(p)), nearest],
                                  colors[nearest]), 1.0)
    top2 = np.sort(z, axis=1)[:, -2:]
    clear = (np.abs(w).min(axis=-1) > 1e-4).all(axis=1) & \
        ((top2[:, 1] - top2[:, 0] > 1e-6) | ~np.isfinite(top2[:, 1]))
    assert clear.mean() > 0.8 and inside.any(axis=1)[clear].mean() > 0.5
    np.testing.assert_allclose(rgb.reshape(-1, 3)[clear], expected[clear], atol=1e-5)
    assert (covered.ravel() == inside.any(axis=1))[clear].all()

    monkeypatch.setattr(raster, "MAX_CANDIDATES", 50)
    chunked, chunked_covered = rasterize(corners, depth, colors, width, height)
    assert np.array_equal(chunked, rgb) and np.array_equal(chunked_covered, covered)


def test_a_saved_picture_reads_back_pixel_for_pixel(tmp_path):
    import io

    from PIL import Image

    rgb = np.random.default_rng(2).integers(0, 256, (37, 53, 3), dtype=np.uint8)
    read = Image.open(io.BytesIO(png_bytes(rgb)))
    assert read.mode == "RGB" and np.array_equal(np.asarray(read), rgb)
    canvas = Canvas.blank(90, 60)
    canvas.paste(rgb / 255.0, 20, 10)
    canvas.text((5, 5), "kPa", 9)
    path = canvas.save(tmp_path / "picture.png")
    assert np.array_equal(np.asarray(Image.open(path)), np.asarray(canvas.image))
    with pytest.raises(RasterError, match="Expected an"):
        png_bytes(rgb[..., :2])


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
