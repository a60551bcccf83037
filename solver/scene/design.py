"""`sitrelax design`: furniture from poses alone. Each pose is classified (`solver.body.posture`),
a template chosen for them all (`DESIGNS`), the people set side by side, the template built
around them, and the scenario written (scenario.toml, loadable by `sitrelax fit`) and fitted by
`run_fit`, the same path as `sitrelax fit`.

    posture    one person       several (side by side)           support (a use)
    seated     chair (back)     bench with a back, a seat each   chair
                                (each measured as their chair)
    perched    stool            bench (backless)                 stool
    reclined   lounger          lounger, as wide as all          lounger
    floor      floor cushion    floor cushion, as wide as all    floor
                                (quads across as one's each)
    lying      bed              a shared bed                     bed

The chair and the bench with a back have no seams (`seams = false`): kept sharp, the seat-back
seam folded back on itself at the sides into slits (`guarantees.surface_guarantees`' `slits`).

Each person's support is the use of the furniture (`posedb.regions.SUPPORT_USES`: the body
regions that kind of furniture carries), so the scenario says `support = "chair"`.

People sitting on the floor or lying are lifted by the cushion's or the bed's height (`LIFT`),
a reclined person until the pelvis is `RECLINED_PELVIS` high, so there is furniture under them;
seated and perched people 2 cm (so the seat, not the floor under the feet, takes most of the
weight); several perched people each to the highest pelvis (one seat height serves them all),
while several seated people keep their own heights (their bench's seats are each measured as
the sitter's own chair would be: `BenchParams.seat_each`). Every
control vertex is free. A chair or bench whose fit puts a peak on the calves is tried again with
a waterfall front (`run_design`). Standing poses, seated or perched poses that stand on their
feet (the centre of mass over or ahead of the ankles: sitting down or rising, `ON_FEET_M`) and
poses of different postures stop with a `DesignError`: there is nothing to sit on, no one a
seat would hold, or no one piece for them all.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import numpy as np

from capture.files import made_folder, replace_results, write_atomic

from solver.body.posture import PostureFigures, classify_posture, pelvis_forward, \
    posture_figures


class DesignError(ValueError):
    """Poses the designer has no furniture for (and why)."""


@dataclass(frozen=True)
class Design:
    """What a posture gets: the template for one person and for several, their extra
    parameters, and the use it is for (`posedb.regions.SUPPORT_USES`, the scenario's
    `support`: the body regions that use carries)."""

    single: str
    several: str
    use: str
    single_given: tuple[tuple[str, object], ...] = ()
    several_given: tuple[tuple[str, object], ...] = ()


DESIGNS = {
    "seated": Design("chair", "bench", "chair", (("seams", False),),
                     (("back", True), ("seat_each", True), ("seams", False))),
    "perched": Design("stool", "bench", "stool"),
    "reclined": Design("lounger", "lounger", "lounger"),
    "floor": Design("floor_cushion", "floor_cushion", "floor"),
    "lying": Design("bed", "bed", "bed"),
}
LIFT = {"floor": 0.13, "lying": 0.46,  # metres people are raised: cushion / bed top + 1 cm,
        "seated": 0.02, "perched": 0.02}  # a seat: the feet rest on a floor 150 times
        # stiffer than its foam, so the seat's share of the weight hinges on how deep it sits
        # in the skin against them (captured as they are, the floor takes 40-45 %)
RECLINED_PELVIS = 0.4  # metres: a reclined person is raised until the pelvis is this high
GAP = 0.04  # metres between neighbours' skin, side by side
ON_FEET_M = 0.0  # a seated or perched body whose centre of mass lies this far ahead of the
# ankles or further (along the pelvis's forward direction) stands on its feet: it is sitting
# down or rising, and a seat under it holds no one (the bundled recordings' sitting frames have
# it 2-19 cm behind the ankles; their sitting-down and rising frames 1-12 cm ahead: a chair
# designed under medium sit frame 75 and stools under high sit frames 56 and 59 held no one)
RELIEF_ROUNDS = 6  # rounds of pressure relief after the fit (solver.scene.relief)


class PoseReading(NamedTuple):
    """What `pose_posture` reads of a pose: its posture, the figures it is classified by, and
    how far its centre of mass lies ahead of the middle of its ankles (metres, along the
    pelvis's forward direction; negative behind them)."""

    posture: str
    figures: PostureFigures
    ahead_of_ankles_m: float


def pose_posture(pose: str, db: str | os.PathLike | None = None) -> PoseReading:
    """The `PoseReading` of a pose reference (`db:NAME`, `bvh:PATH#frame=N`), read on the
    average body posed on its rig with its lowest skin point on the floor (the centre of mass
    is the posed skin's volume centroid)."""
    from solver.body.model import make_body
    from solver.body.poses import load_pose, retarget_captured
    from solver.body.retarget import place
    from solver.body.skinning import skin
    from solver.mesh import volume_centroid

    body = make_body()
    motion = place(retarget_captured(load_pose(pose, db), body), lowest=0.0)
    joints = motion.world.positions[0]
    figures = posture_figures(joints, body.joint_names)
    names = list(body.joint_names)
    forward = pelvis_forward(*(joints[names.index(j)] for j in ("LeftUpLeg", "RightUpLeg")))
    ahead = 0.0
    if np.linalg.norm(forward) > 1e-9:  # (hips standing vertical, lying on a side: no forward)
        ankles = (joints[names.index("LeftFoot")] + joints[names.index("RightFoot")]) / 2
        centre = volume_centroid(skin(body, motion.frame(0), normals=False)[0], body.triangles)
        ahead = float((centre - ankles) @ forward / np.linalg.norm(forward))
    return PoseReading(classify_posture(figures), figures, ahead)


def shared_given(kind: str, people: int) -> dict:
    """The parameters a template shared by `people` people gets beyond one person's: a bed or
    a floor cushion as many quads across each person as one for one has (none otherwise)."""
    if kind not in ("bed", "floor_cushion") or people < 2:
        return {}
    from solver.surface.templates import TEMPLATE_PARAMS

    across, along = TEMPLATE_PARAMS[kind]().quads
    return {"quads": [across * people, along]}


def design_scenario(poses: Sequence[str], db: str | os.PathLike | None = None,
                    base: Path | None = None) -> tuple[dict, dict]:
    """The scenario data a designer would start from for the poses, and what was decided.

    Parameters
    ----------
    poses : pose references, as a scenario's `pose` (relative BVH paths relative to `base`).
    db : the pose library for `db:` poses.

    Returns
    -------
    data : the scenario (as `parse_scenario` reads it): the template with every dimension
        measured on the people, the people side by side, each supported as the template's
        use.
    decisions : postures (per pose), their figures, the template kind.

    Raises DesignError for no pose, a standing pose, or poses of different postures.
    """
    from solver.scene.placement import place_scene
    from solver.scene.run import template_table
    from solver.scene.scenario import parse_scenario

    if not poses:
        raise DesignError("Expected at least one pose, got none")
    read = [pose_posture(p, db) for p in poses]
    postures = [r.posture for r in read]
    standing = [p for p, kind in zip(poses, postures) if kind == "standing"]
    if standing:
        raise DesignError(f"{standing[0]} is a standing pose: there is nothing to design under "
                          f"it (choose a seated, perched, reclined, floor or lying frame)")
    on_feet = [(p, r) for p, r in zip(poses, read) if r.posture in ("seated", "perched")
               and r.ahead_of_ankles_m >= ON_FEET_M]
    if on_feet:
        pose, r = on_feet[0]
        lean = -r.figures.trunk_angle_deg
        raise DesignError(
            f"{pose} stands on its feet: its centre of mass is "
            f"{r.ahead_of_ankles_m * 100:.0f} cm ahead of the ankles (trunk "
            + (f"{lean:.0f} degrees forward" if lean > 0.5 else "upright")
            + f", pelvis {r.figures.pelvis_height:.2f} m up), a body sitting down or rising "
            f"that a seat would not hold; choose a held frame (`sitrelax db suggest` finds "
            f"them)")
    if len(set(postures)) > 1:
        raise DesignError("Expected poses of one posture (one piece of furniture), got "
                          + ", ".join(f"{p}: {k}" for p, k in zip(poses, postures)))
    posture = postures[0]
    design = DESIGNS[posture]
    one = len(poses) == 1
    kind = design.single if one else design.several
    given = dict(design.single_given if one else design.several_given)
    given.update(shared_given(kind, len(poses)))
    lifts = [LIFT.get(posture, 0.0) if posture != "reclined" else
             max(RECLINED_PELVIS - r.figures.pelvis_height, 0.0) for r in read]
    if posture in ("seated", "perched") and not one and not given.get("seat_each"):
        # one seat height for all: the lower sit higher
        top = max(r.figures.pelvis_height for r in read)
        lifts = [lift + top - r.figures.pelvis_height for lift, r in zip(lifts, read)]
    people = [{"name": f"person {k + 1}", "pose": p, "support": design.use,
               "position": [0.0, float(lift), 0.0]}
              for k, (p, lift) in enumerate(zip(poses, lifts))]
    data = {"surface": {"template": {"kind": kind, **given}}, "person": people,
            "relief": {"rounds": RELIEF_ROUNDS}}
    if not one:  # side by side along x, their skin GAP apart (measured over a plain grid: a
        # template built round them all overlapping could be too narrow a seat for each)
        measuring = {**data, "surface": {"grid": {"size": [1.0, 1.0], "resolution": [1, 1],
                                                  "height": 0.45}}}
        _, placed = place_scene(parse_scenario(measuring, "design", base), db)
        widths = np.array([np.ptp(p.vertices[:, 0]) for p in placed])
        centres = [float(np.mean(p.vertices[:, 0].min() + p.vertices[:, 0].max()) / 2)
                   for p in placed]
        pitch = np.concatenate([[0.0], np.cumsum((widths[:-1] + widths[1:]) / 2 + GAP)])
        pitch -= pitch[-1] / 2
        for person, x, c in zip(people, pitch, centres):
            person["position"][0] = float(x - c)
    built, _ = place_scene(parse_scenario(data, "design", base), db)
    data["surface"]["template"] = template_table(built.surface.template)
    return data, {"postures": postures, "posture": posture, "template": kind,
                  "figures": [{**r.figures.__dict__, "ahead_of_ankles_m": r.ahead_of_ankles_m}
                              for r in read]}


def run_design(poses: Sequence[str], out_dir: str | os.PathLike, *,
               db: str | os.PathLike | None = None, pictures: bool = True,
               progress: Callable[[str], None] | None = None) -> dict:
    """Designs furniture for the poses and fits it (`sitrelax design`): writes scenario.toml
    (the scenario used, loadable by `sitrelax fit`) and everything `sitrelax fit` writes into
    `out_dir`; report.json gains "design" (the postures, their figures, the template).

    A chair or bench whose fit puts a person's peak pressure on the calves (the seat's front
    edge, held clear of calves tucked under it, can still swing up beside one) is designed
    again with a waterfall front (`solver.scene.furnish.furnish`'s `waterfall`), fitted
    beside in a folder of its own, and kept in its place only if it misses fewer of the bars
    (`solver.scene.quality`); "design" says what was tried (`waterfall`).

    Returns the report as written. Raises DesignError (see `design_scenario`)."""
    from solver.scene.run import previous_results

    say = progress or (lambda message: None)
    if not os.fspath(out_dir).strip():  # (as `run_fit` and `run_relax` refuse it)
        raise ValueError("Expected a results folder, got an empty name")
    with made_folder(out_dir) as out:  # (gone again if nothing can be designed or fitted)
        stale = previous_results(out)  # (a relaxation's folder is refused before any work)
        absolute = [_absolute(p) for p in poses]
        data, decisions = design_scenario(absolute, db)
        say(f"{', '.join(decisions['postures'])}: a {decisions['template']}")
        header = (f"# sitrelax design {' '.join(poses)}\n# postures: "
                  f"{', '.join(decisions['postures'])}; template: {decisions['template']}\n")
        _drop_unfinished(out)  # an earlier run's unfinished try (not one running beside)
        designed = {**decisions, "poses": list(poses), "scenario_file": "scenario.toml",
                    "waterfall": None}
        # the design whole, scenario.toml and report.json with it, in place of an earlier
        # one only once complete; and complete before any second try (it may not finish)
        stage = _stage(out, "straight")
        try:
            report = _fit_design(stage, header, data, db, say, pictures)
            report["scenario"] = str(out / "scenario.toml")
            report["design"] = designed
            _write_report(stage, report)
            replace_results(stage, out, stale, "report.json")
        finally:
            shutil.rmtree(stage, ignore_errors=True)
    if decisions["template"] in ("chair", "bench") and _on_calves(report):
        tried, kept = _try_waterfall(out, header, data, db, report, designed, say, pictures)
        if kept is not None:  # (in place, with its report, already)
            return kept
        report["design"] = {**designed, "waterfall": tried}
        _write_report(out, report)
    return report


def _stage(out: Path, kind: str) -> Path:
    """A new hidden folder in `out` for one try ("straight" or "waterfall"), its name carrying
    this process's id (`_drop_unfinished` leaves it alone while this process runs); an OSError
    naming `out` when it cannot be made there (as `sitrelax fit` names its folder)."""
    try:
        return Path(tempfile.mkdtemp(prefix=f".{kind}-{os.getpid()}-", dir=out))
    except OSError as exc:
        raise OSError(exc.errno, f"Cannot write the results into this folder "
                                 f"({exc.strerror or exc})", str(out)) from None


def _drop_unfinished(out: Path) -> None:
    """Removes the tries (`_stage`) that designs since stopped left in `out`; one whose process
    still runs is a design working there beside this one, and stays."""
    for stage in [*out.glob(".waterfall-*"), *out.glob(".straight-*")]:
        pid = stage.name.split("-")[1]
        if pid.isdigit():
            try:
                os.kill(int(pid), 0)
                continue  # (still running)
            except ProcessLookupError:
                pass
            except (PermissionError, OverflowError, OSError):
                continue  # (running as someone else, or no telling)
        shutil.rmtree(stage, ignore_errors=True)


def _write_report(out: Path, report: dict) -> None:
    write_atomic(out / "report.json", json.dumps(report, indent=2, allow_nan=False).encode())


def _try_waterfall(out: Path, header: str, data: dict, db, report: dict, designed: dict,
                   say, pictures: bool) -> tuple[dict, dict | None]:
    """`run_design`'s second try, after a chair or bench put a peak on the calves: the design
    `data` again with a waterfall front (its template's measures as they are, the front drop
    measured by `solver.scene.furnish.furnish`'s `waterfall` on the people placed as `data`
    places them), fitted in a folder of its own inside `out` and moved into
    `out` with its report (`designed` and what was tried as its "design") only if it misses
    fewer bars than `report` (the straight front's, written there already).

    Returns what was tried and the waterfall front's report if it was kept (else None). What
    was tried: `front_drop_m` (0 when no calves tuck under the seat's front: nothing is
    fitted), the bars missed before and after, whether the waterfall front was `kept`, the
    straight front's fit time (`straight_fit_s`) and the `error` that stopped the try, if any
    (the straight front's design then stands)."""
    from solver.scene.furnish import furnish
    from solver.scene.placement import place_scene
    from solver.scene.run import previous_results
    from solver.scene.scenario import ScenarioError, parse_scenario
    from solver.surface.fit import FitError
    from solver.surface.templates import TemplateError

    tried = {"front_drop_m": 0.0, "misses_before": _misses(report), "kept": False,
             "straight_fit_s": report.get("timing", {}).get("fit_s")}
    stage = None
    try:
        template = data["surface"]["template"]
        given = {k: v for k, v in template.items() if k not in ("kind", "front_drop")}
        _, placed = place_scene(parse_scenario(data, "design"), db)
        tried["front_drop_m"] = furnish(template["kind"], given, placed,
                                        waterfall=True).params.front_drop
        if tried["front_drop_m"] > 0:
            trial = {**data, "surface": {**data["surface"], "template": {
                **template, "front_drop": tried["front_drop_m"]}}}
            say(f"a peak on the calves: the design again, its front edge dropped "
                f"{100 * tried['front_drop_m']:.0f} cm (a waterfall front)")
            stage = _stage(out, "waterfall")
            again = _fit_design(stage, header, trial, db, say, pictures)
            tried["misses_after"] = _misses(again)
            if tried["misses_after"] < tried["misses_before"]:
                tried["kept"] = True
                again["scenario"] = str(out / "scenario.toml")
                again["design"] = {**designed, "waterfall": tried}
                _write_report(stage, again)
                # (the straight front's files that the waterfall front's fit did not write go)
                replace_results(stage, out, previous_results(out), "report.json")
                say("kept the waterfall front")
                return tried, again
            say("kept the straight front: the waterfall front missed as many bars or more")
    except (ScenarioError, TemplateError, FitError) as exc:
        tried["error"] = str(exc)
        say(f"kept the straight front: the waterfall front failed: {exc}")
    finally:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)
    return tried, None


