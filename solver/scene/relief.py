"""Pressure relief: a fitted surface eased away from the skin it presses hardest, and fitted again.

The fit shapes the surface to the skin; the evaluation then lets each body settle on it, and
where the surface presses the skin harder than `target` times the flat seat's peak at the same
load (`solver.contact.evaluate.flat_at_same_load`), an upholsterer would carve the foam away.
A round does that: under each such skin point (supported or not: an unsupported part pressed
that hard is a peak where none is wanted) the skin the fit aims at and keeps clear of moves out
along its normal by the excess pressure over the foam's stiffness (the depth that much
pressure presses in), at most `STEP` a round and the margin in all, and the surface is fitted
again from the scenario's start (a warm refit settles at once: the changed target moves the
energy too little for its settling rule). The round is evaluated on the bodies as they are and
kept only if `refused` finds nothing: no bar a person met is missed (`solver.scene.quality`),
no bar missed gets worse, no one's peak over the flat seat's comes to more than `RISE` over its
figure before the first round, the highest of them falls, and (the caller's `check`) the
surface misses none of its own bars it met. A refused round is tried again (`SHARES`: as long,
then half and a quarter as long), each time also where the refused fit pressed harder than the
aim (where the peak went); a fit that fails is a refused try. The rounds stop at the first
refused at every share, when every person is at the target, when nothing is left to ease (the
skin out by the margin), or after `rounds`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

STEP = 0.005  # metres the aimed-at skin moves out under a point in one round, at most
SHARES = (1.0, 1.0, 0.5, 0.25)  # of its step a round is tried with, in turn, while refused
RISE = 0.05  # the most a person's peak over the flat seat's may come to over its first figure


@dataclass
class Relief:
    """The fits tried (`rounds`: per fit its round, share of the step, peaks over the flat
    seat's, whether it was kept and why not, the skin moved out at most (m), seconds and
    iterations), the kept round's skin offsets per person, whether a cancel stopped them and
    whether they stopped with every person at the target."""

    rounds: list = field(default_factory=list)
    offsets: list = field(default_factory=list)  # per person (V,) metres, of the kept round
    stopped: bool = False  # cut short by the caller's cancel
    at_target: bool = False  # every person's peak at or under the target when they stopped
    # (and one at least to judge)

    @property
    def kept(self) -> int:
        """How many rounds were kept."""
        return sum(r["kept"] for r in self.rounds)

    def record(self) -> dict:
        """The report's "relief": the rounds, how many were kept, whether the caller's
        cancel stopped them and whether every person was at the target when they stopped."""
        return {"rounds": self.rounds, "kept": self.kept, "stopped": self.stopped,
                "at_target": self.at_target}


def relief_text(record: dict | None) -> str | None:
    """One line on a report's "relief" (`Relief.record`) for the sheet and the command line,
    None without rounds (but for rounds asked for and not needed: every person at the target
    from the start)."""
    if not record:
        return None
    if not record["rounds"]:
        return "pressure relief: no round needed (every peak at the target already)" \
            if record.get("at_target") else None
    tried = record["rounds"]
    rounds = max((r["round"] for r in tried if r["kept"]), default=0)
    seconds = sum(r["fit_s"] or 0.0 for r in tried)  # (None: a fit that failed)
    stopped = ", stopped early: out of time" if record.get("stopped") else ""
    return (f"pressure relief: {rounds} round(s) kept, {len(tried)} fit(s) tried "
            f"({seconds:.1f} s of fitting{stopped})")


def excess_depth(pressure_kpa: np.ndarray, aim_kpa: float, stiffness_pa_m: float
                 ) -> np.ndarray:
    """(V,) metres the foam is pressed in past what `aim_kpa` would press: (p - aim) / k, 0
    under the aim."""
    return np.maximum(pressure_kpa - aim_kpa, 0.0) * 1e3 / stiffness_pa_m


def _ratios(persons: Sequence[dict]) -> list:
    """Each person's peak over the flat seat's (None for a person standing, who sits on no
    seat and is not held to it, or without one)."""
    from solver.scene.quality import NO_SEAT_POSTURES

    return [None if p.get("posture") in NO_SEAT_POSTURES else p.get("peak_of_flat")
            for p in persons]


def _worst(ratios: list) -> float | None:
    known = [r for r in ratios if r is not None]
    return max(known) if known else None


JUDGED_WITHOUT_REST = {"coverage", "contact", "rest", "cut"}  # the bars judged of a body that
# does not rest (`person_miss_kinds` judges the others on the body at rest)
WORSE = {"coverage": 0.01, "contact_coverage": 0.01}  # a share a bar missed may lose, at most
WORSE_CUT_M = 0.001  # metres a cut deeper than the margin may deepen, at most


def refused(before: Sequence[dict], after: Sequence[dict], margin: float,
            first: Sequence[dict] | None = None) -> str | None:
    """Why a round's figures `after` may not replace `before` (per person, as
    `solver.scene.run.evaluate_scene` gives them), None if they may: a bar missed that was met
    (the flat seat's too; of a body that did not rest, those judged without a rest), a bar
    missed that gets worse (coverage or contact by more than 0.01, the cut by more than 1
    mm), a person's peak over the flat seat's lost or more than RISE over its figure in
    `first` (the fit before any round; `before` when not given), or the highest of them not
    lower."""
    from solver.scene.quality import person_miss_kinds

    first = before if first is None else first
    ratios_b, ratios_a = _ratios(before), _ratios(after)
    for b, a, rb, ra, rf in zip(before, after, ratios_b, ratios_a, _ratios(first)):
        missed = {kind for kind, _ in person_miss_kinds(b, margin)}
        judged = None if b["equilibrium"]["stable"] else JUDGED_WITHOUT_REST
        new = [text for kind, text in person_miss_kinds(a, margin)
               if kind not in missed and (judged is None or kind in judged)]
        if new:
            return f"misses a bar it met: {new[0]}"
        name = a["name"].split(" (")[0]
        for figure, kind in (("coverage", "coverage"), ("contact_coverage", "contact")):
            if kind in missed and a[figure] < b[figure] - WORSE[figure]:
                return f"{name}: {figure.replace('_', ' ')} fell further, {b[figure]:.3f} " \
                       f"-> {a[figure]:.3f}"
        if "cut" in missed and a["max_penetration_m"] > b["max_penetration_m"] + WORSE_CUT_M:
            return (f"{name}: the cut deepened, {1000 * b['max_penetration_m']:.0f} -> "
                    f"{1000 * a['max_penetration_m']:.0f} mm")
        if rb is not None and ra is None:
            return f"{name}: the peak over the flat seat's is lost"
        if rf is not None and ra is not None and ra > rf + RISE:
            return f"{name}: the peak over the flat seat's rose from {rf:.2f} to {ra:.2f}"
    worst_b, worst_a = _worst(ratios_b), _worst(ratios_a)
    if worst_b is None or worst_a is None or worst_a >= worst_b:
        return "the highest peak over the flat seat's did not fall"
    return None


def _steps(people: Sequence, persons: Sequence[dict], maps: Sequence, target: float,
           stiffness: float, ratios: list | None = None) -> list[np.ndarray]:
    """Per person (V,) metres a round moves the skin out: its `excess_depth` over `target`
    of its flat seat's peak, at most STEP (none for a person without a seat's load);
    `ratios`: the persons' `_ratios` when known."""
    from solver.contact.evaluate import SURFACE_PARTS, skin_pressure

    steps = []
    ratios = _ratios(persons) if ratios is None else ratios
    for p, row, m, ratio in zip(people, persons, maps, ratios):
        same = row["flat"].get("same_load")
        if same is None or ratio is None:
            steps.append(np.zeros(len(p.vertices)))  # (nothing to judge the pressure by)
            continue
        pressure = skin_pressure(m.settled, len(p.vertices), SURFACE_PARTS)
        steps.append(np.minimum(excess_depth(pressure, target * same["peak_pressure_kpa"],
                                             stiffness), STEP))
    return steps


