"""The bars a fitted piece of furniture should meet, read from its report (report.json's
`guarantees` and `persons`), and what it misses, in words.

The surface (`solver.surface.guarantees`): no self-intersection, no fold over 60 degrees, above
the floor, no body point deeper than the margin (plus 1 mm) on a dense sampling. Each person:

    coverage           >= 0.95 of the supported importance within the margin of the surface
    contact_coverage   >= 0.8 touching it (within 5 mm in front, or sunk in up to the margin)
    rest               the body comes to rest on the surface (and the floor)
    peak               the highest pressure on the surface lies on a region asked to be supported
    seated             a person seated upright carries >= 60 % of the weight on the pelvis and
                       thighs and < 10 % on the calves (`solver.body.posture`)
    flat seat          the surface's peak pressure on the regions a flat seat carries (pelvis
                       and thighs on a seat, a seat's edge or side rising against the thighs
                       included) is at most 0.6 of a flat seat's at the same load (what a
                       shaped surface is for; report.json's `peak_of_flat`,
                       `solver.contact.evaluate.flat_at_same_load`); not for a person
                       standing, who leans on a surface and sits on none

A design in progress is held to one more (`design_misses`): no point of the person's skin cut
deeper than the margin.

Shares are of the body's weight m g, over every support, the floor included.
"""

from __future__ import annotations

import math

from solver.contact.ratios import PEAK_OF_FLAT_BAR, ratio_text

COVERAGE_MIN = 0.95
CONTACT_COVERAGE_MIN = 0.8
SEATED_LOAD_MIN = 0.6  # share of m g on the pelvis and thighs
SEATED_CALVES_MAX = 0.1  # share of m g on the calves
SEATED_POSTURES = ("seated",)
NO_SEAT_POSTURES = ("standing",)  # no flat-seat baseline
CUT_TOLERANCE_M = 1e-3  # a cut deeper than the margin by more than this misses the bar


def person_loads(person: dict) -> dict:
    """A person's load figures from its report row.

    Parameters
    ----------
    person : dict
        One of report.json's `persons` (its `mat` None when the body does not rest).

    Returns
    -------
    dict
        `pelvis_thighs_share`, `calves_share`, `floor_share` (of m g; None without a rest),
        `peak_kpa` (the highest pressure the surface puts on the body, the floor left out) and
        `peak_region` (the body region it lies on; both None without contact).
    """
    peak = {"peak_kpa": person.get("peak_pressure_kpa"), "peak_region": person.get("peak_region")}
    mat = person.get("mat")
    if not mat:
        return {"pelvis_thighs_share": None, "calves_share": None, "floor_share": None, **peak}
    share = {r: f["load_share"] for r, f in mat["total"]["regions"].items()}
    floor = mat["supports"].get("floor")
    return {"pelvis_thighs_share": share.get("pelvis", 0.0) + share.get("thighs", 0.0),
            "calves_share": share.get("calves", 0.0),
            "floor_share": floor["load_share"] if floor else 0.0, **peak}


def _short_of(value: float, bar: float) -> str:
    """A share under its bar, with two decimals, or where two would round it up to the bar, cut
    (not rounded) to three: 0.9496 is 0.949, not 0.95."""
    return f"{value:.2f}" if round(value, 2) < bar else f"{math.floor(value * 1000) / 1000:.3f}"


def surface_misses(guarantees: dict) -> list[str]:
    """What the surface misses of its bars (report.json's `guarantees`), one line each."""
    return [text for _, text in surface_miss_kinds(guarantees)]


def surface_miss_kinds(guarantees: dict) -> list[tuple[str, str]]:
    """`surface_misses` as (bar, line) pairs, the bar one of "crossing", "fold", "slit",
    "floor", "cut"."""
    g, misses = guarantees, []
    if g["self_intersections"]:
        misses.append(("crossing", f"the surface crosses itself ({g['self_intersections']} "
                                   f"pairs of triangles)"))
    if g["folds"]:
        misses.append(("fold", f"{g['folds']} folds: neighbouring faces up to "
                               f"{g['max_fold_deg']:.0f} degrees apart (a fold is over 60)"))
    if g.get("slits"):
        from solver.surface.guarantees import SLIT_LIMIT_DEG

        misses.append(("slit", f"{g['slits']} slits: faces across a crease up to "
                               f"{g['max_crease_deg']:.0f} degrees apart (a slit is over "
                               f"{SLIT_LIMIT_DEG:.0f}: they fold back on each other)"))
    if g["below_floor"]:
        misses.append(("floor", f"dips {1000 * (g['floor_m'] - g['min_height_m']):.0f} mm "
                                f"under the floor"))
    deepest, margin = g["max_penetration_dense_m"], g["margin_m"]
    if deepest > margin + CUT_TOLERANCE_M:
        # (between the skin's vertices too: deeper than a person's own cut, taken at them)
        misses.append(("cut", f"cuts {1000 * deepest:.0f} mm into a body on a dense sampling "
                              f"of the surface (margin {1000 * margin:.0f} mm)"))
    return misses