def _fit_design(out: Path, header: str, data: dict, db, say, pictures: bool) -> dict:
    """Writes a designed scenario into `out` as scenario.toml and fits it there."""
    from solver.scene.run import run_fit
    from solver.scene.scenario import scenario_toml

    path = out / "scenario.toml"
    write_atomic(path, (header + scenario_toml(data)).encode())
    report = run_fit(path, out, db=db, progress=say, pictures=pictures,
                     title=_design_title(data))
    # listed with the results, so that a later result in the same folder (a fit) removes it
    report.setdefault("files", {})["scenario"] = path.name
    return report


def _design_title(data: dict) -> str:
    """The design sheet's title: the template and the poses it was designed for ("a chair for
    cmu_75_17_medium_sit.bvh frame 150"), not the scenario file's name, which every design
    shares."""
    kind = str((data.get("surface", {}).get("template") or {}).get("kind", "surface"))
    poses = []
    for person in data.get("person", []):
        ref = str(person.get("pose", ""))
        where, _, frame = ref.partition("#frame=")
        name = Path(where.split(":")[-1]).name if where.startswith("bvh:") else where
        poses.append(f"{name} frame {frame}" if frame else name)
    shown = ", ".join(poses[:3]) + (f" and {len(poses) - 3} more" if len(poses) > 3 else "")
    return f"sitrelax design: a {kind.replace('_', ' ')} for {shown}"


def _on_calves(report: dict) -> bool:
    """Whether a person's peak pressure lies on the calves and their support leaves them out."""
    return any(p.get("peak_region") == "calves" and "calves" not in p["support"]
               for p in report["persons"])


def _misses(report: dict) -> int:
    """How many bars a fitted design misses (report.json's `misses`: its surface's and its
    people's)."""
    return len(report["misses"])


def _absolute(pose: str) -> str:
    """A BVH pose reference with its path made absolute (the scenario file lives elsewhere)."""
    if pose.startswith("db:") or "bundled:" in pose or "#" not in pose:
        return pose
    text = pose[4:] if pose.startswith("bvh:") else pose
    path, frame = text.split("#", 1)
    if not path.strip():  # (no file named: `load_pose` says so, as `pose show` does, rather
        return pose       # than the working folder resolved from an empty name)
    return f"bvh:{Path(path).resolve()}#{frame}"