def relieve(scenario, people: Sequence, result, persons: list[dict], maps: list, *,
            fit: Callable, evaluate: Callable, rounds: int, target: float,
            say: Callable[[str], None] | None = None,
            cancel: Callable[[], bool] | None = None,
            check: Callable[[object], str | None] | None = None) -> tuple:
    """Rounds of relief (module docstring) after the fit `result` of `people` with its figures
    `persons` and pressure `maps` (`evaluate_scene`'s).

    Parameters
    ----------
    scenario : the scenario (its margin and foam).
    people : the placed people (`PlacedPerson`), as fitted and evaluated.
    fit : fit(targets) -> FitResult, the scenario's fit of the people with their skin moved.
    evaluate : evaluate(result) -> (persons, maps) on the people as they are.
    rounds, target : the scenario's `relief`.
    say : optional progress lines.
    cancel : optional, asked before each fit and after it: when it says so the rounds stop
        with what was kept so far (`Relief.stopped`), a fit it cut short unused.
    check : optional check(result) -> why the surface may not be kept (its own bars: crossing,
        folds, the floor, the dense cut) or None, asked of a fit the people's figures keep.

    Returns
    -------
    (result, persons, maps, Relief): the fit kept (the first when no round was) with its
    figures, and the rounds run.
    """
    from solver.surface.fit import FitError

    margin = scenario.surface.params.margin
    stiffness = scenario.evaluation.foam_stiffness * 1e3  # Pa per metre
    relief = Relief(offsets=[np.zeros(len(p.vertices)) for p in people])
    first = persons
    for k in range(1, rounds + 1):
        ratios = _ratios(persons)
        if all(r is None or r <= target for r in ratios):
            # (with a peak to judge: none for people who do not rest or sit on no seat)
            relief.at_target = any(r is not None for r in ratios)
            break
        steps = _steps(people, persons, maps, target, stiffness, ratios)
        widened, last, made = False, None, 0  # (steps widened where a refused fit pressed
        # harder; the last try's share and widening: the same again is the same fit, not tried
        # twice; the tries made)
        for share in SHARES:
            if (share, widened) == last:
                continue
            last = (share, widened)
            made += 1
            tried = "" if made == 1 else (
                f", try {made} ({share:g} of the step"
                f"{', and where the refused fits pressed harder' if widened else ''})")
            if cancel is not None and cancel():
                relief.stopped = True
                return result, persons, maps, relief
            offsets = [np.minimum(before + share * step, margin)
                       for before, step in zip(relief.offsets, steps)]
            if all(np.array_equal(o, before) for o, before in zip(offsets, relief.offsets)):
                why = "nothing left to ease: the skin is out by the margin where it presses"
                if say is not None:
                    say(f"relief round {k}: {why}")
                break  # (the same fit again: no try)
            targets = [replace(p, vertices=p.vertices + o[:, None] * p.normals)
                       for p, o in zip(people, offsets)]
            moved = max(float(o.max(initial=0.0)) for o in offsets)
            try:
                candidate = fit(targets)
            except FitError as exc:  # (the fit before stands)
                why = f"the fit failed: {exc}"
                relief.rounds.append({"round": k, "share": share, "worst_peak_of_flat": None,
                                      "peak_of_flat": None, "kept": False, "refused": why,
                                      "moved_out_m": moved, "fit_s": None,
                                      "iterations": None})
                if say is not None:
                    say(f"relief round {k}{tried}: refused ({why})")
                continue
            if cancel is not None and cancel():
                relief.stopped = True
                return result, persons, maps, relief
            after, after_maps = evaluate(candidate)
            why = refused(persons, after, margin, first)
            if why is None and check is not None:  # (the surface's bars: only for a keeper)
                why = check(candidate)
            now = _ratios(after)
            worst = _worst(now)
            relief.rounds.append({"round": k, "share": share, "worst_peak_of_flat": worst,
                                  "peak_of_flat": now, "kept": why is None,
                                  "refused": why, "moved_out_m": moved,
                                  "fit_s": candidate.seconds,
                                  "iterations": candidate.iterations})
            if say is not None:
                say(f"relief round {k}{tried}: skin aimed at moved out up to "
                    f"{1000 * moved:.1f} mm, "
                    f"highest peak {'none' if worst is None else f'{worst:.2f}'} of a flat "
                    f"seat's: {'kept' if why is None else 'refused (' + why + ')'}")
            if why is None:
                break
            # tried again where the refused fit pressed too hard as well (a peak moved there)
            wider = [np.maximum(a, b) for a, b in zip(steps, _steps(people, after, after_maps,
                                                                    target, stiffness, now))]
            if any(not np.array_equal(a, b) for a, b in zip(wider, steps)):
                steps, widened, last = wider, True, None  # (a new aim: each share again)
        if why is not None:
            break
        result, persons, maps, relief.offsets = candidate, after, after_maps, offsets
    return result, persons, maps, relief
