"""`sitrelax fit`: a scenario from file to fitted surface, evaluation, exports and report."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from capture.files import results_folder, write_atomic

from solver.mesh import SurfaceMesh
from solver.contact.evaluate import (FLOOR, SUPPORT_FIGURES, SupportGate, body_winding,
                                     cut_vertices, evaluate_person, flat_at_same_load,
                                     flat_seat_height, flat_surface, support_inside)
from solver.contact.evaluate import PressureMap, contact_footprint, surface_pressure
from solver.contact.mat import PressureGrid, pressure_grid, write_pressure_csv
from solver.contact.settle import Foam, reach_depth
from solver.io.export import ExportError, frame_matrix, write_mesh
from solver.mesh import triangle_mesh
from solver.surface.fit import FitError, FitResult, fit_surface
from solver.io.render import (SKIN, SURFACE, MeshView, Panel, field_colors, render_panels,
                              render_pressure_maps)
from solver.scene.scenario import Scenario, load_scenario
from solver.scene.schema import Evaluation
from solver.scene.placement import PlacedPerson, place_scene, scene_posture
from solver.mesh import quad_triangles
from solver.threads import limited_threads

if TYPE_CHECKING:
    from solver.body.relax import RelaxProblem  # the relaxation loads when a pose is relaxed
    from solver.scene.workshop import WorkshopOptions


def foam_text(foam: dict) -> str:
    """A foam (`SURFACE_FOAM` and its values, as a relaxation's report gives it) for people:
    "200 kPa/m, 10 cm, friction 0.5"."""
    return (f"{foam['foam_stiffness']:g} kPa/m, {foam['foam_thickness'] * 100:g} cm, "
            f"friction {foam['friction']:g}")


def foams(evaluation) -> tuple[Foam, Foam | None]:
    """The surface's foam and the floor's (None without a floor) of a scenario's
    `evaluation` (kPa per metre in the scenario, Pa per metre here)."""
    foam = Foam(evaluation.foam_stiffness * 1e3, evaluation.foam_thickness,
                evaluation.friction)
    floor = Foam(evaluation.floor_stiffness * 1e3, FLOOR.thickness, evaluation.friction) \
        if evaluation.floor else None
    return foam, floor


def evaluate_scene(scenario: Scenario, people: list[PlacedPerson], surface: np.ndarray,
                   faces: np.ndarray) -> tuple[list[dict], list[np.ndarray]]:
    """Per person: the fitted surface's figures (with `flat`, the flat-seat baseline and under
    its `same_load` that seat at the fitted seat's load (`flat_at_same_load`), `peak_of_flat`,
    the fitted surface's peak on the regions that flat seat presses over its peak, and
    `support_inside_others`, the share of the person's importance inside other people's
    bodies) and the settle's `PressureMap` (the pressure in kPa per body vertex, the
    contacts)."""
    mesh = SurfaceMesh.from_quads(surface, faces)
    margin, (foam, floor) = scenario.surface.params.margin, foams(scenario.evaluation)
    rows, maps = [], []
    for k, p in enumerate(people):
        winding = body_winding(p.vertices, p.triangles)  # one for both surfaces
        figures, pm = evaluate_person(mesh, p, margin, foam, floor, winding)
        height = flat_seat_height(mesh, p)
        flat, _ = evaluate_person(flat_surface(height, p.vertices.mean(axis=0)), p, margin,
                                  foam, floor, winding)
        flat["height_m"] = height
        # what a shaped surface's peak is judged against: the flat seat at the same load
        flat["same_load"] = flat_at_same_load(p, pm.settled, foam)
        same = flat["same_load"]  # (its seat carries load: both peaks are positive)
        figures["peak_of_flat"] = same["fitted_peak_kpa"] / same["peak_pressure_kpa"] \
            if same and same["fitted_peak_kpa"] is not None else None
        others = [(q.vertices, q.triangles) for j, q in enumerate(people) if j != k]
        rows.append({"name": p.label, "body": p.spec.body.as_dict(),
                     "height_m": p.body.height_m, "mass_kg": p.body.mass_kg,
                     "posture": scene_posture(p), "support": list(p.spec.support),
                     **figures,
                     "support_inside_others": support_inside(p.vertices, p.importance, others),
                     "flat": flat})
        maps.append(pm)
    return rows, maps


def fit_scene(scenario: Scenario, people: list[PlacedPerson],
              progress: Callable[[int, float, float], None] | None = None,
              timing: dict | None = None, *, warm: FitResult | None = None,
              cancel: Callable[[], bool] | None = None,
              iterates: Callable[[int, np.ndarray, np.ndarray], None] | None = None
              ) -> tuple[FitResult, list[dict], list[np.ndarray]]:
    """Fits the scenario's surface to the posed people and evaluates it.

    Parameters
    ----------
    scenario : the scenario (its control mesh, fit parameters and foam stiffness).
    people : the scenario's people as `place_person` posed them, in its order.
    progress : optional callback (iteration, energy, tau) of the fit's loop.
    timing : optional dict that receives `fit_s` and `evaluate_s` (seconds).
    warm, cancel, iterates : as `fit_surface` takes them: an earlier fit of the same control
        mesh to refit from, a callable polled between iterations that ends the fit early, and
        one given every accepted iterate (iteration, control vertices, level-s vertices).

    Returns
    -------
    result : FitResult, the fitted control mesh and its level-s surface (metres).
    persons : per person the report's figures (coverage, max_penetration_m, pressures in kPa,
        contact_area_m2, ...), with the flat-seat baseline under `flat`.
    pressure : per person the settle's `PressureMap`: `pressure_kpa` (V,) float, kPa on each
        body vertex, and `settled`, the body at rest with its contacts.
    """
    timing = timing if timing is not None else {}
    t = time.perf_counter()
    result = fit_people(scenario, people, progress, warm=warm, cancel=cancel,
                        iterates=iterates)
    timing["fit_s"] = time.perf_counter() - t
    t = time.perf_counter()
    _, persons, maps = evaluate_fit(scenario, people, result)
    timing["evaluate_s"] = time.perf_counter() - t
    return result, persons, maps


def evaluate_fit(scenario: Scenario, people: list[PlacedPerson], result: FitResult
                 ) -> tuple[np.ndarray, list[dict], list]:
    """A fit evaluated as `fit_scene` does it, on its limit surface (what `surface.*` holds
    and the guarantees judge): the limit surface (ns, 3) and `evaluate_scene`'s figures and
    pressure maps per person. For callers that decide between the fit and its evaluation (a
    cancelled fit is not evaluated)."""
    limit = result.limit_surface(scenario.surface.params.creases)
    persons, maps = evaluate_scene(scenario, people, limit, result.surface_faces)
    return limit, persons, maps


def fit_people(scenario: Scenario, people: list[PlacedPerson],
               progress: Callable[[int, float, float], None] | None = None, *,
               warm: FitResult | None = None, cancel: Callable[[], bool] | None = None,
               iterates: Callable[[int, np.ndarray, np.ndarray], None] | None = None
               ) -> FitResult:
    """The scenario's surface fitted to the posed people (a template's control mesh built
    around them by `place_scene`); `warm`, `cancel` and `iterates` as `fit_surface` takes
    them."""
    if scenario.surface.vertices is None:
        raise FitError("The scenario's template has no control mesh yet: it is built around "
                       "the placed people (solver.scene.placement.place_scene)")
    return fit_surface(scenario.surface.vertices, scenario.surface.faces, people,
                       scenario.surface.params, progress, warm=warm, cancel=cancel,
                       iterates=iterates)


FLOOR_BAND = 0.05  # metres above the floor within which skin is held above it in a relaxation


def relax_problem(person: PlacedPerson, surface_vertices: np.ndarray,
                  surface_triangles: np.ndarray, threshold: float = 0.02,
                  margin: float | None = None, foam: Foam | None = None,
                  floor: float | None = None) -> RelaxProblem:
    """The relaxation problem of a placed person: its rig in the scene frame, its vertices of
    importance above `threshold`, the rest of its skin that the surface cuts into or that lies
    within `GUARD_BAND` in front of it (guarded: it may not sink deeper), the skin within
    `FLOOR_BAND` of the `floor` (a height, m; held above it: the feet), and the surface to
    settle on.

    Parameters
    ----------
    person : a person placed by `place_person`.
    surface_vertices : (N, 3) float, metres; surface_triangles : (F, 3) int, facing the body.
    threshold : importance (in [0, 1]) a vertex needs to count as supportable.
    margin : metres of softness the surface was fitted with: body points sunk in less are not
        pushed out (None: the paper's 1 cm).
    foam : the surface's foam, whose reach behind it bounds where it can cut into the body
        (None: the scenario's default).
    floor : the floor's height (m; None: no floor).

    Returns
    -------
    RelaxProblem, for `relax`. Raises RelaxError when nothing is supportable.
    """
    from solver.body.relax import DEFAULT_MARGIN, RelaxError, RelaxProblem

    ids = np.flatnonzero(person.importance > threshold)
    if not ids.size:
        raise RelaxError(f"{person.label}: nothing to support (no importance above "
                         f"{threshold})")
    rot, shift = person.transform[:3, :3], person.transform[:3, 3]
    local0 = person.motion.local_rotmats[0].copy()
    local0[0] = rot @ local0[0]
    root0 = rot @ person.motion.root_positions[0] + shift
    problem = RelaxProblem(person.body, local0, root0, ids, person.importance[ids],
                           np.asarray(surface_vertices, dtype=np.float64),
                           np.asarray(surface_triangles, dtype=np.int64),
                           margin=DEFAULT_MARGIN if margin is None else margin)
    guards = guarded_vertices(person, problem.surface_mesh(), threshold,
                              foam or foams(Evaluation())[0])
    held = np.zeros(0, dtype=np.int64)
    if floor is not None:  # the lowest in each cube
        near = np.flatnonzero(person.vertices[:, 1] <= floor + FLOOR_BAND)
        held = _one_per_cube(person.vertices, near, person.vertices[near, 1])
    return dataclasses.replace(problem, guard_ids=guards, floor=floor, floor_ids=held)


def guarded_vertices(person: PlacedPerson, surface: SurfaceMesh, threshold: float,
                     foam: Foam) -> np.ndarray:
    """(g,) the person's vertices of importance up to `threshold` that face the surface (their
    closest point is no border point) and that it cuts into (`cut_vertices`) or that lie within
    `GUARD_BAND` in front of it: of those in each `GUARD_SPACING` cube, the deepest."""
    from solver.body.relax import GUARD_BAND

    rest = np.flatnonzero(person.importance <= threshold)
    reach = max(reach_depth(foam), GUARD_BAND)
    lo, hi = surface.vertices.min(axis=0) - reach, surface.vertices.max(axis=0) + reach
    rest = rest[np.all((person.vertices[rest] >= lo) & (person.vertices[rest] <= hi), axis=1)]
    _, signed, over, _, closest = surface.closest(person.vertices[rest])
    cut = cut_vertices(person.vertices, person.triangles, signed, closest, foam)
    keep = over & (cut | ((signed >= 0) & (signed <= GUARD_BAND)))
    # one per cube, the deepest: neighbours move together
    return _one_per_cube(person.vertices, rest[keep], signed[keep])


def _one_per_cube(vertices: np.ndarray, ids: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Of the vertices `ids`, the one of least `order` (per id) in each `GUARD_SPACING` cube,
    ascending."""
    from solver.body.relax import GUARD_SPACING

    first_ids = ids[np.argsort(order, kind="stable")]
    cells = np.floor(vertices[first_ids] / GUARD_SPACING).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    return np.sort(first_ids[first])


class _CheckedGate(SupportGate):
    """A `SupportGate` that calls `check()` before it judges a pose (a caller's deadline: the
    relaxation's rounds are bounded in evaluations, not in time)."""

    def __init__(self, check: Callable[[], None], *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._check = check

    def figures(self, vertices, reference=None):
        self._check()
        return super().figures(vertices, reference)


def relax_person(scenario: Scenario, person: PlacedPerson, surface: np.ndarray,
                 quads: np.ndarray, check: Callable[[], None] | None = None, *,
                 margin: float | None = None):
    """Relaxes one posed person onto a surface (vertices, quads), accepting only what the
    evaluation's support figures find none worse (`SupportGate`): the solver's result, the
    person's figures before and after (as `evaluate_person` gives them), and the solver's
    seconds. When no round was accepted, the person keeps the captured pose exactly (its
    figures after are those before). `check`, when given, is called between the stages (the
    evaluations, and before each pose the relaxation judges): a caller's deadline raises
    there. `quads` : (F, 4) quads or (F, 3) triangles. `margin` : metres of softness the
    surface was fitted with (None: the scenario's `surface.margin`)."""
    from solver.body.relax import relax

    check = check or (lambda: None)
    margin = scenario.surface.params.margin if margin is None else margin
    foam, floor = foams(scenario.evaluation)
    quads = np.asarray(quads)
    triangles = quad_triangles(quads) if quads.shape[1] == 4 else quads
    problem = relax_problem(person, surface, triangles, margin=margin, foam=foam,
                            floor=0.0 if floor is not None else None)
    mesh = problem.surface_mesh()
    before = evaluate_person(mesh, person, margin, foam, floor)[0]
    check()
    gate = _CheckedGate(check, mesh, person.importance, person.triangles, margin, foam,
                        0.0 if floor is not None else None)  # (the evaluation's floor, y = 0)
    t = time.perf_counter()
    res = relax(problem, gate=gate, figures_before={
        **{k: before[k] for k in SUPPORT_FIGURES}, **gate.floor_figures(person.vertices)})
    seconds = time.perf_counter() - t
    check()
    if not res.accepted:
        res = dataclasses.replace(res, vertices=person.vertices)
        return res, before, before, seconds
    areas, normals = triangle_mesh(person.body.triangles, len(res.vertices)).measures(
        res.vertices)
    relaxed = dataclasses.replace(person, vertices=res.vertices, normals=normals, areas=areas)
    return res, before, evaluate_person(mesh, relaxed, margin, foam, floor)[0], seconds


def relax_text(result) -> str:
    """What a gated relaxation (`relax` with a gate) accepted and why, in one line: per round
    the share of its step accepted and the figures it improved, or the figures that made
    every tried step worse."""
    names = {"mean_support_distance_m": "support distance", "coverage": "coverage",
             "contact_coverage": "contact coverage", "max_penetration_m": "deepest cut",
             "below_floor_m": "depth under the floor"}
    parts = []
    for run in sorted({s.round for s in result.steps}):
        tried = [s for s in result.steps if s.round == run]
        taken = [s for s in tried if s.accepted]
        if taken:
            gain = ", ".join(names[n] for n in taken[0].better) or "nothing changed"
            share = "" if taken[0].scale == 1 else f" ({taken[0].scale:g} of its step)"
            parts.append(f"round {run} accepted{share}: better {gain}")
        else:
            worse = sorted({n for s in tried for n in s.worse}, key=list(names).index)
            parts.append(f"round {run} rejected: {', '.join(names[n] for n in worse)} worse "
                         f"at every step tried")
    if not result.accepted:
        parts.append("the captured pose is kept")
    return "; ".join(parts)


def relax_record(result) -> dict:
    """report.json's record of a gated relaxation: whether the pose moved, the text of
    `relax_text`, and every pose tried (round, share of its step, accepted, the figures worse
    and better than the last accepted pose's, and its figures)."""
    return {"accepted": result.accepted, "summary": relax_text(result),
            "steps": [{"round": s.round, "scale": s.scale, "accepted": s.accepted,
                       "worse": list(s.worse), "better": list(s.better),
                       "figures": s.figures} for s in result.steps]}


def report_parameters(scenario: Scenario) -> dict:
    """The fit's parameters as report.json (and the HTTP API's fit reply) gives them: every
    `FitParams` field, the foam stiffness (kPa per metre) and where the control mesh came
    from."""
    params, template = scenario.surface.params, scenario.surface.template
    more = {} if template is None else {"template": template_table(template)}
    return {**dataclasses.asdict(params), **more, "fixed": list(params.fixed),
            "creases": [list(c) for c in params.creases],
            "foam_stiffness_kpa_per_m": scenario.foam_stiffness,
            "evaluation": scenario.evaluation.model_dump(),
            "relief": scenario.relief.model_dump(),
            "control_mesh": scenario.surface.source}


def template_table(template) -> dict:
    """A scenario's template as a table: its kind and parameters (all of them once built around
    the people, the given ones before), tuples as lists: what `[surface] template` reads."""
    values = dataclasses.asdict(template.built) if template.built is not None else \
        dict(template.given)
    return {"kind": template.kind, **{k: list(v) if isinstance(v, tuple) else v
                                      for k, v in values.items()}}


def relieved(scenario: Scenario, people: list[PlacedPerson], result: FitResult,
             say: Callable[[str], None] | None = None,
             cancel: Callable[[], bool] | None = None) -> FitResult:
    """The fit `result` after the scenario's `[relief]` rounds (`relieve_fit`; itself without
    any): the surface `run_fit` writes, for those that relax onto it."""
    if not scenario.relief.rounds:
        return result
    _, persons, maps = evaluate_fit(scenario, people, result)
    return relieve_fit(scenario, people, result, persons, maps, say, cancel=cancel)[0]


def checked_guarantees(checked: list, fit: FitResult) -> tuple[dict, float | None] | None:
    """The guarantees of `fit` and the seconds their check took, from `checked` ((fit,
    guarantees, seconds) of the fits checked so far), or None when it is not among them."""
    return next(((g, seconds) for f, g, seconds in checked if f is fit), None)


def relieve_fit(scenario: Scenario, people: list[PlacedPerson], result: FitResult,
                persons: list[dict], maps: list, say: Callable[[str], None] | None = None,
                cancel: Callable[[], bool] | None = None,
                checked: list | None = None) -> tuple:
    """The scenario's rounds of pressure relief (`solver.scene.relief.relieve`) after its fit
    `result` with its figures: (result, persons, maps, Relief), the fit kept and its
    figures; `cancel` as `relieve` takes it (each fit is given it too); a fit kept must also
    miss none of the surface's bars (`fit_guarantees`) that the first met. `checked`, a list,
    receives (fit, guarantees, seconds) of every fit whose guarantees were checked (the kept
    fit's among them: the caller need not check it again); a fit it holds already (the first,
    judged by the caller) is not checked again."""
    from solver.scene.quality import surface_miss_kinds
    from solver.scene.relief import relieve

    params, first_missed = scenario.surface.params, None
    checked = [] if checked is None else checked

    tell = say or (lambda message: None)

    def evaluate(candidate: FitResult):
        tell(f"relief: evaluating {len(people)} person(s) on the refitted surface")
        return evaluate_fit(scenario, people, candidate)[1:]

    def missed(fit: FitResult) -> dict:
        known = checked_guarantees(checked, fit)
        if known is None:
            known = _timed(fit_guarantees, fit, people, params)
            checked.append((fit, *known))
        return {kind: text for kind, text in surface_miss_kinds(known[0])}

    def check(candidate: FitResult) -> str | None:  # the surface's bars the first fit met
        nonlocal first_missed
        if first_missed is None:  # (checked only once a fit gets this far)
            first_missed = missed(result)
        new = [text for kind, text in missed(candidate).items() if kind not in first_missed]
        return f"the surface misses a bar it met: {new[0]}" if new else None

    return relieve(scenario, people, result, persons, maps,
                   fit=lambda targets: fit_people(scenario, targets, lambda i, e, tau: tell(
                       f"relief fit: iteration {i}: energy {e:.6g}"), cancel=cancel),
                   evaluate=evaluate, rounds=scenario.relief.rounds,
                   target=scenario.relief.target, say=say, cancel=cancel, check=check)


def run_fit(scenario_path: str | os.PathLike | Scenario, out_dir: str | os.PathLike, *,
            db: str | os.PathLike | None = None,
            progress: Callable[[str], None] | None = None, formats=("obj", "ply", "glb"),
            unit: str | None = None, up: str | None = None,
            workshop: WorkshopOptions | None = None, pictures: bool = True,
            beside: bool | None = None, fitted: FitResult | None = None,
            title: str | None = None, judged: tuple[dict, float | None] | None = None
            ) -> dict:
    """Fits a scenario and writes everything into `out_dir` (`sitrelax fit`).

    Parameters
    ----------
    scenario_path : a scenario file (TOML), or a `Scenario` parsed already.
    out_dir : folder for the surface, control mesh, bodies, pictures and report.json.
    db : the pose library that `db:` poses come from.
    progress : optional callback taking one line of news per stage and iteration.
    workshop : `solver.scene.workshop.WorkshopOptions`, optional: also a solid (STL, 3MF),
        the cutter reach (reach.png) and drawings (DXF, sections.png), with their figures
        under the report's "fabrication".
    formats : the surface's file formats, of `SURFACE_FORMATS` ("3dm": scene.3dm, a Rhino
        document with the control net, the NURBS or limit-mesh surface and the bodies).
    unit, up : the files' length unit ("m", "cm", "mm", "in", "ft") and up axis ("y", "z");
        None: m and Y up for OBJ and PLY, mm and Z up for .3dm (GLB: always m and Y up).
    pictures : False skips scene.png, pressure.png and pressure_map.png (the report's
        "pictures" says so); the workshop's pictures are made when asked for.
    beside : the guarantees' check on a second thread beside the evaluation, then the design
        sheet there beside the exports; None (the default): when the machine has more than one
        core; False: all in this thread, in turn (a batch's workers, one per core).
    fitted : the scenario's fit made already (the studio's, as on screen): written as it is,
        not fitted again (its control mesh must be the scenario's).
    title : the design sheet's title (default: the scenario file's name).
    judged : with `fitted`: its guarantees (`fit_guarantees`) and the seconds their check took,
        when checked already (the studio's, of the fit on screen): not checked again.

    Returns
    -------
    dict, the report as written to report.json (lengths m, pressures kPa, times s; the
    surface's limit figures in mm under surface_limit).
    """
    say = progress or (lambda message: None)
    if not formats or set(formats) - set(SURFACE_FORMATS):  # checked before the fit's work
        raise ExportError(f"Expected surface formats among {SURFACE_FORMATS}, got "
                          f"{list(formats)}")
    frame_matrix(unit or "m", up or "y")
    timing = {}
    start = time.perf_counter()
    if isinstance(scenario_path, Scenario):
        scenario, scenario_path = scenario_path, scenario_path.path
    else:
        scenario = load_scenario(scenario_path)
    # written whole or not at all: the folder's earlier result, if any, stays until this one is
    # complete and then goes (gone again if made and nothing could be posed or fitted)
    read = [scenario_path, db, scenario.surface.source]  # (the source: a control mesh's path)
    _refuse_overwriting(read, Path(out_dir), ("control.obj", "report.json"))  # (before the work)
    with results_folder(out_dir, _sparing(previous_results, read), "report.json") as out:
        t = time.perf_counter()
        scenario, people = place_scene(scenario, db)
        timing["pose_s"] = time.perf_counter() - t
        say(f"posed {len(people)} person(s) in {timing['pose_s']:.2f} s")
        t = time.perf_counter()
        relief, checked = None, []  # (the rounds of relief, and the fits they checked)
        if fitted is None:
            result = fit_people(scenario, people, lambda i, e, tau: say(
                f"iteration {i}: energy {e:.6g} (tau {tau:.2f})"))
            timing["fit_s"] = time.perf_counter() - t
            say(f"fitted in {result.iterations} iterations, {timing['fit_s']:.2f} s: "
                f"{result.stop_reason}")
            if scenario.relief.rounds:  # evaluated first: the rounds start from its figures
                t = time.perf_counter()
                _, persons, maps = evaluate_fit(scenario, people, result)
                timing["evaluate_s"] = time.perf_counter() - t
                t = time.perf_counter()
                result, persons, maps, relief = relieve_fit(scenario, people, result, persons,
                                                            maps, say, checked=checked)
                timing["relief_s"] = time.perf_counter() - t
                if relief.kept:  # (the report is of the kept fit)
                    timing["first_fit_s"], timing["fit_s"] = timing["fit_s"], result.seconds
        else:
            if fitted.faces.shape != scenario.surface.faces.shape or \
                    not np.array_equal(fitted.faces, scenario.surface.faces):
                raise ValueError("Expected a fit of the scenario's control mesh, got one of "
                                 "another mesh")
            result, timing["fit_s"] = fitted, fitted.seconds  # (its own, when it was made)
            if judged is not None:
                checked.append((result, *judged))
            say(f"the fit given ({result.iterations} iterations: {result.stop_reason})")
        # the guarantees' check, then the design sheet, on a second thread: the check beside
        # the evaluation, the sheet beside the exports (their numpy, PNG compression and file
        # writes let go of the interpreter; libigl's queries do not); the BLAS limit is held
        # around both, so the second thread's stays at the solver's count while the
        # evaluation's own limits come and go
        record = None if relief is None else relief.record()
        beside = (os.cpu_count() or 1) > 1 if beside is None else beside
        with limited_threads(), ThreadPoolExecutor(1, "sitrelax-beside") as pool:
            submit = pool.submit if beside else _now
            known = checked_guarantees(checked, result)
            checking = _now(lambda: known) if known is not None else \
                submit(_timed, fit_guarantees, result, people, scenario.surface.params)
            if relief is None:
                t = time.perf_counter()
                _, persons, maps = evaluate_fit(scenario, people, result)
                timing["evaluate_s"] = time.perf_counter() - t
            if pictures:  # (after the check on the one thread beside: it waits for no one)
                title = title or (Path(scenario_path).stem if scenario_path else "scenario")
                sheet = submit(_timed, _design_sheet, out / "sheet.png", title, result,
                               people, maps, checking, persons, dict(timing),
                               scenario.surface.params.creases, record)
            t = time.perf_counter()
            files = export_scene(out, result, people, maps, formats=tuple(formats),
                                 unit=unit, up=up, creases=scenario.surface.params.creases,
                                 pictures=pictures)
            timing["export_s"] = time.perf_counter() - t
            fabrication = _workshop(out, result, people, workshop, files, timing, say,
                                    scenario.surface.params.creases)
            guarantees, timing["guarantees_s"] = checking.result()
            if pictures:
                files["sheet_png"], timing["sheet_s"] = sheet.result()
        timing["total_s"] = time.perf_counter() - start
        report = {
            "scenario": str(scenario_path),
            "parameters": report_parameters(scenario),
            "iterations": result.iterations,
            "stop_reason": result.stop_reason,
            "energies": result.energies,
            "energy_terms": result.energy_terms,
            "timing": timing,
            "control_vertices": int(len(result.control)),
            "surface_vertices": int(len(result.surface)),
            "persons": persons,
            "relief": record,
            "surface_limit": files.pop("surface_limit"),
            "guarantees": guarantees,
            "misses": report_misses(guarantees, persons),
            "pictures": pictures,
            "files": files,
        }
        if fabrication is not None:
            report["fabrication"] = fabrication
        write_atomic(out / "report.json",
                     json.dumps(report, indent=2, allow_nan=False).encode())
        _refuse_overwriting(read, Path(out_dir), [p.name for p in out.iterdir()])
    return report


def report_misses(guarantees: dict, persons: list[dict]) -> list[str]:
    """Every bar the fit misses (`solver.scene.quality`: the surface's, then each person's),
    one line each; none when it meets them all."""
    from solver.scene.quality import person_misses, surface_misses

    return surface_misses(guarantees) + [m for p in persons for m in person_misses(p)]


SURFACE_FORMATS = ("obj", "ply", "glb", "3dm")


def previous_results(folder: Path, listing: type = dict) -> set[str]:
    """The files of the result written into `folder` before: report.json and the names its
    "files" lists (none without a readable report). `listing`: what the command's report
    lists its files in (`run_fit`'s and `sitrelax design`'s a dict, `run_relax`'s a list); a
    folder holding the other command's result is refused (ValueError): its report.json would
    be replaced and its files mixed with these."""
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return set()
    if not isinstance(report, dict) or not isinstance(report.get("files"), (dict, list)):
        return set()
    if not isinstance(report["files"], listing):
        held = "a relaxation's" if isinstance(report["files"], list) else "a fit's"
        raise ValueError(f"{folder} holds {held} results (its report.json): give this command "
                         f"a folder of its own (--out)")
    names = {"report.json"}

    def collect(value) -> None:
        if isinstance(value, str):
            names.add(value)
        elif isinstance(value, list):
            for item in value:
                collect(item)
        elif isinstance(value, dict):
            for item in value.values():
                collect(item)

    collect(report["files"])
    return names


def _inputs(read) -> set[Path]:
    """The files among `read` (paths, or None, or other text), resolved."""
    return {Path(path).resolve() for path in read
            if isinstance(path, (str, os.PathLike)) and os.path.isfile(path)}


def _refuse_overwriting(read, folder: Path, names) -> None:
    """A ValueError when a result of these `names` would replace a file this run reads (`read`)
    in `folder`: a scenario whose control mesh is the folder's control.obj, fitted into it,
    would lose its start to the fitted net."""
    inputs = _inputs(read)
    for name in names:
        if (folder / name).resolve() in inputs:
            raise ValueError(f"{folder / name} is a file this fit reads, and the fit writes a "
                             f"{name} of its own there: give --out another folder (or rename "
                             f"the file the scenario reads)")


def _sparing(previous: Callable[[Path], set], read) -> Callable[[Path], set]:
    """`previous` (the earlier result's files, which a new result replaces) without the files
    this run reads (`read`: paths, or None, or other text): a scenario that `sitrelax design`
    wrote into the folder, fitted into the same folder, stays."""
    def listed(folder: Path) -> set:
        inputs = _inputs(read)
        return {name for name in previous(folder) if (folder / name).resolve() not in inputs}
    return listed


def _timed(func: Callable, *args):
    """func(*args) and the seconds it took."""
    t = time.perf_counter()
    return func(*args), time.perf_counter() - t


def _now(func: Callable, *args) -> Future:
    """func(*args) called now, as a finished future (`run_fit`'s work in turn)."""
    done = Future()
    done.set_result(func(*args))
    return done


def _design_sheet(path: Path, title: str, result: FitResult, people: list[PlacedPerson],
                  maps: list, checking: Future, persons: list[dict], timing: dict,
                  creases=(), relief: dict | None = None) -> str:
    """`run_fit`'s sheet.png once the guarantees' check (`checking`) is done; its name."""
    from solver.scene.sheet import write_design_sheet

    guarantees, _ = checking.result()
    write_design_sheet(path, title, result.limit_surface(creases), result.surface_faces, people,
                       maps, {"guarantees": guarantees, "persons": persons, "timing": timing,
                              "iterations": result.iterations, "relief": relief})
    return path.name


def fit_guarantees(result: FitResult, people: list[PlacedPerson], params) -> dict:
    """`solver.surface.guarantees.surface_guarantees` of the limit surface that `surface.*`
    holds (the level-s quads at their limit points; the level's creases are no folds), against
    the posed bodies, with the fit's margin and floor (`params`, the `FitParams`)."""
    from solver.surface.guarantees import surface_guarantees

    sub = result.subdivision
    if sub is None:
        raise ValueError("Expected a FitResult that carries its subdivision, got none")
    limit = result.limit_surface(params.creases)
    sharp = sub.steps[-1].creases if sub.level > 0 else \
        (np.asarray(params.creases, dtype=np.int64).reshape(-1, 2) if params.creases else None)
    return surface_guarantees(limit, result.surface_faces,
                              [(p.vertices, p.triangles) for p in people], params.margin,
                              getattr(params, "floor", 0.0), sharp_edges=sharp)


def _workshop(out: Path, result: FitResult, people: list[PlacedPerson], workshop, files: dict,
              timing: dict, say, creases=()) -> dict | None:
    """The workshop's files (solid, reach, drawings) of the limit surface, as `surface.*` hold
    it, when asked for: adds them to `files` and their time to `timing`; their figures (the
    report's "fabrication"), or None."""
    if workshop is None or not workshop.any:
        return None
    from solver.scene.workshop import export_workshop

    t = time.perf_counter()
    limit = result.limit_surface(creases)
    more, fabrication = export_workshop(out, limit, result.surface_faces, people, workshop)
    files.update(more)
    timing["workshop_s"] = time.perf_counter() - t
    problem = (fabrication.get("solid") or {}).get("problem")
    say(f"workshop files: {', '.join(sorted(more))}" if more else
        f"workshop files: none written{f' ({problem})' if problem else ''}")
    return fabrication


def export_scene(out: Path, result: FitResult, people: list[PlacedPerson],
                 settles: list[PressureMap], *, formats=("obj", "ply", "glb"),
                 unit: str | None = None, up: str | None = None, creases=(),
                 pictures: bool = True) -> dict:
    """Surface, control mesh, posed bodies, pictures and the pressure mats' maps; returns the
    file names (and under "surface_limit" the limit surface's figures, `CadSurface.figures`).
    The surface files hold the limit surface (`solver.scene.cad`): OBJ/PLY/GLB the
    level-s quads at their limit points, `scene.3dm` (with "3dm" in `formats`) NURBS for a
    grid control net. `unit` and `up` (None: metres and Y up for OBJ and PLY, millimetres and
    Z up for .3dm) apply to every file but GLB (glTF: metres, Y up). `pictures` False: no
    PNG."""
    from solver.scene.cad import cad_surface, write_scene_3dm

    files = {}
    # the pictures and colours show what the surface presses (the floor under the feet, 30 to 80
    # kPa on a hard floor, would leave the seat's few kPa without colour)
    maps = [surface_pressure(m) for m in settles]
    frame = {"unit": unit or "m", "up": up or "y"}
    files["control_obj"] = write_mesh(
        out / "control.obj", result.control, result.faces, **frame,
        comment="sitrelax control mesh (quads) of a Catmull-Clark surface: boundary vertices "
                "on cubic B-splines of the boundary points, one-face corners kept;\n"
                "surface.* holds its limit surface").name
    cad = cad_surface(result, creases)
    files["surface_limit"] = cad.figures
    contact = _contact_colors(result.surface, people)
    level = cad.figures["level"]
    for suffix in [f".{f}" for f in formats if f != "3dm"]:
        name = f"surface{suffix}"
        write_mesh(out / name, cad.vertices, cad.faces,
                   vertex_colors=None if suffix == ".obj" else contact,
                   comment=f"sitrelax limit surface: the level-{level} quads with every vertex "
                           f"at its Catmull-Clark limit point",
                   **(frame if suffix != ".glb" else {}))
        files[f"surface_{suffix[1:]}"] = name
    peak = max([float(m.max()) for m in maps] + [1.0])
    bodies, bodies_obj = [], []
    for k, (p, pressure) in enumerate(zip(people, maps), start=1):
        colors = field_colors(pressure, 0.0, peak)
        write_mesh(out / f"person_{k}.ply", p.vertices, p.body.faces, vertex_colors=colors,
                   **frame)
        write_mesh(out / f"person_{k}.obj", p.vertices, p.body.faces, **frame)
        bodies.append(f"person_{k}.ply")
        bodies_obj.append(f"person_{k}.obj")
    files["bodies"] = bodies  # (with the pressure as vertex colours)
    files["bodies_obj"] = bodies_obj
    if "3dm" in formats:
        labels = [(f"person {k}", p.label.split(" (")[0]) for k, p in enumerate(people, 1)]
        names = [a if a == b else f"{a}: {b}" for a, b in labels]
        write_scene_3dm(out / "scene.3dm", result, cad, [(p.vertices, p.body.faces)
                                                         for p in people], names,
                        unit=unit or "mm", up=up or "z")
        files["scene_3dm"] = "scene.3dm"
    if pictures:
        _scene_pictures(out, result, people, maps, peak, files)
    grids = mat_maps(result, people, settles, creases)
    if grids:
        write_pressure_csv(out / "pressure_map.csv", grids)
        files["pressure_map_csv"] = "pressure_map.csv"
        if pictures:
            render_pressure_maps(out / "pressure_map.png", grids,
                                 title="Pressure as a mat on each support shows it (kPa)")
            files["pressure_map_png"] = "pressure_map.png"
    return files


def _scene_pictures(out: Path, result: FitResult, people: list[PlacedPerson],
                    maps: list[np.ndarray], peak: float, files: dict) -> None:
    """scene.png and pressure.png, added to `files`."""
    # the bodies in the scene carry their pressure, on the same scale as pressure.png
    scene = [MeshView(result.surface, result.surface_faces, SURFACE)] + [
        MeshView(p.vertices, p.body.faces, pressure_on_skin(m, peak))
        for p, m in zip(people, maps)]
    render_panels(out / "scene.png", [Panel(scene, "three-quarter", "fitted surface"),
                                      Panel(scene, "side", "side")], columns=2,
                  colorbar=("pressure from the surface, kPa", 0.0, peak))
    files["scene_png"] = "scene.png"
    panels = [Panel([MeshView(p.vertices, p.body.faces, field_colors(m, 0.0, peak))], "below",
                    f"{p.label}: peak {float(m.max()):.1f} kPa") for p, m in zip(people, maps)]
    render_panels(out / "pressure.png", panels, columns=min(3, len(panels)),
                  colorbar=("pressure from the surface, kPa", 0.0, peak))
    files["pressure_png"] = "pressure.png"


def mat_maps(result: FitResult, people: list[PlacedPerson],
             settles: list[PressureMap], creases=()) -> list[PressureGrid]:
    """The pressure mats' grids: per person at rest, one per support part it loads (the
    surface's draped on its limit surface, where the settle's contacts lie, the floor's on the
    floor), named "person: support"; `creases` as the fit's (for a result that does not carry
    its limit surface)."""
    grids = []
    limit = result.limit_surface(creases)
    for p, m in zip(people, settles):
        if not m.settled.stable:
            continue
        footprint = contact_footprint(m.settled, len(p.vertices))
        for c in m.settled.contacts:
            on_surface = c.faces.min() >= 0
            grid = pressure_grid(c, limit if on_surface else None,
                                 result.surface_faces if on_surface else None, footprint)
            if grid.pressure_kpa.size:
                grids.append(dataclasses.replace(grid, name=f"{p.label.split(' (')[0]}: "
                                                            f"{c.name}"))
    return grids


def pressure_on_skin(pressure: np.ndarray, peak: float) -> np.ndarray:
    """Per body vertex: the pressure colour where the body is pressed, skin elsewhere."""
    colors = field_colors(pressure, 0.0, peak)
    colors[pressure <= 0] = SKIN
    return colors


def _contact_colors(surface: np.ndarray, people: list[PlacedPerson]) -> np.ndarray:
    """Per surface vertex: blue where no body is near, warm where a body rests (within 3 cm)."""
    from solver.contact.skins import vertex_tree

    points = np.concatenate([p.vertices for p in people])
    dist, _ = vertex_tree(points).query(surface)  # one person's: the evaluation's tree
    near = np.clip(1.0 - dist / 0.03, 0.0, 1.0)
    base = np.array(SURFACE)
    warm = np.array([0.95, 0.55, 0.2])
    return base[None, :] * (1 - near[:, None]) + warm[None, :] * near[:, None]


def run_relax(scenario_path: str | os.PathLike, out_dir: str | os.PathLike, *,
              surface_dir: str | os.PathLike | None = None, person: int | None = None,
              db: str | os.PathLike | None = None, save: bool = False,
              progress: Callable[[str], None] | None = None,
              lock_timeout: float | None | str = "default") -> dict:
    """Relaxes the scenario's people onto a surface and writes the results (`sitrelax relax`).

    Parameters
    ----------
    scenario_path : a scenario file (TOML).
    out_dir : folder for the relaxed bodies (OBJ), their poses (BVH), relax.png and
        report.json (made if missing).
    surface_dir : the surface to relax onto: an earlier `sitrelax fit` result's folder (its
        surface.obj, else surface.ply, else surface.glb: `surface_file`) or a surface file
        (.obj, .ply, .glb; in the unit and up axis it states). None: fit the scenario now,
        with its rounds of relief, as `run_fit` writes surface.obj.
        The body may sink into the surface by the softness margin it was fitted with, and
        presses the foam it was fitted for (stiffness, thickness, the cover's friction): a
        fit's own (its report.json beside the file, `fitted_material`), whatever the
        scenario's `surface.margin` and `evaluation` say; the scenario's for a surface without
        a fit's report (from CAD) or fitted now. The report's `margin_m`, `foam` and
        `margin_from` say which.
    person : only this person (1-based; None: everybody).
    db : the pose library for `db:` poses, and where `save` stores the relaxed poses.
    save : store each relaxed pose in `db`, linked to its origin (see `save_relaxed`); the
        library is checked first, before any work (`check_library_for_save`).
    progress : optional callback taking one line of news per stage.
    lock_timeout : seconds to wait for another writer of `db` when saving (None: as long as
        it runs; "default": $SITRELAX_LOCK_TIMEOUT or the library's default).

    Returns
    -------
    dict, the report as written to report.json (each person's figures before and after).
    """
    from capture import Motion, write_bvh

    from solver.body.relax import RelaxError
    from solver.body.rig import pose_channels, rig_skeleton

    say = progress or (lambda message: None)
    start = time.perf_counter()
    if save and db is None:
        raise RelaxError("Saving relaxed poses needs a pose library (--db)")
    scenario = load_scenario(scenario_path)
    if person is not None and not 1 <= person <= len(scenario.persons):
        raise RelaxError(f"Expected --person in 1..{len(scenario.persons)}, got {person}")
    chosen = range(len(scenario.persons)) if person is None else [person - 1]
    # what can be refused without the work is refused before it: the surface, the library
    scenario_margin = scenario.surface.params.margin
    margin, margin_from = scenario_margin, "scenario"
    if surface_dir is not None:
        source = surface_file(surface_dir)
        surface, faces = _read_surface(source)
        material = fitted_material(source)
        if material is not None:  # the surface's own, as fitted
            (margin, fitted_foam), margin_from = material, "surface"
            scenario = dataclasses.replace(
                scenario, evaluation=scenario.evaluation.model_copy(update=fitted_foam))
    foam = {key: getattr(scenario.evaluation, key) for key in SURFACE_FOAM}  # judged with
    if save:
        check_library_for_save(db, lambda seconds: say(
            f"waiting for another writer of {db} to finish: {seconds:.0f} s"), lock_timeout)
    # written whole or not at all, in place of an earlier relaxation's result (not a fit's)
    with results_folder(out_dir, lambda folder: previous_results(folder, list),
                        "report.json") as out:
        scenario, people = place_scene(scenario, db)
        if surface_dir is not None:
            _within_reach(surface, [people[k] for k in chosen])
            _facing_people(surface, faces, [people[k] for k in chosen], source)
            say(f"surface from {source}")
            if margin_from == "surface":
                say(f"margin {margin * 100:g} cm and foam ({foam_text(foam)}), "
                    f"the surface's own (its fit's report.json)" +
                    (f", not the scenario's {scenario_margin * 100:g} cm"
                     if margin != scenario_margin else ""))
            else:
                say(f"margin {margin * 100:g} cm and foam ({foam_text(foam)}), "
                    f"the scenario's (no fit's report.json beside {source.name})")
        else:
            result = fit_people(scenario, people)  # relaxed onto its limit surface, as evaluated
            say(f"fitted the surface in {result.iterations} iterations")
            result = relieved(scenario, people, result, say)  # (as surface.obj holds it)
            surface = result.limit_surface(scenario.surface.params.creases)
            faces = result.surface_faces
        keys = ("mean_support_distance_m", "max_penetration_m", "coverage", "contact_coverage",
                "peak_pressure_kpa", "supported", "equilibrium")
        rows, meshes_before, meshes_after, relaxed = [], [], [], []
        for k in chosen:
            p = people[k]
            res, before, after, seconds = relax_person(scenario, p, surface, faces,
                                                       margin=margin)
            name = f"person_{k + 1}_relaxed"
            write_mesh(out / f"{name}.obj", res.vertices, p.body.faces)
            skeleton, _ = rig_skeleton(p.body)
            channels = pose_channels(p.body, res.local, res.world.positions[0])
            write_bvh(out / f"{name}.bvh", skeleton, Motion(channels[None], 1 / 30))
            rows.append({"name": p.label, "seconds": seconds, "evaluations": res.evaluations,
                         "parameters_at_limit": res.at_limit,
                         "before": {key: before[key] for key in keys},
                         "after": {key: after[key] for key in keys},
                         "relaxation": relax_record(res),
                         "files": [f"{name}.obj", f"{name}.bvh"]})
            relaxed.append((p, res))
            meshes_before.append(MeshView(p.vertices, p.body.faces))
            meshes_after.append(MeshView(res.vertices, p.body.faces, (0.62, 0.78, 0.62)))
            say(f"{p.label}: relaxed in {seconds:.2f} s; mean support distance "
                f"{before['mean_support_distance_m'] * 100:.1f} -> "
                f"{after['mean_support_distance_m'] * 100:.1f} cm; {relax_text(res)}")
        surf_view = MeshView(surface, faces, SURFACE)
        render_panels(out / "relax.png", [Panel([surf_view] + meshes_before, "side", "before"),
                                          Panel([surf_view] + meshes_after, "side", "after")],
                      columns=2)
        # stored last, once every file but the report is written: a relaxation whose results
        # fail to be written leaves no pose behind in the library
        if save:
            for row, saved in zip(rows, save_relaxed(db, relaxed, str(surface_dir or "fitted"),
                                                        lock_timeout)):
                row["saved_pose"] = saved
                say(f"{row['name']}: saved as pose {saved['name']!r} ({saved['id']})")
        report = {"scenario": str(scenario_path), "surface": str(surface_dir or "fitted"),
                  "margin_m": margin, "margin_from": margin_from,
                  "foam": foam,
                  "persons": rows,
                  "timing": {"total_s": time.perf_counter() - start},
                  "files": ["relax.png"] + [name for row in rows for name in row["files"]]}
        write_atomic(out / "report.json", json.dumps(report, indent=2, allow_nan=False).encode())
    return report


SURFACE_FILES = ("surface.obj", "surface.ply", "surface.glb")  # a fit's, in `relax`'s order


def surface_file(given: str | os.PathLike) -> Path:
    """The surface file `sitrelax relax --surface` names: the file itself, or in a `sitrelax
    fit` folder the first of `SURFACE_FILES` there (every mesh format `fit --format` writes).
    A RelaxError naming the path when there is none (saying so of a folder holding only a
    scene.3dm, which relax does not read)."""
    from solver.body.relax import RelaxError
    from solver.io.obj import SURFACE_SUFFIXES

    path = Path(given)
    if path.is_dir():
        for name in SURFACE_FILES:
            if (path / name).is_file():
                return path / name
        rhino = ("; its scene.3dm is not read: fit again with --format obj (or ply, glb)"
                 if (path / "scene.3dm").exists() else "")
        raise RelaxError(f"Expected a `sitrelax fit` folder holding {', '.join(SURFACE_FILES)}"
                         f", got {path}, which holds none of them{rhino}")
    if not path.exists():
        raise RelaxError(f"Expected a `sitrelax fit` folder or a surface file "
                         f"({', '.join(SURFACE_SUFFIXES)}), got {path}: no such file or "
                         f"folder")
    return path


SURFACE_FOAM = ("foam_stiffness", "foam_thickness", "friction")  # the surface's own material,
# with its margin: what a fit's report gives a relaxation onto its surface


def fitted_material(path: Path) -> tuple[float, dict] | None:
    """The softness margin (m) and the foam (`SURFACE_FOAM` of the scenario's `evaluation`:
    stiffness, thickness, the cover's friction) of the fit that wrote the surface file `path`,
    from its report.json (`parameters.margin`, `parameters.evaluation`) when a `sitrelax fit`
    report beside the file lists it; None otherwise (a surface from CAD). A RelaxError naming
    the report when it cannot be read or its values are not what a scenario may hold (the
    foam of a report without one is the scenario's)."""
    from pydantic import TypeAdapter, ValidationError

    from solver.body.relax import RelaxError
    from solver.scene.schema import FIT_FIELDS, Evaluation

    report_path = path.parent / "report.json"
    if not report_path.exists():
        return None
    try:
        report = json.loads(report_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RelaxError(f"Expected the report of the fit that wrote {path.name}, but "
                         f"{report_path} cannot be read ({exc}): mend or remove it (without "
                         f"it the scenario's margin and foam are used)") from None
    files = report.get("files") if isinstance(report, dict) else None
    if not isinstance(files, dict) or path.name not in files.values():
        return None  # (another command's report, or a file the fit did not write)
    params = report.get("parameters")
    margin = params.get("margin") if isinstance(params, dict) else None
    try:  # (a scenario's bounds: 0-0.5 m)
        TypeAdapter(FIT_FIELDS["margin"]).validate_python(
            float(margin) if isinstance(margin, int) and not isinstance(margin, bool)
            else margin)
    except ValidationError as exc:
        raise RelaxError(f"Expected the fit's margin in metres in {report_path} "
                         f"(parameters.margin): {exc.errors()[0]['msg']}, got "
                         f"{margin!r}") from None
    given = params.get("evaluation")
    given = given if isinstance(given, dict) else {}
    foam = {key: given[key] for key in SURFACE_FOAM if key in given}
    try:
        Evaluation.model_validate(foam)
    except ValidationError as exc:
        raise RelaxError(f"Expected the fit's foam in {report_path} (parameters.evaluation): "
                         f"{exc.errors()[0]['loc'][0]}: {exc.errors()[0]['msg']}") from None
    return float(margin), foam


def check_library_for_save(db: str | os.PathLike,
                           on_wait: Callable[[float], None] | None = None,
                           lock_timeout: float | None | str = "default") -> None:
    """Refuses a pose library `save_relaxed` could not store into, before any work and with
    the pose library's own errors (those `sitrelax db` commands give): missing, a folder, no
    pose library, damaged, read-only, or locked by another writer past the lock timeout
    ($SITRELAX_LOCK_TIMEOUT). The checks a change (`PoseLibrary.edit`) makes before it
    writes, without writing. `on_wait(seconds waited)`, about once a second while another
    writer holds the library; `lock_timeout` as `PoseLibrary` takes it."""
    from posedb import PoseLibrary

    PoseLibrary(db, on_wait=on_wait, lock_timeout=lock_timeout).check_changeable()


def _read_surface(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A surface to relax onto (`sitrelax relax --surface`, `read_surface_mesh`: OBJ, PLY,
    GLB), in metres, Y up: vertices (V, 3) and faces, (F, 4) quads or (F, 3) triangles; a
    RelaxError naming the file when it cannot be read or reaches past MAX_COORDINATE."""
    from solver.body.relax import RelaxError
    from solver.io.obj import MeshFileError, read_surface_mesh
    from solver.scene.schema import MAX_COORDINATE

    try:
        surface, faces = read_surface_mesh(path)
    except MeshFileError as exc:
        raise RelaxError(f"Expected a surface to relax onto: {exc}") from None
    far = np.flatnonzero(~(np.abs(surface) <= MAX_COORDINATE).all(axis=1))
    if len(far):
        raise RelaxError(f"Expected a surface within {MAX_COORDINATE:g} m of the "
                         f"origin: {path} has vertex {far[0] + 1} at "
                         f"{surface[far[0]].tolist()} m" +
                         (f" and {len(far) - 1} more beyond" if len(far) > 1 else ""))
    return surface, faces


def _within_reach(surface: np.ndarray, people: list[PlacedPerson]) -> None:
    """A RelaxError for a person whose supported skin lies wholly beyond the fit's REACH of the
    surface's vertices (nothing there to relax onto), as a fit refuses one."""
    from scipy.spatial import cKDTree

    from solver.body.relax import RelaxError
    from solver.surface.fit import REACH

    tree = cKDTree(surface)
    for p in people:
        points = p.vertices[p.importance > 0] if np.any(p.importance > 0) else p.vertices
        nearest = float(tree.query(points)[0].min())
        if nearest > REACH:
            raise RelaxError(f"{p.label} is entirely outside the surface's reach: its nearest "
                             f"supported point is {nearest:.2f} m from the surface (reach "
                             f"{REACH} m); move the person or the surface")


def _facing_people(surface: np.ndarray, quads: np.ndarray, people: list[PlacedPerson],
                   path: Path) -> None:
    """A RelaxError for a surface whose faces point away from a person
    (`solver.contact.evaluate.facing_away_share`), as a fit refuses such a control mesh: the
    relaxation would pull the skin onto the surface's back. surface : (N, 3) metres;
    quads : (F, 4) quads or (F, 3) triangles."""
    from solver.body.relax import RelaxError
    from solver.contact.evaluate import facing_away_share
    from solver.mesh import SurfaceMesh

    mesh = SurfaceMesh.from_faces(surface, quads)
    for p in people:
        share = facing_away_share(mesh, p)
        if share is not None and share > 0.5:
            raise RelaxError(f"Expected a surface whose faces point towards the people: "
                             f"{share:.0%} of {p.label}'s supported skin near it faces the same "
                             f"way as {path}; flip it (reverse each face's vertex order)")


def save_relaxed(db: str | os.PathLike, relaxed: list, surface: str,
                 lock_timeout: float | None | str = "default") -> list[dict]:
    """Stores relaxed poses in the pose library, all in one commit: each as a one-frame take
    in the body's rig (origin "relaxed", source: the pose it came from, a library pose id or
    the BVH reference) and a pose "<origin>-relaxed" carrying the origin's tags, "relaxed" and
    the parts it was supported on. The scene's placement is undone: the pose is stored in its
    own frame (the captured pose's), with where the relaxation left it relative to the standard
    placement (`posedb.PosePlacement`, `solver.scene.placement.relaxed_placement`), so that put
    back into the scenario at the same position and rotation it stands where it was relaxed to.
    relaxed : [(PlacedPerson, RelaxResult)]; lock_timeout : as `PoseLibrary` takes it (seconds
    to wait for another writer)."""
    from posedb import PoseLibrary, PosePlacement

    from solver.body.rig import pose_channels, rig_skeleton
    from solver.scene.placement import relaxed_placement

    lib = PoseLibrary(db, lock_timeout=lock_timeout)
    taken = {p.name for p in lib.poses()} | {t.name for t in lib.takes()}
    saved = []
    with lib.edit() as ed:
        for person, res in relaxed:
            ref = person.spec.pose
            if ref.startswith("db:"):
                origin = lib.pose(ref[3:])
                source, base, tags = origin.id, origin.name, origin.tags
            else:
                # "bvh:bundled:NAME.bvh#frame=N" or "bvh:PATH.bvh#...": the file's stem
                source, base, tags = ref, Path(ref.split("#")[0].split(":")[-1]).stem, ()
            # the pose "<base>-relaxed" and its take "<base>-relaxed-take" (takes and poses
            # share one namespace)
            name, k = f"{base}-relaxed", 2
            while name in taken or f"{name}-take" in taken:
                name, k = f"{base}-relaxed-{k}", k + 1
            taken |= {name, f"{name}-take"}
            rot, shift = person.transform[:3, :3], person.transform[:3, 3]
            local = res.local.copy()
            local[0] = rot.T @ local[0]
            root = rot.T @ (res.world.positions[0] - shift)
            skeleton, _ = rig_skeleton(person.body)
            notes = f"relaxed from {ref} onto the surface {surface}"
            tid = ed.add_take(skeleton, pose_channels(person.body, local, root)[None], 1 / 30,
                              name=f"{name}-take", source=source, origin="relaxed",
                              notes=notes)
            offset, heading = relaxed_placement(person, res.vertices, res.world.positions[0])
            pid = ed.add_pose(tid, 0, name, tags=tuple(tags) + ("relaxed",),
                              supports=person.spec.support, notes=notes,
                              placement=PosePlacement(offset, heading))
            saved.append({"id": pid, "name": name, "take": tid, "origin": source})
    return saved
