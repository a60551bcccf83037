"""Pictures drawn on numpy and Pillow, without matplotlib: a z-buffer rasteriser of triangle
meshes, and what the figures around them need (text in DejaVu Sans, lines, arrows, axes with
ticks, colour bars, the viridis colour map).

The rasteriser takes triangles already projected to pixels (x to the right, y down, pixel
centres at half-integers) with a depth each corner (larger is nearer) and a colour each corner:
every pixel whose centre falls inside a triangle (its edges included) takes the nearest
triangle's colour there, interpolated between its corners. It works on all the triangles at once
(each triangle's pixel box expanded into candidate pixels), in chunks that bound the memory.
Pictures are drawn at twice their size and averaged down, which smooths the edges.

Sizes are pixels; `points(pt)` turns a font size in points into pixels at the 100 dots per inch
the pictures have always had.
"""

from __future__ import annotations

import functools
import io
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

DPI = 100
MAX_CANDIDATES = 32_768  # pixel candidates in one rasterising chunk (arrays small enough to
# be reused from the heap and to stay in cache, rather than mapped afresh for each picture)
BAD_COLOR = (0.93, 0.93, 0.93)  # a map's cell where nothing presses
COLORBAR_WIDTH = 110  # pixels a colour bar and its labels take on the right


class RasterError(ValueError):
    """A picture that cannot be drawn as asked."""


def points(pt: float) -> int:
    """A font size in points as pixels at `DPI`."""
    return max(1, round(pt * DPI / 72))


@functools.lru_cache(maxsize=1)
def viridis_table() -> np.ndarray:
    """(256, 3) float, the viridis colour map (solver/data/viridis.npy, `make_viridis.py`)."""
    return np.load(Path(__file__).resolve().parents[1] / "data" / "viridis.npy")


def viridis(values: np.ndarray, low: float = 0.0, high: float = 1.0) -> np.ndarray:
    """(..., 3) RGB in [0, 1] of values scaled from [low, high] (clipped) on viridis."""
    t = np.clip((np.asarray(values, dtype=float) - low) / max(high - low, 1e-300), 0, 1)
    t = np.nan_to_num(t, nan=0.0)
    return viridis_table()[np.minimum((t * 256).astype(np.int64), 255)]


