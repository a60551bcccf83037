"""A design sheet: one PNG that shows a fitted piece of furniture as a designer reads it.

    row 1      the surface alone, square-on from the front, the side and above, shaded on both
               sides (the underside darker: a fold, an overhang or a curtain shows), its border
               drawn and its overall dimensions written on it (`solver.io.drawing`)
    rows 2..   a vertical section through each person (the surface's profile and the body's
               outline, `solver.io.drawing.Section`), then the pressure on each body seen from
               the surface's side (`solver.io.render`), filling the rows in that order

A title and lines of notes head the sheet; problems (a fold, a cut, a body that does not come to
rest) are written in red, so that nothing the figures say is wrong is left to be found in a
picture. Metres in, millimetres on the drawing; Y up, bodies face +Z.
"""

from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import Sequence

import numpy as np

from .drawing import DrawingError, Section, draw_elevation, draw_section, save_png
from .render import Panel, draw_colorbar, draw_meshes

PANEL_INCHES = (5.0, 3.7)  # width and height of one panel
LINE_INCHES = 0.2  # one line of the heading


def render_sheet(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
                 sections: Sequence[Section], pressure: Sequence[Panel], *,
                 title: str, notes: Sequence[str] = (), problems: Sequence[str] = (),
                 colorbar: tuple[str, float, float] | None = None, floor: float = 0.0,
                 columns: int = 3) -> Path:
    """Renders a design sheet (see the module docstring) into one PNG.

    Parameters
    ----------
    path : str or os.PathLike
        The PNG file to write (atomically).
    vertices : (N, 3) float
        The surface, metres, Y up.
    faces : (F, 4) or (F, 3) int
    sections : sequence of Section
        One per person (a section that misses the surface is drawn all the same: its body).
    pressure : sequence of Panel
        The bodies coloured by pressure, one panel each, seen from their `view`.
    title : str
    notes : sequence of str
        Lines under the title (figures, what the pictures show).
    problems : sequence of str
        Lines under the notes, in red (what misses a bar).
    colorbar : (label, low, high), optional
        The pressure panels' viridis scale (one for all, drawn beside each).
    floor : float
        The floor's height y, metres.
    columns : int
        Panels per row (the surface's views always take one row of three).

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    DrawingError
        If `columns` is under 3.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if columns < 3:
        raise DrawingError(f"Expected at least 3 columns (front, side, top), got {columns}")
    rows = 1 + -(-(len(sections) + len(pressure)) // columns)
    width = PANEL_INCHES[0] * columns
    chars = int(width * 100 / 7)  # about 7 px a character at 9 points
    heading = [textwrap.fill(title, chars)] + [textwrap.fill(n, chars) for n in notes]
    red = [textwrap.fill(p, chars) for p in problems]
    lines = sum(t.count("\n") + 1 for t in heading + red) + 1  # the title takes two
    top = 0.15 + LINE_INCHES * lines + 0.45  # and the panels' titles under the heading
    height = PANEL_INCHES[1] * rows + top
    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(rows, columns, top=1 - top / height, bottom=0.55 / height,
                            left=0.04, right=0.94, hspace=0.35, wspace=0.25)
    y = 1 - 0.15 / height
    for k, text in enumerate(heading + red):
        color = "firebrick" if k >= len(heading) else "black"
        fig.text(0.02, y, text, ha="left", va="top", fontsize=12 if k == 0 else 9,
                 color=color, weight="bold" if k == 0 else "normal")
        y -= LINE_INCHES * (text.count("\n") + 1 + (k == 0)) / height
    for k, view in enumerate(("front", "side", "top")):
        draw_elevation(fig.add_subplot(grid[0, k]), vertices, faces, view, floor)
    cells = [grid[1 + k // columns, k % columns] for k in range(len(sections) + len(pressure))]
    for cell, sec in zip(cells, sections):
        draw_section(fig.add_subplot(cell), sec)
    for cell, panel in zip(cells[len(sections):], pressure):
        ax = fig.add_subplot(cell)
        draw_meshes(ax, panel.meshes, panel.view)
        if panel.title:
            ax.set_title(textwrap.fill(panel.title, int(PANEL_INCHES[0] * 100 / 7)),
                         fontsize=9)
        if colorbar is not None:  # each panel its own bar, all on the same scale
            draw_colorbar(fig, [ax], colorbar)
    return save_png(fig, path)
