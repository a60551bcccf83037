"""Headless PNG pictures of meshes (no display, no GPU): matplotlib's Agg canvas.

Meshes are projected orthographically, faces turned away from the camera are culled, and the
rest are drawn far to near (painter's algorithm) with flat Lambert shading. That suffices for
bodies and smooth surfaces seen from outside, which is all the pictures show.
"""

from __future__ import annotations

import os
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

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


def draw_meshes(ax, meshes: Sequence[MeshView], view: str | Sequence[float] = "three-quarter",
                light: Sequence[float] = (0.4, 0.8, 0.6)) -> None:
    """Draws meshes into a matplotlib axes, orthographic and flat-shaded (see the module
    docstring), the axes fitted to them, equal aspect, no frame.

    Parameters
    ----------
    ax : matplotlib Axes
    meshes : sequence of MeshView
    view : str or (3,) float
        A name from `VIEWS`, or a direction from the scene towards the camera (any length).
        The picture's x is the camera's right, its y the camera's up (`camera_axes`).
    light : (3,) float
        Direction of the light (any length).
    """
    from matplotlib.collections import PolyCollection

    right, up, back = camera_axes(view)
    light = np.asarray(light, dtype=float)
    light /= np.linalg.norm(light)
    polys, colors, depths = [], [], []
    for mesh in meshes:
        v = np.asarray(mesh.vertices, dtype=float)
        f = np.asarray(mesh.faces)
        corners = v[f]  # (F, k, 3)
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        if f.shape[1] == 4:
            normal += np.cross(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        facing = normal @ back > 0
        col = np.asarray(mesh.color, dtype=float)
        if col.ndim == 1:
            col = np.broadcast_to(col, (len(f), 3))
        elif len(col) == len(v) and len(v) != len(f):
            col = col[f].mean(axis=1)
        shade = 0.35 + 0.65 * np.clip(np.abs(normal @ light), 0, 1)
        if mesh.back_color is not None:
            col = np.where(facing[:, None], col, np.asarray(mesh.back_color, dtype=float))
            facing = np.ones(len(f), dtype=bool)
        keep = np.flatnonzero(facing)
        xy = np.stack([corners @ right, corners @ up], axis=-1)[keep]
        polys.extend(xy)
        colors.append(np.clip(col[keep] * shade[keep, None], 0, 1))
        depths.append((corners @ back).mean(axis=1)[keep])
    order = np.argsort(np.concatenate(depths)) if depths else np.zeros(0, dtype=int)
    colors_all = np.concatenate(colors)[order] if colors else np.zeros((0, 3))
    polys = [polys[k] for k in order]
    ax.add_collection(PolyCollection(polys, facecolors=colors_all, edgecolors="none",
                                     antialiased=False))
    if polys:
        pts = np.concatenate(polys)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        pad = 0.05 * (hi - lo).max()
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.axis("off")


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
    """Renders a grid of panels into one PNG and returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows = -(-len(panels) // columns)
    fig = Figure(figsize=(panel_size[0] * columns / 100, panel_size[1] * rows / 100 + 0.5),
                 dpi=100)
    FigureCanvasAgg(fig)
    for k, panel in enumerate(panels):
        ax = fig.add_subplot(rows, columns, k + 1)
        draw_meshes(ax, panel.meshes, panel.view, light)
        if panel.title:  # wrapped to the axes' width (about 11 px of panel a character)
            ax.set_title(textwrap.fill(panel.title, max(20, panel_size[0] // 11)), fontsize=10)
    if title:
        fig.suptitle(title, fontsize=12)
    if colorbar is not None:
        draw_colorbar(fig, fig.axes, colorbar)
    path = Path(path)
    fig.savefig(path, facecolor="white")
    return path


def draw_colorbar(fig, axes, colorbar: tuple[str, float, float]) -> None:
    """A viridis colour bar (label, low, high) beside the matplotlib axes."""
    from matplotlib import cm
    from matplotlib.colors import Normalize

    label, low, high = colorbar
    sm = cm.ScalarMappable(norm=Normalize(low, high), cmap="viridis")
    fig.colorbar(sm, ax=axes, fraction=0.03, pad=0.01, label=label)


def field_colors(values: np.ndarray, low: float = 0.0, high: float = 1.0) -> np.ndarray:
    """(N, 3) viridis RGB of values scaled from [low, high]."""
    from matplotlib import colormaps

    t = np.clip((np.asarray(values, dtype=float) - low) / max(high - low, 1e-300), 0, 1)
    return colormaps["viridis"](t)[:, :3]


def render_png(path: str | os.PathLike, meshes: Sequence[MeshView], *,
               view: str | Sequence[float] = "three-quarter", size: tuple[int, int] = (800, 800),
               title: str | None = None, light: Sequence[float] = (0.4, 0.8, 0.6),
               colorbar: tuple[str, float, float] | None = None) -> Path:
    """Renders meshes to a PNG file and returns its path.

    Orthographic, back faces culled, flat Lambert shading (see the module docstring).

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
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size[0] / 100, size[1] / 100), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes([0.02, 0.02, 0.96, 0.9 if title else 0.96])
    draw_meshes(ax, meshes, view, light)
    if title:
        fig.suptitle(title, fontsize=12)
    if colorbar is not None:
        draw_colorbar(fig, [ax], colorbar)
    path = Path(path)
    fig.savefig(path, facecolor="white")
    return path


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


