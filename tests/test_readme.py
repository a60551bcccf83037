"""Every concrete command in the README runs as written, in order, in a fresh folder.

The synopsis block (metavariables such as FILE and SOURCE) and the install commands (run by CI
itself) are left out; a line ending in `&` runs in the background for the lines after it, as in
a shell. The README's fixed ports are swapped for free ones so parallel runs cannot collide.
"""

import re
import shlex
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from studio.cli import main

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        if "sitrelax bvh info FILE" in block or "python3 -m venv" in block:
            continue
        joined = re.sub(r"\\\n\s*", "", block)
        for line in joined.splitlines():
            line = re.sub(r"\s+#\s.*$", "", line).strip()
            if line:
                commands.append(line)
    return commands


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_readme_lists_the_commands_it_shows():
    commands = readme_commands()
    assert all(c.startswith("sitrelax ") for c in commands), commands
    for needed in ("capture replay", "capture listen", "capture record", "db import",
                   "db suggest", "db list", "body make", "pose show", "fit", "relax",
                   "studio", "serve"):
        assert any(c.startswith(f"sitrelax {needed} ") for c in commands), needed


def _run_as_written(commands, tmp_path, monkeypatch, capsys):
    """Runs `commands` in order in the fresh folder `tmp_path`, as `sitrelax` would."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("SITRELAX_DB", raising=False)
    (tmp_path / "fixtures").symlink_to(ROOT / "fixtures")
    ports = {fixed: str(_free_port()) for fixed in ("7001", "8080", "8765")}
    background = []
    try:
        for command in commands:
            for fixed, free in ports.items():
                command = command.replace(fixed, free)
            args = shlex.split(command.rstrip("&").strip())[1:]
            if command.endswith("&"):
                background.append(subprocess.Popen(
                    [sys.executable, "-m", "studio.cli", *args], cwd=tmp_path,
                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE))
                time.sleep(1.0)  # let it listen
                assert background[-1].poll() is None, background[-1].stderr.read()
                continue
            status = main(args)
            captured = capsys.readouterr()
            assert status == 0, f"{command}\n{captured.err}"
    finally:
        for proc in background:
            proc.terminate()
            proc.wait(10)


@pytest.mark.slow
def test_every_readme_command_runs_as_written(tmp_path, monkeypatch, capsys):
    _run_as_written(readme_commands(), tmp_path, monkeypatch, capsys)
    # what the commands say they make
    assert (tmp_path / "session.raw").stat().st_size > 0
    assert (tmp_path / "poses.h5").exists()
    for made in ("body.obj", "seated.png", "seated.obj", "result/report.json",
                 "thin/report.json", "heavy_on_thin/report.json", "sweep/summary.csv"):
        assert (tmp_path / made).exists(), made


# the README's commands that need no stream, server, fit or worker: the default run's smoke test
QUICK = ("sitrelax bvh ", "sitrelax db ", "sitrelax body ", "sitrelax pose ")


def test_the_readme_library_and_body_commands_run_as_written(tmp_path, monkeypatch, capsys):
    quick = [c for c in readme_commands() if c.startswith(QUICK)]
    assert len(quick) >= 15
    _run_as_written(quick, tmp_path, monkeypatch, capsys)
    for made in ("poses.h5", "body.obj", "seated.png", "seated.obj", "seated_part.bvh"):
        assert (tmp_path / made).exists(), made


def test_the_readme_scenario_example_is_valid():
    import tomllib

    from solver.scene.scenario import parse_scenario

    (block,) = [b for b in re.findall(r"```toml\n(.*?)```", (ROOT / "README.md").read_text(),
                                      flags=re.S) if "[surface]" in b]
    scenario = parse_scenario(tomllib.loads(block))
    assert scenario.surface.params.sigma == 0.003 and scenario.surface.params.margin == 0.03
    assert list(scenario.surface.params.fixed) == [0, 7]
    assert scenario.foam_stiffness == 200.0
    (person,) = scenario.persons
    assert person.pose == "db:relaxed_sit_01" and person.support == ("pelvis", "thighs")  # a seat


def test_the_grasshopper_section_lists_the_scripts_inputs_and_outputs():
    """The README's table of the Grasshopper component is the script's (which the tests in
    tests/studio/test_grasshopper.py run against a real server)."""
    import ast

    from studio import grasshopper

    text = (ROOT / "README.md").read_text()
    section = text[text.index("### From Rhino 8 and Grasshopper"):text.index("## Python API")]
    listed = re.findall(r"^\| `(\w+)` \|", section, flags=re.M)
    call = ast.parse(Path(grasshopper.__file__).read_text()).body[-1]
    inputs = [e.value for e in ast.walk(call.body[0].value) if isinstance(e, ast.Constant)
              and isinstance(e.value, str)]
    assert listed == inputs
    outputs = [t.id for t in call.body[0].targets[0].elts]
    assert outputs == ["subd", "surface", "net", "report", "status"]
    for name in outputs:
        assert f"`{name}`" in section
