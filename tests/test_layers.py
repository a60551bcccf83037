"""The layering rule, read from every module's imports (function-level imports included):
capture <- posedb <- solver <- studio, and inside the solver mesh <- body <- contact <- surface,
io on mesh alone, scene above them all; no algorithm layer imports scene, io or the CLI."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# what each layer may import of this project (besides itself)
BASE = {"solver.threads", "solver.kept"}  # what every solver layer may use
ALLOWED = {
    "capture": set(),
    "solver.threads": set(),  # BLAS thread control
    "solver.kept": set(),  # what is built from arrays, kept by their content
    "posedb": {"capture"},
    "solver.mesh": {"capture", "posedb"} | BASE,
    "solver.body": {"capture", "posedb", "solver.mesh"} | BASE,
    "solver.contact": {"capture", "posedb", "solver.mesh", "solver.body"} | BASE,
    "solver.surface": {"capture", "posedb", "solver.mesh", "solver.body", "solver.contact"} | BASE,
    "solver.io": {"capture", "solver.mesh"} | BASE,
    "solver.scene": {"capture", "posedb", "solver.mesh", "solver.body", "solver.contact",
                     "solver.surface", "solver.io"} | BASE,
    "solver": {"capture", "posedb", "solver"},  # the facade, the CLI and the bench runner
    "studio": {"capture", "posedb", "solver"},
}
PROJECT = ("capture", "posedb", "solver", "studio")


def _layer(module: str) -> str:
    for layer in sorted(ALLOWED, key=len, reverse=True):
        if module == layer or module.startswith(layer + "."):
            return layer
    raise AssertionError(f"{module} belongs to no layer")


def _modules():
    for package in PROJECT:
        for path in sorted((ROOT / package).rglob("*.py")):
            if "data" in path.relative_to(ROOT).parts[1:-1]:
                continue  # asset conversion scripts are not library code
            parts = path.relative_to(ROOT).with_suffix("").parts
            yield ".".join(parts[:-1] if parts[-1] == "__init__" else parts), path


def _imports(module: str, path: Path):
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                yield ".".join(base + ([node.module] if node.module else []))
            else:
                yield node.module


def _violations(modules) -> list[str]:
    wrong = []
    for module, path in modules:
        own = _layer(module)
        for name in _imports(module, path):
            if not name.startswith(PROJECT):
                continue
            target = _layer(name)
            if target != own and not any(target == a or target.startswith(a + ".")
                                         for a in ALLOWED[own]):
                wrong.append(f"{module} imports {name}")
    return wrong


def test_every_module_imports_only_the_layers_below_it():
    wrong = _violations(_modules())
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("layer", ["solver.body", "solver.contact", "solver.surface",
                                   "solver.mesh"])
def test_algorithm_layers_never_reach_the_scene_io_or_cli(layer):
    names = {name for module, path in _modules() if _layer(module) == layer
             for name in _imports(module, path)}
    assert not {n for n in names if n.startswith(("solver.scene", "solver.io", "solver.cli",
                                                   "solver.bench", "studio"))}


def test_the_checker_sees_upward_imports(tmp_path):
    """The checker itself: modules importing upwards, at the top or inside a function, are
    caught; the same imports in the layer above are not."""
    upward = tmp_path / "relax.py"
    upward.write_text("import numpy\nfrom solver.scene.run import run_fit\n\n"
                      "def f():\n    from ..io import render\n    import studio.api\n")
    assert _violations([("solver.body.relax", upward)]) == [
        "solver.body.relax imports solver.scene.run", "solver.body.relax imports solver.io",
        "solver.body.relax imports studio.api"]
    assert _violations([("solver.scene.run", upward)]) == [
        "solver.scene.run imports studio.api"]
