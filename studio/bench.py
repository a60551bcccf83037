"""Benchmark entries of the studio layer (run by `sitrelax bench`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import tomllib
import urllib.request
from pathlib import Path

from solver.bench import BenchCase, _example_path


def _api_setup():
    from .api import ApiThread

    data = tomllib.loads(_example_path("single_seated").read_text())
    return ApiThread(), json.dumps(data).encode(), data


def _api_fit(arg):
    api, body, _ = arg
    request = urllib.request.Request(f"{api.url}/api/fit", data=body, method="POST",
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=60) as response:
        reply = json.loads(response.read())
    if not reply["persons"]:
        raise RuntimeError("api_fit: no person in the answer")
    return reply


def _in_process_fit(arg):
    from solver.scene.run import fit_scene
    from solver.scene.scenario import parse_scenario
    from solver.scene.placement import place_scene

    return fit_scene(*place_scene(parse_scenario(arg[2], "bench", files=False)))


PACKAGES = ("capture", "posedb", "solver", "studio")


def _cli_start_setup() -> tuple[list[str], dict]:
    """The `sitrelax --help` command line, run with this checkout's packages first on the path
    as a user's copy runs from the second time on: their bytecode compiled (pip compiles an
    installed package's; Python caches a checkout's when it first imports it), and read, even
    where the environment says not to write it (PYTHONDONTWRITEBYTECODE: every start would
    compile all of it again, about 0.25 s of `sitrelax fit`)."""
    import compileall

    root = Path(__file__).resolve().parents[1]
    for package in PACKAGES:
        compileall.compile_dir(root / package, quiet=2)
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(root), env.get("PYTHONPATH")) if p)
    return [sys.executable, "-m", "studio.cli", "--help"], env


def _cli_start(arg) -> None:
    command, env = arg
    subprocess.run(command, env=env, stdout=subprocess.DEVNULL, check=True)


def _fit_command_setup(pictures: bool = True):
    """`sitrelax fit single_seated.toml --out DIR` (with `--no-pictures` when asked), run with
    this checkout's packages first on the path, into a fresh folder each time."""
    command, env = _cli_start_setup()
    command = command[:-1] + ["fit", str(_example_path("single_seated"))]
    return command + ([] if pictures else ["--no-pictures"]), env


def _fit_command(arg) -> None:
    import tempfile

    command, env = arg
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(command + ["--out", tmp], env=env, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL, check=True)
        if not (Path(tmp) / "report.json").exists():
            raise RuntimeError("fit_command: no report.json written")


def _refit_setup():
    """A studio on loopback with one headless tab (`studio.headless`), single_seated's start and
    person in its Design view, refitting while dragging."""
    from .headless import HeadlessTab
    from .web import Studio

    data = tomllib.loads(_example_path("single_seated").read_text())
    grid, person = data["surface"]["grid"], data["person"][0]
    studio = Studio(port=0, out=os.devnull)
    tab = HeadlessTab(studio, watch=("/design/surface",), texts=True)
    view = tab.view
    view.design.new_grid(grid["size"], grid["resolution"], grid["height"])
    view.add_person(person["pose"], **{k: person[k] for k in ("position", "facing", "support")})
    view.live.value = True

    def stop() -> None:  # the tab first, so the server sees it leave before it stops
        tab.close()
        studio.stop()

    # before the interpreter's thread pools shut down (plain atexit runs after them, when
    # viser could no longer run the tab's disconnect)
    threading._register_atexit(stop)
    return {"studio": studio, "tab": tab, "view": view, "position": list(person["position"]),
            "step": 0}


def _idle(view, deadline: float) -> None:
    """Waits until the studio's refit worker has nothing running or asked for."""
    refitter = view.session.refitter
    while refitter.busy or refitter.wanted:
        if time.perf_counter() > deadline:
            raise RuntimeError(f"studio_refit: the studio did not settle "
                               f"({view.status_text[:200]})")
        time.sleep(0.002)