def rasterize(corners: np.ndarray, depth: np.ndarray, colors: np.ndarray, width: int,
              height: int, background: Sequence[float] = (1.0, 1.0, 1.0)
              ) -> tuple[np.ndarray, np.ndarray]:
    """Draws triangles with a z-buffer.

    Parameters
    ----------
    corners : (T, 3, 2) float
        The triangles' corners in pixels: x to the right, y down; pixel (i, j) has its centre at
        (j + 0.5, i + 0.5).
    depth : (T, 3) float
        Each corner's depth, larger nearer the camera.
    colors : (T, 3, 3) float
        Each corner's RGB in [0, 1]; a pixel takes the barycentric mix.
    width, height : int
        The picture's size, pixels.
    background : (3,) float
        RGB where no triangle is.

    Returns
    -------
    rgb : (height, width, 3) float
    covered : (height, width) bool, where a triangle was drawn.
    """
    corners = np.asarray(corners, dtype=np.float64)
    depth = np.asarray(depth, dtype=np.float64)
    colors = np.asarray(colors, dtype=np.float64)
    if corners.ndim != 3 or corners.shape[1:] != (3, 2) or depth.shape != corners.shape[:2] \
            or colors.shape != corners.shape[:2] + (3,):
        raise RasterError(f"Expected corners (T, 3, 2), depth (T, 3) and colours (T, 3, 3), "
                          f"got {corners.shape}, {depth.shape} and {colors.shape}")
    rgb = np.empty((height * width, 3))
    rgb[:] = background
    zbuf = np.full(height * width, -np.inf)
    x, y = corners[..., 0], corners[..., 1]
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (y[:, 1] - y[:, 0]) * (x[:, 2] - x[:, 0])
    # the columns and rows whose centres lie in each triangle's box
    j0 = np.maximum(np.ceil(np.minimum(np.minimum(x[:, 0], x[:, 1]), x[:, 2]) - 0.5), 0)
    j1 = np.minimum(np.floor(np.maximum(np.maximum(x[:, 0], x[:, 1]), x[:, 2]) - 0.5), width - 1)
    i0 = np.maximum(np.ceil(np.minimum(np.minimum(y[:, 0], y[:, 1]), y[:, 2]) - 0.5), 0)
    i1 = np.minimum(np.floor(np.maximum(np.maximum(y[:, 0], y[:, 1]), y[:, 2]) - 0.5), height - 1)
    nx = np.maximum(j1 - j0 + 1, 0).astype(np.int64)
    ny = np.maximum(i1 - i0 + 1, 0).astype(np.int64)
    flat = np.abs(area) <= 1e-12
    count = np.where(flat, 0, nx * ny)
    safe = np.where(flat, 1.0, area)[:, None]
    # barycentric weight k is linear in the pixel, from the edge opposite corner k (p to q) over
    # the triangle's doubled signed area: its value at the centre of the box's first pixel, and
    # its steps one column right and one row down (offsets from the box: no cancellation)
    px, py = x[:, [1, 2, 0]], y[:, [1, 2, 0]]
    dx, dy = x[:, [2, 0, 1]] - px, y[:, [2, 0, 1]] - py
    first = (dy * (px - (j0 + 0.5)[:, None]) - dx * (py - (i0 + 0.5)[:, None])) / safe
    step_x, step_y = -dy / safe, dx / safe
    # depth and colour likewise: the weights' blend of the corners'
    z_first, z_x, z_y = (np.einsum("tk,tk->t", w, depth) for w in (first, step_x, step_y))
    c_first, c_x, c_y = (np.einsum("tk,tkc->ct", w, colors) for w in (first, step_x, step_y))
    # one contiguous row per weight (per channel): the candidates gather them with `take`
    first, step_x, step_y = (np.ascontiguousarray(w.T) for w in (first, step_x, step_y))
    c_first, c_x, c_y = (np.ascontiguousarray(c) for c in (c_first, c_x, c_y))
    corner = (i0 * width + j0).astype(np.int64)  # the box's first pixel
    start, live = 0, np.flatnonzero(count)
    while start < len(live):
        total = np.cumsum(count[live[start:]])
        stop = start + max(1, int(np.searchsorted(total, MAX_CANDIDATES, side="right")))
        tris = live[start:stop]
        # each box's rows, then each row's pixels: a row's weights stepped along it
        rows = ny.take(tris)
        row_tri = np.repeat(tris, rows)
        down = np.arange(len(row_tri)) - np.repeat(np.cumsum(rows) - rows, rows)
        cols = nx.take(row_tri)
        across = np.arange(int(cols.sum())) - np.repeat(np.cumsum(cols) - cols, cols)
        steps = across.astype(np.float32)
        inside = np.ones(len(across), dtype=bool)
        for k in range(3):
            w_row = (first[k].take(row_tri) + step_y[k].take(row_tri) * down).astype(np.float32)
            w = np.repeat(w_row, cols)
            w += np.repeat(step_x[k].take(row_tri).astype(np.float32), cols) * steps
            inside &= w >= -1e-6
        hit = np.flatnonzero(inside)
        row = np.repeat(np.arange(len(row_tri)), cols).take(hit)
        tri, down, across = row_tri.take(row), down.take(row), across.take(hit)
        key = corner.take(tri) + down * width + across
        z = z_first.take(tri) + z_y.take(tri) * down + z_x.take(tri) * across
        np.maximum.at(zbuf, key, z)
        near = np.flatnonzero(z >= zbuf.take(key))
        tri, down, across, key = tri.take(near), down.take(near), across.take(near), key.take(near)
        for c in range(3):
            rgb[key, c] = c_first[c].take(tri) + c_y[c].take(tri) * down + c_x[c].take(tri) * across
        start = stop
    return rgb.reshape(height, width, 3), np.isfinite(zbuf).reshape(height, width)


@dataclass(frozen=True)
class Projection:
    """An orthographic camera fitted to a picture: scene point p lands at pixel
    (offset_x + scale * p.right, offset_y - scale * p.up)."""

    right: np.ndarray
    up: np.ndarray
    back: np.ndarray
    scale: float
    offset: tuple[float, float]

    def pixels(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) pixel coordinates (x, y down) of scene points (..., 3)."""
        p = np.asarray(points, dtype=np.float64)
        return np.stack([self.offset[0] + self.scale * (p @ self.right),
                         self.offset[1] - self.scale * (p @ self.up)], axis=-1)

    def plane(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) pixel coordinates of points given in the picture plane (right, up)."""
        xy = np.asarray(xy, dtype=np.float64)
        return np.stack([self.offset[0] + self.scale * xy[..., 0],
                         self.offset[1] - self.scale * xy[..., 1]], axis=-1)


