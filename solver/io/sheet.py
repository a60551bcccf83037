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

from .drawing import DrawingError, Section, boundary_loops, draw_elevation, draw_section
from .render import Panel, draw_meshes

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
    from .raster import COLORBAR_WIDTH, Canvas, draw_colorbar, text_height, wrap

    if columns < 3:
        raise DrawingError(f"Expected at least 3 columns (front, side, top), got {columns}")
    rows = 1 + -(-(len(sections) + len(pressure)) // columns)
    width = round(PANEL_INCHES[0] * columns * 100)
    chars = int(width / 7)  # about 7 px a character at 9 points
    heading = [textwrap.fill(title, chars)] + [textwrap.fill(n, chars) for n in notes]
    red = [textwrap.fill(p, chars) for p in problems]
    lines = sum(t.count("\n") + 1 for t in heading + red) + 1  # the title takes two
    top = 0.15 + LINE_INCHES * lines + 0.45  # and the panels' titles under the heading
    height = round((PANEL_INCHES[1] * rows + top) * 100)
    canvas = Canvas.blank(width, height)
    y = 15.0
    for k, text in enumerate(heading + red):
        color = (0.7, 0.13, 0.13) if k >= len(heading) else (0, 0, 0)
        canvas.text((0.02 * width, y), text, 12 if k == 0 else 9, color=color, bold=k == 0)
        y += LINE_INCHES * 100 * (text.count("\n") + 1 + (k == 0))
    # the grid of panels: 4 % of the width on the left, 6 % on the right, 55 px at the bottom,
    # a quarter of a panel between columns and a third between rows
    left, right, bottom = 0.04 * width, 0.94 * width, height - 55
    cw = (right - left) / (columns + 0.25 * (columns - 1))
    ch = (bottom - top * 100) / (rows + 0.35 * (rows - 1))

    def cell(k: int) -> tuple:
        x, y = left + (k % columns) * 1.25 * cw, top * 100 + (k // columns) * 1.35 * ch
        return x, y, x + cw, y + ch

    loops = boundary_loops(faces)  # one border for the three views
    for k, view in enumerate(("front", "side", "top")):
        draw_elevation(canvas, cell(k), vertices, faces, view, floor, loops=loops)
    for k, sec in enumerate(sections):
        draw_section(canvas, cell(columns + k), sec)
    for k, panel in enumerate(pressure):
        x0, y0, x1, y1 = cell(columns + len(sections) + k)
        if panel.title:
            text = wrap(panel.title, cw, 9)
            canvas.text(((x0 + x1) / 2, y0 - 6 - text_height(text, 9)), text, 9, "ma")
        draw_meshes(canvas, (x0, y0, x1 - (COLORBAR_WIDTH if colorbar else 0), y1),
                    panel.meshes, panel.view)
        if colorbar is not None:  # each panel its own bar, all on the same scale
            label, low, high = colorbar
            bar = x1 - COLORBAR_WIDTH + 12
            draw_colorbar(canvas, (bar, y0 + 0.1 * ch, bar + 16, y1 - 0.1 * ch), low, high,
                          label)
    return canvas.save(path)