def person_misses(person: dict) -> list[str]:
    """What one person misses of its bars (see the module docstring), one line each, naming
    the person."""
    return [text for _, text in person_miss_kinds(person)]


def person_miss_kinds(person: dict, margin: float | None = None) -> list[tuple[str, str]]:
    """`person_misses` as (bar, line) pairs, the bar one of "coverage", "contact", "rest",
    "peak_region", "flat_seat", "pelvis_thighs", "calves", and with a `margin` (metres, a
    design in progress) "cut" too (`design_misses`)."""
    name = person["name"].split(" (")[0]
    misses = []
    if person["coverage"] < COVERAGE_MIN:
        misses.append(("coverage", f"{name}: coverage "
                       f"{_short_of(person['coverage'], COVERAGE_MIN)} (bar {COVERAGE_MIN})"))
    if person["contact_coverage"] < CONTACT_COVERAGE_MIN:
        misses.append(("contact", f"{name}: contact coverage "
                       f"{_short_of(person['contact_coverage'], CONTACT_COVERAGE_MIN)} (bar "
                       f"{CONTACT_COVERAGE_MIN})"))
    balance = person["equilibrium"]
    if not balance["stable"]:
        misses.append(("rest", f"{name}: does not come to rest ({balance['reason']})"))
        return misses + _cut(person, name, margin)
    loads = person_loads(person)
    if loads["peak_region"] is not None and loads["peak_region"] not in person["support"]:
        misses.append(("peak_region", f"{name}: peak pressure {loads['peak_kpa']:.1f} kPa on "
                       f"the {loads['peak_region']}, which are not to be supported"))
    ratio = person.get("peak_of_flat")
    if ratio is not None and ratio > PEAK_OF_FLAT_BAR and \
            person.get("posture") not in NO_SEAT_POSTURES:
        from solver.contact.evaluate import seated_skin

        same = person["flat"]["same_load"]
        misses.append(("flat_seat", f"{name}: peak pressure on the {seated_skin(same)} "
                       f"{same['fitted_peak_kpa']:.1f} kPa, "
                       f"{ratio_text(ratio, PEAK_OF_FLAT_BAR)} of a flat seat's at "
                       f"the same load ({same['peak_pressure_kpa']:.1f} kPa; bar "
                       f"{PEAK_OF_FLAT_BAR})"))
    if person.get("posture") in SEATED_POSTURES:
        if loads["pelvis_thighs_share"] < SEATED_LOAD_MIN:
            misses.append(("pelvis_thighs", f"{name}: "
                           f"{100 * loads['pelvis_thighs_share']:.0f} % of the weight on pelvis "
                           f"and thighs (bar {100 * SEATED_LOAD_MIN:.0f} %)"))
        if loads["calves_share"] >= SEATED_CALVES_MAX:
            misses.append(("calves", f"{name}: {100 * loads['calves_share']:.0f} % of the "
                           f"weight on the calves (bar under {100 * SEATED_CALVES_MAX:.0f} %)"))
    return misses + _cut(person, name, margin)


def _cut(person: dict, name: str, margin: float | None) -> list[tuple[str, str]]:
    """A design's cut deeper than the `margin` (none without one)."""
    if margin is None or not person["max_penetration_m"] > margin + CUT_TOLERANCE_M:
        return []  # (as `surface_misses`: a cut is a depth past the margin)
    deepest = person["max_penetration_m"]
    where = person.get("deepest_cut_region")
    where = f"the {where.replace('_', ' ')}" if where else "the skin"
    return [("cut", f"{name}: the surface cuts {1000 * deepest:.0f} mm into {where} (margin "
                    f"{1000 * margin:.0f} mm)")]


def design_misses(person: dict, margin: float) -> list[str]:
    """`person_misses` and, for a design in progress, a cut deeper than the `margin` (metres),
    one line each, naming the person."""
    return [text for _, text in person_miss_kinds(person, margin)]