def fit_projection(right, up, back, lo, hi, width: int, height: int,
                   pad: float = 0.05) -> Projection:
    """The projection that shows the picture-plane box [lo, hi] (2,) centred in width x height
    pixels, equal scale both ways, with `pad` of its larger side around it."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    size = np.maximum(hi - lo, 1e-12)
    margin = pad * size.max()
    scale = min(width / (size[0] + 2 * margin), height / (size[1] + 2 * margin))
    mid = (lo + hi) / 2
    return Projection(right, up, back, float(scale),
                      (width / 2 - scale * mid[0], height / 2 + scale * mid[1]))


@dataclass
class Canvas:
    """A picture being drawn: a Pillow RGB image, and every text written on it (in order), so
    that what a picture says can be read back."""

    image: object
    texts: list = field(default_factory=list)

    @classmethod
    def blank(cls, width: int, height: int) -> "Canvas":
        from PIL import Image

        return cls(Image.new("RGB", (int(width), int(height)), "white"))

    @functools.cached_property
    def draw(self):
        from PIL import ImageDraw

        return ImageDraw.Draw(self.image)

    def paste(self, rgb: np.ndarray, x: int, y: int) -> None:
        """Puts an (h, w, 3) float picture with its top left corner at (x, y)."""
        from PIL import Image

        self.image.paste(Image.fromarray(to_bytes(rgb)), (int(round(x)), int(round(y))))

    def text(self, xy, text: str, size: float = 10, anchor: str = "la", color=(0, 0, 0),
             bold: bool = False, rotate: bool = False, spacing: float = 0.2) -> tuple:
        """Writes text (lines split at line breaks) at xy with a Pillow anchor ("la": left
        ascender, "mm": middle, ...), `size` in points; `rotate` turns it a quarter to read
        upwards, anchored at its middle. Returns its box (left, top, right, bottom)."""
        self.texts.append(text)
        font = _font(points(size), bold)
        fill = _rgb8(color)
        gap = int(points(size) * spacing)
        if not rotate:
            box = self.draw.multiline_textbbox(xy, text, font=font, anchor=anchor,
                                               spacing=gap, align=_align(anchor))
            self.draw.multiline_text(xy, text, font=font, fill=fill, anchor=anchor,
                                     spacing=gap, align=_align(anchor))
            return box
        from PIL import Image, ImageDraw

        left, top, right, bottom = self.draw.multiline_textbbox((0, 0), text, font=font,
                                                                spacing=gap)
        label = Image.new("L", (right - left + 2, bottom - top + 2), 0)
        ImageDraw.Draw(label).multiline_text((1 - left, 1 - top), text, font=font, fill=255,
                                             spacing=gap)
        label = label.rotate(90, expand=True)
        x, y = int(xy[0] - label.width / 2), int(xy[1] - label.height / 2)
        self.image.paste(Image.new("RGB", label.size, fill), (x, y), label)
        return x, y, x + label.width, y + label.height

    def line(self, points_xy, color=(0, 0, 0), width: float = 1.0) -> None:
        """A polyline through (K, 2) pixel points, `width` in points."""
        pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
        if len(pts) > 1:  # Pillow takes the points as one flat list x0, y0, x1, y1, ...
            self.draw.line(pts.ravel().tolist(), fill=_rgb8(color),
                           width=max(1, round(width * DPI / 72)), joint="curve")

    def arrow(self, p1, p2, color=(0.15, 0.15, 0.15), width: float = 0.8,
              head: float = 7.0) -> None:
        """A line from p1 to p2 with a filled arrow head at both ends (`head` pixels long)."""
        p1, p2 = np.asarray(p1, dtype=float), np.asarray(p2, dtype=float)
        self.line([p1, p2], color, width)
        d = p2 - p1
        d /= max(np.linalg.norm(d), 1e-9)
        n = np.array([-d[1], d[0]])
        for tip, back in ((p1, d), (p2, -d)):
            base = tip + back * head
            self.draw.polygon([tuple(tip), tuple(base + n * head * 0.35),
                               tuple(base - n * head * 0.35)], fill=_rgb8(color))

    def rectangle(self, box, outline=None, fill=None, width: float = 0.8) -> None:
        self.draw.rectangle([float(v) for v in box], outline=None if outline is None else
                            _rgb8(outline), fill=None if fill is None else _rgb8(fill),
                            width=max(1, round(width * DPI / 72)))

    def save(self, path: str | os.PathLike) -> Path:
        """Writes the picture as PNG (`png_bytes`), atomically; returns the path."""
        from capture.files import write_atomic

        if self.image.mode == "RGB":
            data = png_bytes(np.asarray(self.image))
        else:
            buf = io.BytesIO()
            self.image.save(buf, format="PNG", compress_level=1)
            data = buf.getvalue()
        write_atomic(Path(path), data)
        return Path(path)


def png_bytes(rgb: np.ndarray) -> bytes:
    """A PNG file of an (h, w, 3) uint8 picture: 8-bit RGB, its rows unfiltered and deflated
    at zlib's fastest level. The pictures are flat colour and white, which deflate compresses
    about as well without a row filter as with one (within a few per cent either way); choosing
    a filter per row, as Pillow's encoder does, takes three times as long."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or not rgb.size:
        raise RasterError(f"Expected an (h, w, 3) picture, got {rgb.shape}")
    height, width = rgb.shape[:2]
    rows = np.zeros((height, 1 + 3 * width), dtype=np.uint8)  # each row: filter type 0, pixels
    rows[:, 1:] = rgb.reshape(height, 3 * width)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body)))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB, not interlaced
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(rows.tobytes(), 1)) + chunk(b"IEND", b""))