def _draw_map(ax, m, norm, span: tuple[float, float]) -> None:
    p = np.asarray(m.pressure_kpa, dtype=float)
    ax.set_facecolor("white")
    if p.size:
        rows, cols = np.asarray(m.row_edges_m) * 100, np.asarray(m.column_edges_m) * 100
        cmap = _map_cmap()
        ax.pcolormesh(cols, rows, np.ma.masked_less_equal(p, 0.0), cmap=cmap, norm=norm,
                      edgecolors="none", antialiased=False)
        ax.add_patch(_rectangle(cols, rows))
        mid_c, mid_r = (cols[0] + cols[-1]) / 2, (rows[0] + rows[-1]) / 2
    else:
        mid_c = mid_r = 0.0
        ax.text(0.5, 0.5, "no contact", ha="center", va="center", transform=ax.transAxes,
                color="0.5")
    ax.set_xlim(mid_c - span[1] / 2, mid_c + span[1] / 2)
    ax.set_ylim(mid_r + span[0] / 2, mid_r - span[0] / 2)  # row 0 at the top
    ax.set_aspect("equal")
    if getattr(m, "draped", False):
        ax.set_xlabel("across the mat, cm", fontsize=8)
        ax.set_ylabel("along the mat, cm", fontsize=8)
    else:
        ax.set_xlabel(f"{_axis_name(getattr(m, 'column_axis', None), 'column')}, cm",
                      fontsize=8)
        ax.set_ylabel(f"{_axis_name(getattr(m, 'row_axis', None), 'row')}, cm", fontsize=8)
    ax.tick_params(labelsize=7)


def _axis_name(axis, fallback: str) -> str:
    """"x", "-z", ... for a direction along a world axis, else the fallback."""
    if axis is None or not np.size(axis):
        return fallback
    a = np.asarray(axis, dtype=float)
    k = int(np.argmax(np.abs(a)))
    if abs(a[k]) < 0.99 * np.linalg.norm(a):
        return f"{fallback} axis"
    return ("" if a[k] > 0 else "-") + "xyz"[k]


def _map_cmap():
    from matplotlib import colormaps

    return colormaps["viridis"].with_extremes(bad=(0.93, 0.93, 0.93))  # unloaded: bare grey


def _rectangle(cols: np.ndarray, rows: np.ndarray):
    from matplotlib.patches import Rectangle

    return Rectangle((cols[0], rows[0]), cols[-1] - cols[0], rows[-1] - rows[0], fill=False,
                     edgecolor="0.6", linewidth=0.8)


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
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    maps = list(maps)
    if not maps:
        raise ValueError("Expected at least one pressure map, got none")
    columns = max(1, min(columns, len(maps)))
    rows = -(-len(maps) // columns)
    span = [1e-2, 1e-2]
    for m in maps:
        if np.size(m.pressure_kpa):
            span[0] = max(span[0], float(np.ptp(m.row_edges_m)) * 100)
            span[1] = max(span[1], float(np.ptp(m.column_edges_m)) * 100)
    if panel_size is None:
        panel_size = (380, int(np.clip(300 * span[0] / span[1] + 110, 260, 560)))
    width, height = panel_size[0] * columns / 100 + 1.0, panel_size[1] * rows / 100 + \
        (0.5 if title else 0.1)
    fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(rows, columns, k + 1) for k in range(len(maps))]
    from matplotlib import cm

    for ax, m in zip(axes, maps):
        peak = float(np.max(m.pressure_kpa)) if np.size(m.pressure_kpa) else 0.0
        norm = Normalize(0.0, high_kpa if high_kpa is not None else max(peak, 1e-3))
        _draw_map(ax, m, norm, (span[0], span[1]))
        ax.set_title(_map_title(m), fontsize=10)
        if high_kpa is None:
            fig.colorbar(cm.ScalarMappable(norm=norm, cmap=_map_cmap()), ax=ax, fraction=0.05,
                         pad=0.02, shrink=0.8, label="kPa")
    if title:
        fig.suptitle(title, fontsize=12)
    if high_kpa is not None:
        fig.colorbar(cm.ScalarMappable(norm=Normalize(0.0, high_kpa), cmap=_map_cmap()),
                     ax=axes, fraction=0.04, pad=0.02, label="pressure, kPa")
    path = Path(path)
    fig.savefig(path, facecolor="white")
    return path
