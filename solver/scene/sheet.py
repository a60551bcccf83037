"""A fit's design sheet (sheet.png, `solver.io.sheet.render_sheet`): the surface alone from
the front, the side and above with its overall dimensions, a section through each person, the
pressure the surface puts on each body, and, in red, every bar the fit misses
(`solver.scene.quality`).

The section runs vertically through the person's left hip joint along the direction the person
faces (`solver.scene.placement.person_frame`): it cuts the buttock, the thigh and the calf where
they rest, and the back beside the spine, rather than the gap between the legs. The pressure is
the surface's alone (the floor's under the feet is left out: its tens of kPa would drown the
seat's few), each body seen from where the surface meets it (against the force-weighted mean of
the surface's contact normals), on one scale for everybody.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from solver.contact.evaluate import SURFACE_PARTS, PressureMap, surface_pressure
from solver.io.drawing import Section, section
from solver.io.render import MeshView, Panel
from solver.scene.placement import PlacedPerson, person_frame
from solver.scene.quality import person_loads, person_misses, surface_misses
from solver.scene.relief import relief_text
from solver.scene.run import pressure_on_skin


def person_section(name: str, surface: np.ndarray, faces: np.ndarray,
                   person: PlacedPerson) -> Section:
    """The vertical section through a person's left hip joint, along the way the person faces.

    Parameters
    ----------
    name : the section's title.
    surface : (N, 3) float, metres; faces : (F, 4) int.
    person : a placed person.

    Returns
    -------
    Section, its layers SURFACE and BODY, distances along from the hip joint.
    """
    _, forward = person_frame(person)
    hip = person.motion.world.positions[0, person.body.joint_index("LeftUpLeg")]
    origin = person.transform[:3, :3] @ hip + person.transform[:3, 3]
    return section(name, origin, forward, {"SURFACE": (surface, faces),
                                           "BODY": (person.vertices, person.triangles)})


def pressure_view(pressure: PressureMap) -> np.ndarray:
    """(3,) the direction towards a camera that sees the skin the surface presses: against the
    force-weighted mean of the surface's contact normals (straight up from below without
    contact)."""
    total = np.zeros(3)
    for c in pressure.settled.contacts:
        if c.name in SURFACE_PARTS:
            total += c.normal_force @ c.normals
    norm = np.linalg.norm(total)
    return -total / norm if norm > 0 else np.array([0.0, -1.0, 0.0])


def sheet_lines(report: dict) -> tuple[list[str], list[str]]:
    """The sheet's notes (the surface's and each person's figures) and problems (every bar
    missed) from a fit's report (report.json's fields)."""
    g = report["guarantees"]
    notes = [f"surface: {g['folds']} folds (largest angle between neighbouring faces "
             f"{g['max_fold_deg']:.0f} deg), {g['self_intersections']} self-intersections, "
             f"lowest point {1000 * g['min_height_m']:.0f} mm above the floor, deepest cut into "
             f"a body {1000 * g['max_penetration_dense_m']:.0f} mm (margin "
             f"{1000 * g['margin_m']:.0f} mm); fitted in {report['timing']['fit_s']:.1f} s, "
             f"{report['iterations']} iterations"]
    relief = relief_text(report.get("relief"))
    if relief is not None:
        notes[0] += f"; {relief}"
    for p in report["persons"]:
        loads = person_loads(p)
        text = (f"{p['name']}, {p.get('posture', '?')}, supported: "
                f"{', '.join(p['support'])}: coverage {p['coverage']:.2f}, contact "
                f"{p['contact_coverage']:.2f}")
        if loads["pelvis_thighs_share"] is not None:
            # (a share may be a little under 0: a wall leant on may pull the body down by its
            # friction, and the floor carry more than the weight)
            pct = {k: int(round(100 * loads[k])) for k in ("pelvis_thighs_share", "calves_share",
                                                             "floor_share")}  # no "-0"
            text += (f"; weight on pelvis + thighs {pct['pelvis_thighs_share']} %, "
                     f"calves {pct['calves_share']} %, floor {pct['floor_share']} %")
        if loads["peak_region"] is not None:
            text += f"; peak {loads['peak_kpa']:.1f} kPa on the {loads['peak_region']}"
        notes.append(text)
    problems = surface_misses(g)
    for p in report["persons"]:  # one line a person
        misses = person_misses(p)
        if misses:
            name = misses[0].split(": ", 1)[0]
            problems.append(f"{name}: " + "; ".join(m.split(": ", 1)[1] for m in misses))
    return notes, problems


def write_design_sheet(path: str | os.PathLike, title: str, surface: np.ndarray,
                       faces: np.ndarray, people: list[PlacedPerson],
                       pressures: list[PressureMap], report: dict) -> Path:
    """Writes a fit's design sheet (see the module docstring).

    Parameters
    ----------
    path : the PNG to write.
    title : the sheet's heading (the scenario).
    surface : (N, 3) float, metres, the fitted surface as the files hold it; faces : (F, 4).
    people : the placed people; pressures : their settles' `PressureMap`s, in that order.
    report : the fit's report so far: `guarantees`, `persons`, `timing` (fit_s), `iterations`.

    Returns
    -------
    pathlib.Path, the path written.
    """
    from solver.io.sheet import render_sheet

    notes, problems = sheet_lines(report)
    names = [p.label.split(" (")[0] for p in people]
    sections = [person_section(f"{name}: section through the left hip", surface, faces, p)
                for name, p in zip(names, people)]
    fields = [surface_pressure(m) for m in pressures]
    peak = max([float(f.max()) for f in fields] + [0.0])
    panels = []
    for name, p, m, field in zip(names, people, pressures, fields):
        title_text = (f"{name}: peak {field.max():.1f} kPa from the surface" if
                      m.settled.stable else f"{name}: no rest ({m.settled.reason})")
        panels.append(Panel([MeshView(p.vertices, p.body.faces,
                                      pressure_on_skin(field, max(peak, 1e-9)))],
                            pressure_view(m), title_text))
    return render_sheet(path, surface, faces, sections, panels, title=title, notes=notes,
                        problems=problems,
                        colorbar=("pressure from the surface, kPa", 0.0, peak) if peak > 0
                        else None,
                        floor=report["guarantees"]["floor_m"] or 0.0)