def to_bytes(rgb: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 of a float picture in [0, 1]."""
    return (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)


def _rgb8(color) -> tuple:
    if isinstance(color, str):
        return color
    return tuple(int(round(255 * float(c))) for c in color)


def _align(anchor: str) -> str:
    return {"l": "left", "m": "center", "r": "right"}[anchor[0]]


@functools.lru_cache(maxsize=32)
def _font(size: int, bold: bool):
    """DejaVu Sans (matplotlib's, the face of the pictures until now), else Pillow's own."""
    from importlib.util import find_spec

    from PIL import ImageFont

    spec = find_spec("matplotlib")  # finding the package does not import it
    if spec is not None and spec.submodule_search_locations:
        name = "DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf"
        path = Path(list(spec.submodule_search_locations)[0]) / "mpl-data" / "fonts" / "ttf" \
            / name
        if path.exists():
            return ImageFont.truetype(str(path), size)
    return ImageFont.load_default(size)


def nice_ticks(low: float, high: float, most: int = 7) -> np.ndarray:
    """Round values (1, 2, 2.5 or 5 times a power of ten apart) inside [low, high], at most
    `most` of them and as many as that allows."""
    lo, hi = min(low, high), max(low, high)
    if not hi > lo:
        return np.array([lo])
    raw = (hi - lo) / max(most - 1, 1)
    power = 10.0 ** np.floor(np.log10(raw))
    step = next(power * m for m in (1, 2, 2.5, 5, 10) if power * m >= raw * (1 - 1e-9))
    first = np.ceil(lo / step - 1e-9) * step
    ticks = np.arange(first, hi + step * 1e-9, step)
    return np.round(ticks / step) * step


def tick_label(value: float, step: float) -> str:
    """A tick's text: as many decimals as the step needs, no "-0"."""
    decimals = max(0, -int(np.floor(np.log10(step) + 1e-9))) if step > 0 else 0
    if step > 0 and abs(step * 10 ** decimals - round(step * 10 ** decimals)) > 1e-6:
        decimals += 1  # 2.5, 0.25
    text = f"{value:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


@dataclass(frozen=True)
class Axes:
    """A plot's frame on a canvas: its pixel box (left, top, right, bottom) and the data
    ranges it shows (x left to right; y bottom to top, or top to bottom when `y_down`)."""

    box: tuple[float, float, float, float]
    xlim: tuple[float, float]
    ylim: tuple[float, float]
    y_down: bool = False

    def pixels(self, x, y) -> np.ndarray:
        """(..., 2) pixel coordinates of data points."""
        left, top, right, bottom = self.box
        fx = (np.asarray(x, dtype=float) - self.xlim[0]) / (self.xlim[1] - self.xlim[0])
        fy = (np.asarray(y, dtype=float) - self.ylim[0]) / (self.ylim[1] - self.ylim[0])
        py = top + fy * (bottom - top) if self.y_down else bottom - fy * (bottom - top)
        return np.stack(np.broadcast_arrays(left + fx * (right - left), py), axis=-1)


def equal_axes(box, xlim, ylim, y_down: bool = False) -> Axes:
    """An `Axes` inside `box` with one scale both ways: the data ranges widened to fill it,
    about their middles."""
    left, top, right, bottom = box
    w, h = right - left, bottom - top
    dx, dy = xlim[1] - xlim[0], ylim[1] - ylim[0]
    scale = min(w / max(dx, 1e-12), h / max(dy, 1e-12))
    mx, my = (xlim[0] + xlim[1]) / 2, (ylim[0] + ylim[1]) / 2
    return Axes(box, (mx - w / scale / 2, mx + w / scale / 2),
                (my - h / scale / 2, my + h / scale / 2), y_down)


def draw_frame(canvas: Canvas, axes: Axes, xlabel: str = "", ylabel: str = "",
               tick_size: float = 7, label_size: float = 8) -> None:
    """The axes' frame, ticks with their values on the left and bottom, and the labels."""
    left, top, right, bottom = axes.box
    canvas.rectangle(axes.box, outline=(0, 0, 0), width=0.8)
    shown = []  # the y ticks' values, whose width places the y label
    for k, lim in enumerate((axes.xlim, axes.ylim)):
        # as many ticks as leave room for their values (about 40 px across, 30 up)
        room = (right - left) / 40 if k == 0 else (bottom - top) / 30
        ticks = nice_ticks(*lim, most=int(np.clip(room, 4, 7 if k == 0 else 8)))
        step = ticks[1] - ticks[0] if len(ticks) > 1 else 1.0
        for value in ticks:
            text = tick_label(value, step)
            if k == 0:
                x = axes.pixels(value, axes.ylim[0])[0]
                canvas.line([(x, bottom), (x, bottom + 4)])
                canvas.text((x, bottom + 6), text, tick_size, "ma")
            else:
                y = axes.pixels(axes.xlim[0], value)[1]
                canvas.line([(left - 4, y), (left, y)])
                canvas.text((left - 6, y), text, tick_size, "rm")
                shown.append(text)
    if xlabel:
        canvas.text(((left + right) / 2, bottom + 8 + points(tick_size) + 4), xlabel,
                    label_size, "ma")
    if ylabel:
        width = max((_font(points(tick_size), False).getlength(text) for text in shown),
                    default=0)
        canvas.text((left - 10 - width - points(label_size) * 0.7, (top + bottom) / 2),
                    ylabel, label_size, rotate=True)


def draw_colorbar(canvas: Canvas, box, low: float, high: float, label: str = "",
                  tick_size: float = 9, label_size: float = 10) -> None:
    """A vertical viridis colour bar in the pixel box (left, top, right, bottom), `low` at the
    bottom and `high` at the top, ticks on its right and the label beside them."""
    left, top, right, bottom = (int(round(v)) for v in box)
    h, w = max(bottom - top, 1), max(right - left, 1)
    values = np.linspace(high, low, h)[:, None] * np.ones((1, w))
    canvas.paste(viridis(values, low, high), left, top)
    canvas.rectangle((left, top, right, bottom), outline=(0, 0, 0), width=0.6)
    axis = Axes((left, top, right, bottom), (0.0, 1.0), (low, high if high > low else low + 1))
    ticks = nice_ticks(*axis.ylim, most=7)
    step = ticks[1] - ticks[0] if len(ticks) > 1 else 1.0
    widest = 0.0
    for value in ticks:
        y = axis.pixels(0.0, value)[1]
        canvas.line([(right, y), (right + 4, y)])
        text = tick_label(value, step)
        canvas.text((right + 6, y), text, tick_size, "lm")
        widest = max(widest, _font(points(tick_size), False).getlength(text))
    if label:
        canvas.text((right + 10 + widest + points(label_size) * 0.7, (top + bottom) / 2),
                    label, label_size, rotate=True)


def wrap(text: str, width_px: float, size: float) -> str:
    """Text broken into lines no wider than `width_px` at `size` points (at spaces)."""
    font = _font(points(size), False)
    lines = []
    for paragraph in text.split("\n"):
        line = ""
        for word in paragraph.split(" "):
            trial = f"{line} {word}" if line else word
            if line and font.getlength(trial) > width_px:
                lines.append(line)
                line = word
            else:
                line = trial
        lines.append(line)
    return "\n".join(lines)


def text_height(text: str, size: float, spacing: float = 0.2) -> int:
    """Pixels taken by lines of text at `size` points (as `Canvas.text` writes them)."""
    lines = text.count("\n") + 1
    return int(lines * points(size) * 1.17 + (lines - 1) * int(points(size) * spacing))
