"""Headless PNG pictures of meshes and pressure maps (no display, no GPU, no matplotlib):
`solver.io.raster`'s z-buffer on numpy, text and PNG through Pillow.

Meshes are projected orthographically and faces turned away from the camera are culled (or
drawn in a back colour). Each face is shaded flat by the Lambert term of its normal, while its
colour blends between its vertices' when the colour is given per vertex (a pressure field reads
smoothly across the skin). That suffices for bodies and smooth surfaces seen from outside,
which is all the pictures show.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .raster import (BAD_COLOR, COLORBAR_WIDTH, Axes, Canvas, Projection, RasterError,
                     draw_colorbar, draw_frame, fit_projection, rasterize, text_height, viridis,
                     wrap)
from .views import VIEWS  # noqa: F401 (solver.io.render.VIEWS, as before)

SKIN = (0.86, 0.72, 0.62)
SURFACE = (0.55, 0.68, 0.82)


@dataclass
class MeshView:
    """A mesh to draw: vertices (V, 3), faces (F, 3) or (F, 4), and a colour: one RGB, or
    per-face (F, 3) or per-vertex (V, 3) RGB values in [0, 1]. Faces turned away from the
    camera are left out, unless `back_color` (one RGB) is given: then they are drawn in it, so
    a sheet's underside shows wherever it is seen (a fold, an overhang, a curtain)."""

    vertices: np.ndarray
    faces: np.ndarray
    color: Sequence[float] | np.ndarray = SKIN
    edges: bool = False
    back_color: Sequence[float] | None = None


