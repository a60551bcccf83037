"""The README's plain install (`pip install .`, not editable) gives a working package: the wheel
built from the tracked files holds every module and data file of the four packages, and the
command line runs from it alone (the repository off the import path)."""

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("capture", "posedb", "solver", "studio")


def _tracked() -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs the git checkout (its tracked files are what a wheel is built from)")
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True)
    return [p for p in out.stdout.decode().split("\0") if p]


@pytest.fixture(scope="module")
def wheel_tree(tmp_path_factory) -> tuple[Path, set[str]]:
    """The wheel of a clean copy of the tracked files, unpacked: (its folder, its file names)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    tracked = _tracked()
    for name in tracked:
        path = ROOT / name
        if path.is_file() and not path.is_symlink():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, src / name)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                            str(tmp / "out"), str(src)], capture_output=True, text=True)
    if built.returncode != 0 and ("Could not find a version" in built.stderr or
                                  "NewConnectionError" in built.stderr):
        pytest.skip("pip could not fetch the build backend (no package index reachable)")
    assert built.returncode == 0, built.stderr[-2000:]
    (wheel,) = (tmp / "out").glob("sitrelax-*.whl")
    unpacked = tmp / "site"
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(unpacked)
        names = set(zf.namelist())
    return unpacked, names


def test_wheel_holds_every_module_and_data_file(wheel_tree):
    """Every tracked file of the four packages is in the wheel."""
    _, names = wheel_tree
    wanted = [p for p in _tracked() if p.split("/")[0] in PACKAGES and
              not (ROOT / p).is_symlink()]
    assert len(wanted) > 100
    missing = sorted(p for p in wanted if p not in names)
    assert not missing, f"the wheel lacks {len(missing)} tracked file(s): {missing[:10]}"


def test_command_line_runs_from_the_wheel_alone(wheel_tree, tmp_path):
    """Every module imports from the unpacked wheel, and `sitrelax fit` runs an example."""
    site, _ = wheel_tree
    # -S: the installed packages' folder is on the path, but not its .pth files (this
    # checkout's own editable install among them)
    purelib = sysconfig.get_paths()["purelib"]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), purelib]),
               OPENBLAS_NUM_THREADS="1")
    run = subprocess.run(
        [sys.executable, "-S", "-c",
         "import sys, importlib, pkgutil\n"
         "import capture, posedb, solver, studio\n"
         "for pkg in (capture, posedb, solver, studio):\n"
         "    assert pkg.__file__.startswith(sys.argv[1]), pkg.__file__\n"
         "    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
         "        if '.data.' not in m.name:\n"
         "            importlib.import_module(m.name)\n",
         str(site)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    scenario = site / "solver" / "data" / "scenarios" / "single_seated.toml"
    fit = subprocess.run([sys.executable, "-S", "-m", "studio.cli", "fit", str(scenario), "--out",
                          str(tmp_path / "out"), "--no-pictures"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert fit.returncode == 0, fit.stderr[-2000:]
    assert (tmp_path / "out" / "report.json").is_file()
