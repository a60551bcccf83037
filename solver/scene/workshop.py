"""From the design to the workshop: a fitted scene's solid (STL, 3MF), cutter reach and
drawings (DXF, PNG), written beside `sitrelax fit`'s other files.

Files for the workshop are millimetres, Z up: a scene point (x, y, z) in metres, Y up, is
written as 1000 (x, -z, y) (a rotation, not a mirror); see `solver.io.solid` and
`solver.io.drawing`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from solver.io.drawing import (overall_dimensions, render_sections, section,
                               write_overall_dxf, write_section_dxf)
from solver.io.reach import (MAX_TOOL_RADIUS, bending_towards_normal, cutter_reach,
                             render_reach)
from solver.io.solid import SolidError, check_solid, plinth, thicken, write_3mf, write_stl
from solver.scene.placement import person_frame

WORKSHOP_UNITS = ("STL, 3MF and DXF in millimetres, Z up: a scene point (x, y, z) in metres, "
                  "Y up, is written as 1000 (x, -z, y); sections are drawn in their own plane "
                  "(mm along the section from the pelvis, mm above the floor)")


MAX_SOLID_THICKNESS = 0.1  # metres: trimming a 0.1 m offset of a seat takes about 30 s
MIN_SOLID_THICKNESS = 0.001  # metres: a thinner sheet is no workshop's, and its check (0.1 mm
# on the thickness, corners 10 um apart for single precision) could not pass


@dataclass(frozen=True)
class WorkshopOptions:
    """What to make for the workshop: an offset solid `solid_thickness` metres thick (None:
    no solid) or, with `plinth`, a solid down to the floor; the cutter reach for a ball-nose
    of `tool_radius` metres (None: no reach check); the sections and dimensions (`drawings`)."""

    solid_thickness: float | None = None
    plinth: bool = False
    drawings: bool = False
    tool_radius: float | None = None

    def __post_init__(self):
        t = self.solid_thickness
        if t is not None and not (np.isfinite(t) and
                                  MIN_SOLID_THICKNESS <= t <= MAX_SOLID_THICKNESS):
            why = ("a thickness is a finite number" if not np.isfinite(t) else
                   "no workshop cuts a thinner sheet" if t < MIN_SOLID_THICKNESS else
                   "trimming a thicker offset where the surface bends takes longer than half "
                   "a minute")
            raise SolidError(f"Expected a solid thickness in [{MIN_SOLID_THICKNESS:g}, "
                             f"{MAX_SOLID_THICKNESS:g}] m, got {t} ({why}; --plinth fills down "
                             "to the floor)")
        r = self.tool_radius
        if r is not None and not (np.isfinite(r) and 0 < r <= MAX_TOOL_RADIUS):
            raise SolidError(f"Expected a tool radius in (0, {MAX_TOOL_RADIUS:g}] m, got {r} "
                             "(a ball-nose cutter's radius)")

    @property
    def any(self) -> bool:
        return bool(self.solid_thickness is not None or self.plinth or self.drawings or
                    self.tool_radius is not None)


def export_workshop(out: Path, surface: np.ndarray, faces: np.ndarray, people: list,
                    options: WorkshopOptions) -> tuple[dict, dict]:
    """Writes the solid, reach picture and drawings that `options` ask for into `out`.

    Parameters
    ----------
    out : folder to write into.
    surface : (N, 3) float, metres, Y up; faces : (F, 4) int, normals towards the bodies.
    people : the scene's `PlacedPerson`s (for the sections).
    options : WorkshopOptions

    Returns
    -------
    (files, fabrication): file names by key, and the figures for report.json (lengths m,
    areas m^2, volume m^3; drawings' dimensions mm). A solid that fails its checks is not
    written; `fabrication["solid"]["problem"]` says why.
    """
    files, fab = {}, {"units": WORKSHOP_UNITS}
    bend = bending_towards_normal(surface, faces)
    towards, away = bend[:, 0].max(), -bend[:, 1].min()
    fab["min_concave_radius_m"] = float(1 / towards) if towards > 0 else None
    fab["min_convex_radius_m"] = float(1 / away) if away > 0 else None
    solid = None
    if options.solid_thickness is not None or options.plinth:
        solid, fab["solid"] = _solid(surface, faces, options)
        radius = fab["min_convex_radius_m"]
        if solid is None and radius is not None and not options.plinth:
            fab["solid"]["problem"] += (f"; the surface's tightest bend away from the bodies "
                                        f"has a radius of {radius * 1000:.1f} mm")
        if solid is not None:
            write_stl(out / "solid.stl", solid)
            write_3mf(out / "solid.3mf", solid)
            files["solid_stl"], files["solid_3mf"] = "solid.stl", "solid.3mf"
    if options.tool_radius is not None:
        reach = cutter_reach(surface, faces, options.tool_radius)
        fab["reach"] = reach.summary()
        render_reach(out / "reach.png", surface, faces, reach)
        files["reach_png"] = "reach.png"
    if options.drawings:  # (the solid's size when one is written: what the workshop makes)
        files.update(_drawings(out, surface, faces, people, solid))
        fab["dimensions_mm"] = overall_dimensions(surface if solid is None else solid.vertices)
        fab["dimensions_of"] = "surface" if solid is None else "solid"
    return files, fab


def _solid(surface, faces, options: WorkshopOptions):
    """The solid (None when it fails its checks) and its figures."""
    try:
        if options.plinth:
            solid = plinth(surface, faces, check=False)
        else:
            solid = thicken(surface, faces, options.solid_thickness, check=False)
    except SolidError as exc:
        # (a plinth has no thickness, as a written one reports: --solid's is not used)
        kind, thickness = ("plinth", None) if options.plinth else \
            ("offset", options.solid_thickness)
        return None, {"kind": kind, "thickness_m": thickness, "ok": False,
                      "problem": str(exc)}
    check = check_solid(solid)
    figures = {"kind": solid.kind, "thickness_m": solid.thickness, **asdict(check),
               "ok": check.ok, "problem": check.problem(),
               "vertices": int(len(solid.vertices)), "triangles": int(len(solid.triangles))}
    return (solid if check.ok else None), figures


def _drawings(out: Path, surface, faces, people: list, solid) -> dict:
    files = {"overall_dxf": "overall.dxf"}
    if solid is None:
        write_overall_dxf(out / "overall.dxf", surface, faces)
    else:
        write_overall_dxf(out / "overall.dxf", solid.vertices, solid.triangles, what="solid")
    sections, names = [], []
    for k, person in enumerate(people, start=1):
        pelvis, forward = person_frame(person)
        meshes = {"SURFACE": (surface, faces), "BODY": (person.vertices, person.triangles)}
        if solid is not None:
            meshes["SOLID"] = (solid.vertices, solid.triangles)
        across = np.cross([0.0, 1.0, 0.0], forward)  # to the person's left
        for kind, along in (("sagittal", forward), ("transverse", across)):
            sec = section(f"person {k} {kind}", pelvis, along, meshes)
            if sec.extent() is None:
                continue  # the plane misses the surface: nothing to draw
            name = f"section_{k}_{kind}.dxf"
            write_section_dxf(out / name, sec)
            sections.append(sec)
            names.append(name)
    files["section_dxf"] = names
    if sections:
        render_sections(out / "sections.png", sections, columns=2,
                        title="Sections through each person's pelvis (mm)")
        files["sections_png"] = "sections.png"
    return files

