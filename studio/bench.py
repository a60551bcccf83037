"""Benchmark entries of the studio layer (run by `sitrelax bench`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
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


def _cli_start_setup() -> tuple[list[str], dict]:
    """The `sitrelax --help` command line, run with this checkout's packages first on the path."""
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
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
        BenchCase("api_fit", "POST /api/fit of single_seated to a running `sitrelax serve` "
                  "(pose, fit, evaluate, JSON both ways)", _api_setup, _api_fit,
                  _in_process_fit, "the same fit and evaluation in-process", repeats=7,
                  baseline_repeats=7),
    ]