def _refit_drag(arg) -> tuple[float, float]:
    """One gizmo update of the person (1 cm along x, back and forth) sent as the page sends it
    to a settled studio: the seconds until the tab has received the first surface of the refit
    (a streamed iterate) and until it has the finished refit's (surface, bodies and figures)."""
    from viser import _messages

    tab, view = arg["tab"], arg["view"]
    _idle(view, time.perf_counter() + 120.0)
    arg["step"] += 1
    x, y, z = arg["position"]
    position = (x + 0.01 * (arg["step"] % 2), y, z)
    fits = view.fits
    start = time.perf_counter()
    tab.send(_messages.TransformControlsUpdateMessage(
        f"{view.prefix}/people/p0", (1.0, 0.0, 0.0, 0.0), position, str(tab.client_id)))
    deadline = start + 120.0
    # the status line's "(fit N)" is sent after the refit's surface, bodies and figures
    while (done := tab.text_arrived(f"(fit {fits + 1})", start)) is None:
        if time.perf_counter() > deadline:
            raise RuntimeError(f"studio_refit: no refitted surface after 120 s "
                               f"({view.status_text[:200]})")
        time.sleep(0.002)
    first = next((t for t in list(tab.arrivals["/design/surface"]) if t >= start), done)
    return first - start, done - start


def _refit_in_process(arg) -> tuple[float, float]:
    """The same move and warm refit made in-process (`Design.fit`, nothing drawn): the seconds
    from the fit's call to its first accepted iterate and to its end, evaluation included."""
    view = arg["view"]
    _idle(view, time.perf_counter() + 120.0)
    arg["step"] += 1
    x, y, z = arg["position"]
    view.design.update_person(0, position=[x + 0.01 * (arg["step"] % 2), y, z])
    seen = []
    start = time.perf_counter()
    view.design.fit(warm=True, iterates=lambda it: seen.append(time.perf_counter()))
    done = time.perf_counter() - start
    return (seen[0] - start if seen else done), done


def _first(measure):
    return lambda arg: measure(arg)[0]


def _finished(measure):
    return lambda arg: measure(arg)[1]


def cases() -> list[BenchCase]:
    return [
        BenchCase("cli_start", "`sitrelax --help` in a fresh interpreter (start-up, every "
                  "subcommand's parser, no work loaded)", _cli_start_setup, _cli_start,
                  repeats=10),
        BenchCase("fit_command", "`sitrelax fit single_seated.toml --out DIR` in a fresh "
                  "interpreter: start-up, pose, fit, evaluation, every file and picture",
                  _fit_command_setup, _fit_command, repeats=5),
        BenchCase("fit_command_no_pictures", "the same with `--no-pictures`",
                  lambda: _fit_command_setup(pictures=False), _fit_command, repeats=5),
        BenchCase("studio_refit", "a person's gizmo moved 1 cm in a settled studio tab (over "
                  "viser's websocket, headless) until the tab has the first surface of the "
                  "refit (a streamed iterate): single_seated, refit while dragging",
                  _refit_setup, _first(_refit_drag), _first(_refit_in_process),
                  "the same warm refit in-process to its first iterate (Design.fit)",
                  repeats=9, baseline_repeats=9, self_timed=True),
        BenchCase("studio_refit_finished", "the same drag until the tab has the finished "
                  "refit's surface (evaluated: figures and pressure drawn)", _refit_setup,
                  _finished(_refit_drag), _finished(_refit_in_process),
                  "the same warm refit in-process, evaluation included (Design.fit)",
                  repeats=9, baseline_repeats=9, self_timed=True),
        BenchCase("api_fit", "POST /api/fit of single_seated to a running `sitrelax serve` "
                  "(pose, fit, evaluate, JSON both ways)", _api_setup, _api_fit,
                  _in_process_fit, "the same fit and evaluation in-process", repeats=7,
                  baseline_repeats=7),
    ]