def camera_axes(view: str | Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(3,) unit vectors of a view: the picture's right, its up, and towards the camera. A
    camera looking straight down (or up) has the scene's -z as its up."""
    if isinstance(view, str) and view not in VIEWS:
        raise ValueError(f"Expected a view from {sorted(VIEWS)} or a direction, got {view!r}")
    d = np.asarray(VIEWS[view] if isinstance(view, str) else view, dtype=float)
    back = d / np.linalg.norm(d)  # towards the camera
    up = np.array([0.0, 1.0, 0.0]) if abs(back[1]) < 0.95 else np.array([0.0, 0.0, -1.0])
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    return right, np.cross(back, right), back


def mesh_triangles(meshes: Sequence[MeshView], right: np.ndarray, up: np.ndarray,
                   back: np.ndarray, light: Sequence[float] = (0.4, 0.8, 0.6)):
    """The triangles a camera sees of meshes, shaded (see the module docstring).

    Returns
    -------
    plane : (T, 3, 2) float, corners in the picture plane (right, up), scene units.
    depth : (T, 3) float, towards the camera.
    colors : (T, 3, 3) float, each corner's RGB: its vertex's colour (or the face's), times the
        face's Lambert shade.
    """
    light = np.asarray(light, dtype=float)
    light = light / np.linalg.norm(light)
    camera = np.stack([right, up, back], axis=1)
    planes, depths, colors = [np.zeros((0, 3, 2))], [np.zeros((0, 3))], [np.zeros((0, 3, 3))]
    for mesh in meshes:
        v = np.asarray(mesh.vertices, dtype=float)
        f = np.asarray(mesh.faces, dtype=np.int64)
        if not len(f):
            continue
        corner = [v.take(f[:, k], axis=0) for k in range(f.shape[1])]  # take: a fast gather
        a = corner[0]
        normal = np.cross(corner[1] - a, corner[2] - a)
        if f.shape[1] == 4:
            normal += np.cross(corner[2] - a, corner[3] - a)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        facing = normal @ back > 0
        shade = 0.35 + 0.65 * np.clip(np.abs(normal @ light), 0, 1)
        if mesh.back_color is not None:
            keep = np.arange(len(f))
        else:
            keep = np.flatnonzero(facing)
        kept = f.take(keep, axis=0)
        shade = shade[keep, None, None]
        col = np.asarray(mesh.color, dtype=float)
        per_vertex = col.ndim > 1 and len(col) == len(v) and len(v) != len(f)
        if col.ndim > 1 and not per_vertex:  # per face
            face_col = col[keep, :3]
        elif col.ndim == 1:
            face_col = np.broadcast_to(col[:3], (len(keep), 3))
        if mesh.back_color is not None and not per_vertex:
            face_col = np.where(facing[:, None], face_col,
                                np.asarray(mesh.back_color, dtype=float)[:3])
        seen = v @ camera  # each vertex in the camera's frame: right, up, towards it
        split = [[0, 1, 2]] if f.shape[1] == 3 else [[0, 1, 2], [0, 2, 3]]
        for idx in split:
            tri = kept[:, idx]
            corners = seen.take(tri, axis=0)
            planes.append(corners[..., :2])
            depths.append(corners[..., 2])
            if per_vertex:  # blended across the face
                corner_col = col[:, :3].take(tri, axis=0)
                if mesh.back_color is not None:
                    corner_col = np.where(facing[:, None, None], corner_col,
                                          np.asarray(mesh.back_color, dtype=float)[:3])
            else:
                corner_col = face_col[:, None, :]
            colors.append(np.broadcast_to(np.clip(corner_col * shade, 0, 1), tri.shape + (3,)))
    return np.concatenate(planes), np.concatenate(depths), np.concatenate(colors)


def draw_meshes(canvas: Canvas, box: Sequence[float], meshes: Sequence[MeshView],
                view: str | Sequence[float] = "three-quarter",
                light: Sequence[float] = (0.4, 0.8, 0.6), bounds=None,
                supersample: int = 1) -> Projection | None:
    """Draws meshes into a box of a canvas, orthographic and shaded (see the module docstring),
    fitted to the box with one scale both ways.

    Parameters
    ----------
    canvas : `solver.io.raster.Canvas`
    box : (left, top, right, bottom) pixels.
    meshes : sequence of MeshView
    view : str or (3,) float
        A name from `VIEWS`, or a direction from the scene towards the camera (any length).
        The picture's x is the camera's right, its y the camera's up (`camera_axes`).
    light : (3,) float
        Direction of the light (any length).
    bounds : ((2,), (2,)) float, optional
        The picture-plane box (right, up) to show exactly; by default the visible faces' with
        5 % around.
    supersample : int
        Drawn this many times larger each way, then averaged down (smoother edges).

    Returns
    -------
    The `Projection` from the scene to the canvas's pixels, or None when nothing is seen and
    no bounds are given.
    """
    right, up, back = camera_axes(view)
    plane, depth, colors = mesh_triangles(meshes, right, up, back, light)
    if bounds is None:
        if not len(plane):
            return None
        flat = plane.reshape(-1, 2)
        bounds, pad = (flat.min(axis=0), flat.max(axis=0)), 0.05
    else:
        pad = 0.0
    left, top, right_px, bottom = (int(round(v)) for v in box)
    width, height = max(right_px - left, 1), max(bottom - top, 1)
    s = max(1, int(supersample))
    big = fit_projection(right, up, back, bounds[0], bounds[1], width * s, height * s, pad)
    rgb, covered = rasterize(big.plane(plane), depth, colors, width * s, height * s)
    if s > 1:  # the mean of each s x s block
        blocks = rgb.reshape(height, s, width, s, 3)
        rgb = sum(blocks[:, a, :, b] for a in range(s) for b in range(s)) / (s * s)
    canvas.paste(rgb, left, top)
    return Projection(right, up, back, big.scale / s,
                      (left + big.offset[0] / s, top + big.offset[1] / s))


@dataclass
class Panel:
    """One picture in a grid: meshes seen from a view, with an optional title."""

    meshes: Sequence[MeshView]
    view: str | Sequence[float] = "three-quarter"
    title: str | None = None


def render_panels(path: str | os.PathLike, panels: Sequence[Panel], *, columns: int = 3,
                  panel_size: tuple[int, int] = (400, 500), title: str | None = None,
                  light: Sequence[float] = (0.4, 0.8, 0.6),
                  colorbar: tuple[str, float, float] | None = None) -> Path:
    """Renders a grid of panels into one PNG (each `panel_size` pixels, half an inch more for
    the title) and returns its path.

    Parameters
    ----------
    path : the PNG to write (atomically).
    panels : the panels, row by row.
    columns : panels per row.
    panel_size : (2,) int, width and height of a panel, pixels.
    title : a title over the picture.
    light : (3,) float, direction of the light.
    colorbar : (label, low, high), optional: a viridis colour bar on the right, the scale the
        caller coloured by.
    """
    if not panels:
        raise RasterError("Expected at least one panel to draw, got none")
    rows = -(-len(panels) // columns)
    width, height = panel_size[0] * columns, panel_size[1] * rows + 50
    canvas = Canvas.blank(width, height)
    _mesh_grid(canvas, panels, columns, (0, 50, width, height), light, title, colorbar)
    return canvas.save(path)


def _mesh_grid(canvas: Canvas, panels: Sequence[Panel], columns: int, area, light, title,
               colorbar, title_size: float = 10) -> None:
    """Panels in a grid filling `area` (left, top, right, bottom), the colour bar on its
    right, the title over it all."""
    left, top, right, bottom = area
    if title:
        canvas.text(((left + right) / 2, 12), title, 12, "ma")
    if colorbar is not None:
        label, low, high = colorbar
        right -= COLORBAR_WIDTH
        span = bottom - top
        draw_colorbar(canvas, (right + 12, top + 0.12 * span, right + 30, bottom - 0.12 * span),
                      low, high, label)
    rows = -(-len(panels) // columns)
    cw, ch = (right - left) / columns, (bottom - top) / rows
    for k, panel in enumerate(panels):
        x0, y0 = left + (k % columns) * cw, top + (k // columns) * ch
        y = y0 + 0.02 * ch
        if panel.title:
            text = wrap(panel.title, cw * 0.9, title_size)
            canvas.text((x0 + cw / 2, y), text, title_size, "ma")
            y += text_height(text, title_size) + 6
        draw_meshes(canvas, (x0 + 0.04 * cw, y, x0 + 0.96 * cw, y0 + 0.96 * ch), panel.meshes,
                    panel.view, light)


def field_colors(values: np.ndarray, low: float = 0.0, high: float = 1.0) -> np.ndarray:
    """(N, 3) viridis RGB of values scaled from [low, high]."""
    return viridis(np.asarray(values, dtype=float).ravel(), low, high)


def render_png(path: str | os.PathLike, meshes: Sequence[MeshView], *,
               view: str | Sequence[float] = "three-quarter", size: tuple[int, int] = (800, 800),
               title: str | None = None, light: Sequence[float] = (0.4, 0.8, 0.6),
               colorbar: tuple[str, float, float] | None = None) -> Path:
    """Renders meshes to a PNG file and returns its path.

    Orthographic, back faces culled, Lambert shading (see the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        The PNG file to write.
    meshes : sequence of MeshView
        The meshes to draw: vertices (V, 3), faces (F, 3) or (F, 4), and colours.
    view : str or (3,) float, default "three-quarter"
        A name from `VIEWS`, or a direction from the scene towards the camera (any length).
    size : (2,) int, default (800, 800)
        Picture width and height, pixels.
    title : str, optional
        A title over the picture.
    light : (3,) float, default (0.4, 0.8, 0.6)
        Direction of the light (any length).
    colorbar : (label, low, high), optional
        A colour bar drawn with the viridis scale the caller coloured by.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    canvas = Canvas.blank(*size)
    top = 40 if title else 0
    _mesh_grid(canvas, [Panel(meshes, view)], 1, (0, top, size[0], size[1]), light, title,
               colorbar)
    return canvas.save(path)


@dataclass
class MapPanel:
    """A pressure map to draw: cells (R, C) in kPa, 0 where nothing presses, with their edges
    (R + 1,) and (C + 1,) in metres (row 0 drawn at the top), a title, and whether the edges
    are arc lengths along a draped mat (else plane coordinates). A
    `solver.contact.mat.PressureGrid` has the same fields (its `name` is the title)."""

    pressure_kpa: np.ndarray
    row_edges_m: np.ndarray
    column_edges_m: np.ndarray
    title: str | None = None
    draped: bool = False


def _map_title(m) -> str:
    name = getattr(m, "title", None) or getattr(m, "name", None) or "map"
    p = np.asarray(m.pressure_kpa)
    if not p.size or not (p > 0).any():
        return f"{name}\nno contact"
    text = f"{name}\npeak cell {p.max():.1f} kPa"
    area = getattr(m, "cell_area_m2", None)
    if area is not None:
        text += f", {np.asarray(area)[p > 0].sum() * 1e4:.0f} cm\u00b2 loaded"
    return text


def _draw_map(canvas: Canvas, area, m, high: float, span: tuple[float, float]) -> None:
    """One map in the pixel box `area`: its cells at one centimetre scale shared by all
    panels (`span`, cm: rows, columns), row 0 at the top, ticks in cm, labels."""
    p = np.asarray(m.pressure_kpa, dtype=float)
    if p.size:
        rows, cols = np.asarray(m.row_edges_m) * 100, np.asarray(m.column_edges_m) * 100
        mid_c, mid_r = (cols[0] + cols[-1]) / 2, (rows[0] + rows[-1]) / 2
    else:
        mid_c = mid_r = 0.0
    left, top, right, bottom = area
    # the frame keeps the maps' shape: as large as fits, centred
    scale = min((right - left) / span[1], (bottom - top) / span[0])
    w, h = span[1] * scale, span[0] * scale
    cx, cy = (left + right) / 2, (top + bottom) / 2
    axes = Axes((cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2),
                (mid_c - span[1] / 2, mid_c + span[1] / 2),
                (mid_r - span[0] / 2, mid_r + span[0] / 2), y_down=True)
    if p.size:
        x0, y0 = (int(round(v)) for v in axes.box[:2])
        x1, y1 = (int(round(v)) for v in axes.box[2:])
        xs = axes.xlim[0] + (np.arange(x0, x1) + 0.5 - axes.box[0]) / scale
        ys = axes.ylim[0] + (np.arange(y0, y1) + 0.5 - axes.box[1]) / scale
        ci = np.searchsorted(cols, xs, side="right") - 1
        ri = np.searchsorted(rows, ys, side="right") - 1
        inside = (ri[:, None] >= 0) & (ri[:, None] < p.shape[0]) & (ci[None] >= 0) & \
            (ci[None] < p.shape[1])
        cell = p[np.clip(ri, 0, p.shape[0] - 1)][:, np.clip(ci, 0, p.shape[1] - 1)]
        rgb = np.where((cell > 0)[..., None], viridis(cell, 0.0, high), BAD_COLOR)
        canvas.paste(np.where(inside[..., None], rgb, 1.0), x0, y0)
        corners = axes.pixels(cols[[0, -1]], rows[[0, -1]])
        canvas.rectangle((*corners[0], *corners[1]), outline=(0.6, 0.6, 0.6), width=0.8)
    else:
        canvas.text((cx, cy), "no contact", 10, "mm", color=(0.5, 0.5, 0.5))
    if getattr(m, "draped", False):
        xlabel, ylabel = "across the mat, cm", "along the mat, cm"
    else:
        xlabel = f"{_axis_name(getattr(m, 'column_axis', None), 'column')}, cm"
        ylabel = f"{_axis_name(getattr(m, 'row_axis', None), 'row')}, cm"
    draw_frame(canvas, axes, xlabel, ylabel)


def _axis_name(axis, fallback: str) -> str:
    """"x", "-z", ... for a direction along a world axis, else the fallback."""
    if axis is None or not np.size(axis):
        return fallback
    a = np.asarray(axis, dtype=float)
    k = int(np.argmax(np.abs(a)))
    if abs(a[k]) < 0.99 * np.linalg.norm(a):
        return f"{fallback} axis"
    return ("" if a[k] > 0 else "-") + "xyz"[k]


def render_pressure_maps(path: str | os.PathLike, maps: Sequence, *, columns: int = 3,
                         panel_size: tuple[int, int] | None = None, title: str | None = None,
                         high_kpa: float | None = None) -> Path:
    """Renders pressure maps as a mat's screen shows them, one panel each, into one PNG.

    Parameters
    ----------
    path : str or os.PathLike
        The PNG file to write.
    maps : sequence of MapPanel or PressureGrid
        The maps (one per support: seat, back, floor, ...). Cells at 0 kPa are drawn grey,
        loaded ones on the viridis scale; every panel has the same centimetre scale, so the
        contact areas compare at a glance.
    columns : int, default 3
        Panels per row.
    panel_size : (2,) int, optional
        Width and height of a panel, pixels (default: 380 wide, as high as the maps' common
        extent needs, between 260 and 560).
    title : str, optional
        A title over the picture.
    high_kpa : float, optional
        The top of one colour scale shared by all panels (one colour bar). By default each
        panel has its own scale, from 0 to its largest cell, and its own colour bar, so that
        a seat's few kPa stay readable next to the feet's tens.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    maps = list(maps)
    if not maps:
        raise RasterError("Expected at least one pressure map, got none")
    columns = max(1, min(columns, len(maps)))
    rows = -(-len(maps) // columns)
    span = [1e-2, 1e-2]
    for m in maps:
        if np.size(m.pressure_kpa):
            span[0] = max(span[0], float(np.ptp(m.row_edges_m)) * 100)
            span[1] = max(span[1], float(np.ptp(m.column_edges_m)) * 100)
    if panel_size is None:
        panel_size = (380, int(np.clip(300 * span[0] / span[1] + 110, 260, 560)))
    top = 50 if title else 10
    width, height = panel_size[0] * columns + 100, panel_size[1] * rows + top
    canvas = Canvas.blank(width, height)
    if title:
        canvas.text((width / 2, 12), title, 12, "ma")
    shared = high_kpa is not None
    cw = (width - (COLORBAR_WIDTH if shared else 0)) / columns
    for k, m in enumerate(maps):
        x0, y0 = (k % columns) * cw, top + (k // columns) * panel_size[1]
        peak = float(np.max(m.pressure_kpa)) if np.size(m.pressure_kpa) else 0.0
        high = high_kpa if shared else max(peak, 1e-3)
        heading = _map_title(m)
        canvas.text((x0 + cw / 2, y0 + 6), heading, 10, "ma")
        y_top = y0 + 12 + text_height(heading, 10)
        x_right = x0 + cw - (0 if shared else 85)
        _draw_map(canvas, (x0 + 62, y_top, x_right - 8, y0 + panel_size[1] - 42), m, high,
                  (span[0], span[1]))
        if not shared:
            mid = (y_top + y0 + panel_size[1] - 42) / 2
            half = 0.4 * (y0 + panel_size[1] - 42 - y_top)
            draw_colorbar(canvas, (x_right, mid - half, x_right + 16, mid + half), 0.0, high,
                          "kPa")
    if shared:
        draw_colorbar(canvas, (width - COLORBAR_WIDTH + 12, top + 0.1 * (height - top),
                               width - COLORBAR_WIDTH + 30, height - 0.1 * (height - top)),
                      0.0, high_kpa, "pressure, kPa")
    return canvas.save(path)
