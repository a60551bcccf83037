"""`sitrelax demo`: the whole chain on the bundled recordings, through the product's own paths.

1. capture: two replay servers on loopback ports stream a Perception Neuron recording (Axis
   Neuron, standing; its first seconds) and a CMU sitting recording, in real time, and two
   recorders store them as takes of a fresh pose library;
2. poses: the held postures of both takes are suggested and accepted, tagged;
3. scenario: two people of different body shapes on one seated pose, side by side on a bench;
4. fit, evaluation against a flat seat, and export (`solver.run.run_fit`);
5. relaxation of both people onto the fitted surface (`solver.run.run_relax`).
"""

from __future__ import annotations

import os
import shutil
import threading
import time
from pathlib import Path
from typing import Callable

from capture import resolve_path
from capture.files import made_folder

STANDING = "bundled:axis_neuron_standing_yxz.bvh"
SITTING = "bundled:cmu_75_18_high_sit.bvh"
STANDING_SECONDS = 3.0  # how much of the long standing recording is streamed

SCENARIO = """\
# Written by `sitrelax demo`: two people of different build on one seated pose from the library.
[surface]
# a seat with a back for both, built around them; its front edge dropped 8 cm (a waterfall
# front): the slighter person's calves tuck under it, and a straight front put her peak there
template = {{ kind = "bench", back = true, front_drop = 0.08 }}
level = 3
sigma = 0.003
tau_max = 0.5
margin = 0.03

[[person]]
name = "slight"
pose = "db:{pose}"
body = {{ gender = 0.2, weight = 0.3, height = 0.4 }}
position = [-0.33, 0.0, -0.1]
support = "seat"  # the pose leans back: the bench's back keeps it from tipping over

[[person]]
name = "broad"
pose = "db:{pose}"
body = {{ gender = 0.9, weight = 0.8, height = 0.6 }}
position = [0.33, 0.0, -0.1]
support = "seat"
"""


class DemoError(ValueError):
    """A stage of the demo that did not produce what the next one needs."""


def _stream_and_record(source: str, library: Path, take: str, frames: int, tags: list[str],
                       results: dict, say: Callable[[str], None], stop: threading.Event,
                       running: list) -> None:
    """Serves `source` on a free loopback port and records it into `take` on a thread, which
    (with its replay) joins `running`; both end early once `stop` is set."""
    from capture.replay import Replay, ReplayThread, TcpServerSink
    from posedb.record import record

    path = str(resolve_path(source))
    sink = TcpServerSink("127.0.0.1", 0)
    replay = ReplayThread(Replay.from_bvh(path), sink, wait_for_client=True, rate=1.0,
                          max_frames=frames).start()

    def main() -> None:
        try:
            results[take] = record(sink.name, library, take, path, frames=frames, tags=tags,
                                   subject="demo", stop=stop.is_set)
        except BaseException as exc:  # reported by run_demo
            results[take] = exc
        finally:
            replay.stop()

    thread = threading.Thread(target=main, daemon=True)
    running.append((replay, thread))
    thread.start()
    say(f"streaming {Path(path).name} on {sink.name}")


def _capture(library: Path, say: Callable[[str], None]) -> tuple[dict, dict]:
    """Streams both recordings at once from replay servers and records them into a new
    library; returns each take's (source, frames, tags) and its recording result. Should it
    fail or be interrupted, the streams and recorders are stopped before it raises (nothing
    goes on writing into the library)."""
    from capture import read_bvh
    from posedb import PoseLibrary

    PoseLibrary(library, create=True)
    standing = read_bvh(resolve_path(STANDING))
    sitting = read_bvh(resolve_path(SITTING))
    jobs = {"standing": (STANDING, int(STANDING_SECONDS / standing.motion.frame_time), ["stand"]),
            "sitting": (SITTING, sitting.motion.num_frames, ["sit"])}
    results: dict = {}
    stop = threading.Event()
    running: list = []
    try:
        for take, (src, frames, tags) in jobs.items():
            _stream_and_record(src, library, take, frames, tags, results, say, stop, running)
        for _, thread in running:
            thread.join(60)
    except BaseException:
        stop.set()
        for replay, thread in running:
            replay.stop()
            thread.join(10)
        raise
    for take in jobs:
        got = results.get(take)
        if isinstance(got, BaseException):
            raise DemoError(f"recording {take} failed: {got}") from got
        if not got or not got.get("take"):
            raise DemoError(f"recording {take} stored nothing")
        say(f"recorded {got['frames']} frames into take {take} ({got['dropped']} dropped)")
    return jobs, results


def run_demo(out_dir: str | os.PathLike, progress: Callable[[str], None] | None = None
             ) -> dict:
    """Runs the demo into `out_dir` (see the module docstring); returns its summary.

    `out_dir` must be a new or empty folder (DemoError for a folder that holds files, a file,
    or an empty name, before any work). A demo that fails or is interrupted (Ctrl-C) leaves the
    folder as it was: empty, or gone when the demo made it."""
    report = progress or (lambda message: None)

    def say(message: str) -> None:  # the stages' news, without the fit's every iteration
        if not message.startswith("iteration "):
            report(message)

    if not os.fspath(out_dir).strip():
        raise DemoError("Expected a folder for the demo (--out), got an empty name")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise DemoError(f"Expected a folder for the demo (--out), got a file: {out}")
    if out.is_dir() and any(out.iterdir()):  # (its files would mix with the demo's)
        raise DemoError(f"{out} is not empty: give the demo an empty or new folder (--out)")
    with made_folder(out):  # (the folders it made go again when the demo fails)
        try:
            return _demo(out, say)
        except BaseException:
            # a demo that fails or is interrupted leaves no half-written folder: everything
            # in `out` is its own (the folder was empty or new)
            for entry in list(out.iterdir()):
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry, ignore_errors=True)
                else:
                    entry.unlink(missing_ok=True)
            raise


def _demo(out: Path, say: Callable[[str], None]) -> dict:
    """`run_demo`'s work into the empty folder `out`."""
    from posedb import PoseLibrary
    from posedb.suggest import suggest_poses

    from solver.contact.evaluate import flat_text
    from solver.scene.run import run_fit, run_relax

    library = out / "poses.h5"
    stages: dict[str, float] = {}
    start = time.perf_counter()

    # 1. capture both streams at once, in real time
    jobs, results = _capture(library, say)
    stages["capture_s"] = time.perf_counter() - start

    # 2. poses: suggest and accept the held postures
    t = time.perf_counter()
    lib = PoseLibrary(library)
    accepted = {take: suggest_poses(lib, take, accept=True, tags=jobs[take][2] + ["demo"],
                                    supports="seat") for take in jobs}
    seated = accepted["sitting"]
    if not seated:
        raise DemoError("no held seated posture was found in the recorded sitting take")
    pose = seated[0]["name"]
    say(f"accepted {sum(len(v) for v in accepted.values())} poses; the scene uses {pose}")
    stages["poses_s"] = time.perf_counter() - t

    # 3-4. the scenario, fitted, evaluated and exported
    t = time.perf_counter()
    scenario = out / "scenario.toml"
    scenario.write_text(SCENARIO.format(pose=pose))
    fit = run_fit(scenario, out / "fit", db=library, progress=say)
    stages["fit_s"] = time.perf_counter() - t

    # 5. both people relaxed onto the fitted surface
    t = time.perf_counter()
    relaxed = run_relax(scenario, out / "relax", surface_dir=out / "fit", db=library,
                        progress=say)
    stages["relax_s"] = time.perf_counter() - t
    stages["total_s"] = time.perf_counter() - start

    persons = [{"name": fitted["name"], "mass_kg": fitted["mass_kg"],
                "coverage": fitted["coverage"], "max_penetration_m": fitted["max_penetration_m"],
                "peak_pressure_kpa": fitted["peak_pressure_kpa"],
                "flat_peak_pressure_kpa": _same_load_peak(fitted),
                "peak_of_flat": fitted.get("peak_of_flat"),
                "flat": flat_text(fitted), "relaxed": rel["after"]}
               for fitted, rel in zip(fit["persons"], relaxed["persons"])]
    return {
        "out": str(out), "library": library.name, "scenario": scenario.name,
        "takes": {take: {"frames": results[take]["frames"], "dropped": results[take]["dropped"],
                         "poses": [row["name"] for row in accepted[take]]} for take in jobs},
        "fit": {"folder": "fit", "iterations": fit["iterations"],
                "stop_reason": fit["stop_reason"], "files": sorted(os.listdir(out / "fit"))},
        "relax": {"folder": "relax", "files": sorted(os.listdir(out / "relax"))},
        "persons": persons, "timing": stages,
    }


def _same_load_peak(person: dict) -> float | None:
    """The flat seat's peak the bars and the printed summary use: at the load the fitted seat
    carries (`flat_text`, a batch's `flat_peak_pressure_kpa_max`); None where there is none."""
    return ((person.get("flat") or {}).get("same_load") or {}).get("peak_pressure_kpa")


def _kpa(value: float | None) -> str:
    return "no rest" if value is None else f"{value:.1f} kPa"


def format_summary(summary: dict) -> str:
    """The demo's summary for people."""
    t = summary["timing"]
    lines = [f"sitrelax demo: everything is in {summary['out']}"]
    for take, info in summary["takes"].items():
        lines.append(f"  take {take}: {info['frames']} frames streamed and recorded "
                     f"({info['dropped']} dropped), poses {', '.join(info['poses']) or 'none'}")
    lines.append(f"  fit: {summary['fit']['iterations']} iterations, "
                 f"{summary['fit']['stop_reason'].split(':')[0]}; files in fit/, relaxed "
                 f"poses in relax/")
    for p in summary["persons"]:
        lines.append(f"  {p['name']} ({p['mass_kg']:.0f} kg): coverage {p['coverage']:.2f}, "
                     f"deepest cut {p['max_penetration_m'] * 1000:.0f} mm, peak "
                     f"{_kpa(p['peak_pressure_kpa'])} (flat seat {p['flat']}); relaxed "
                     f"coverage {p['relaxed']['coverage']:.2f}")
    lines.append(f"  time: capture {t['capture_s']:.1f} s, poses {t['poses_s']:.1f} s, fit and "
                 f"export {t['fit_s']:.1f} s, relax {t['relax_s']:.1f} s, total "
                 f"{t['total_s']:.1f} s")
    return "\n".join(lines)
