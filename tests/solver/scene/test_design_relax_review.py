"""`sitrelax design` and `sitrelax relax` as a designer uses them: what the README and --help
promise against what the commands do."""

import json
from pathlib import Path

import pytest

from solver.scene.run import run_fit, run_relax

EXAMPLES = Path(__file__).resolve().parents[3] / "solver" / "data" / "scenarios"
FIGURES = ("mean_support_distance_m", "coverage", "contact_coverage", "max_penetration_m",
           "peak_pressure_kpa")


def test_relax_without_a_surface_relaxes_onto_the_relieved_surface_that_fit_writes(tmp_path):
    # the README: without --surface each person is relaxed onto the limit surface "what
    # surface.obj holds and the fit's figures are judged on"; with [relief] rounds that is the
    # relieved fit, not the plain one
    scenario = tmp_path / "relieved.toml"
    scenario.write_text((EXAMPLES / "single_seated.toml").read_text()
                        + "\n[relief]\nrounds = 1\n")
    fitted = run_fit(scenario, tmp_path / "fit", pictures=False)
    assert fitted["relief"]["kept"] == 1  # (else the plain and relieved surfaces are one)
    relaxed = run_relax(scenario, tmp_path / "relax")
    on_file = run_relax(scenario, tmp_path / "relax_file", surface_dir=tmp_path / "fit")
    for fit_person, now, given in zip(fitted["persons"], relaxed["persons"],
                                      on_file["persons"]):
        for key in FIGURES:
            assert now["before"][key] == pytest.approx(fit_person[key], rel=1e-6), key
            # (surface.obj holds micrometres: the settle moves a little)
            assert now["before"][key] == pytest.approx(given["before"][key], rel=1e-3), key


HIGH = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


def test_design_refuses_an_empty_folder_name_as_fit_and_relax_do(tmp_path, monkeypatch):
    # `sitrelax design POSE --out ""` wrote the design into the current folder and printed
    # "wrote /scenario.toml"; `fit` and `relax` refuse the empty name before any work
    import solver.scene.design as design

    def no_fit(*args, **kwargs):
        raise AssertionError("fitted before the folder was checked")

    monkeypatch.setattr(design, "_fit_design", no_fit)
    monkeypatch.chdir(tmp_path)
    for name in ("", "  "):
        with pytest.raises(ValueError, match="empty name"):
            design.run_design([HIGH], name, pictures=False)
    assert list(tmp_path.iterdir()) == []


def test_design_refuses_a_relaxations_folder_before_it_fits(tmp_path, monkeypatch):
    # the refusal came only after the whole fit (10-30 s with relief); `fit` refuses at once
    import solver.scene.design as design

    out = tmp_path / "relaxed"
    out.mkdir()
    report = {"persons": [], "files": ["relax.png", "person_1_relaxed.obj"]}
    (out / "report.json").write_text(json.dumps(report))

    def no_fit(*args, **kwargs):
        raise AssertionError("fitted before the folder was checked")

    monkeypatch.setattr(design, "_fit_design", no_fit)
    with pytest.raises(ValueError, match="holds a relaxation's results"):
        design.run_design([HIGH], out, pictures=False)
    assert sorted(p.name for p in out.iterdir()) == ["report.json"]


def test_a_design_leaves_the_try_of_a_design_running_beside_in_the_same_folder(tmp_path,
                                                                                monkeypatch):
    # two designs into one folder: the second removed the first's hidden folder as it worked
    # in it, and the first stopped with "No such folder to write into: .../.straight-..."
    import os
    import subprocess
    import sys

    import solver.scene.design as design
    from solver.surface.fit import FitError

    out = tmp_path / "out"
    out.mkdir()
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                           capture_output=True, text=True, check=True)
    running = out / f".straight-{os.getpid()}-beside"  # (this process runs)
    gone = out / f".straight-{int(ended.stdout)}-killed"  # (its process ended)
    for stage in (running, gone):
        stage.mkdir()
        (stage / "scenario.toml").write_text("# a try")

    def failing(*args, **kwargs):
        raise FitError("no fit")

    monkeypatch.setattr(design, "_fit_design", failing)
    with pytest.raises(FitError):
        design.run_design([HIGH], out, pictures=False)
    assert (running / "scenario.toml").read_text() == "# a try"
    assert not gone.exists()


def test_a_folder_design_cannot_write_into_is_named_as_fit_names_it(tmp_path, monkeypatch):
    # `fit` says "Cannot write the results into this folder (Permission denied): DIR"; the
    # design named a hidden folder of its own that the user never made (DIR/.straight-...)
    import errno
    import tempfile

    import solver.scene.design as design

    out = tmp_path / "locked"
    out.mkdir()

    def denied(prefix=None, dir=None, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", f"{dir}/{prefix}x1y2z3")

    monkeypatch.setattr(tempfile, "mkdtemp", denied)
    with pytest.raises(OSError) as caught:
        design.run_design([HIGH], out, pictures=False)
    assert caught.value.filename == str(out)
    assert "Cannot write the results into this folder" in caught.value.strerror


def test_the_gate_refuses_skin_sunk_further_under_the_floor():
    """A relaxed pose may not put skin more than 1 mm under the floor, nor deeper than the
    pose before it was (`SupportGate.floor`); without a floor nothing is said of it."""
    import numpy as np

    from solver.body.relax import FLOOR_TOLERANCE
    from solver.contact.evaluate import SupportGate

    gate = SupportGate(None, None, None, 0.03, None, 0.0)
    assert gate.floor_figures(np.array([[0.0, -0.004, 0.0], [0.0, 1.0, 0.0]])) == \
        {"below_floor_m": 0.004}
    assert gate.floor_figures(np.array([[0.0, 0.2, 0.0]])) == {"below_floor_m": 0.0}
    on, within, under = ({"below_floor_m": d} for d in (0.0, 0.5 * FLOOR_TOLERANCE, 2 * FLOOR_TOLERANCE))
    assert gate.worse(on, within) == [] and gate.worse(on, under) == ["below_floor_m"]
    assert gate.worse(under, under) == [] and gate.worse(under, on) == []
    assert SupportGate(None, None, None, 0.03, None).floor_figures(np.zeros((1, 3))) == {}


@pytest.mark.slow  # two fits with relief and a relaxation (about 15 s)
def test_a_relaxed_body_keeps_its_feet_on_the_floor(tmp_path):
    """The thin body of figure 8 relaxed onto the overweight body's relieved seat: the
    relaxation pulled it down onto the seat with its feet 18 mm through the floor; the floor
    is held now (and the gate refuses what sinks under it)."""
    import trimesh

    from solver.body.relax import FLOOR_TOLERANCE

    run_fit(EXAMPLES / "seat_for_heavy.toml", tmp_path / "heavy", pictures=False)
    report = run_relax(EXAMPLES / "seat_for_thin.toml", tmp_path / "thin_on_heavy",
                       surface_dir=tmp_path / "heavy")
    body = trimesh.load(tmp_path / "thin_on_heavy" / "person_1_relaxed.obj", process=False)
    assert body.vertices[:, 1].min() >= -FLOOR_TOLERANCE - 1e-6, body.vertices[:, 1].min()
    before, after = report["persons"][0]["before"], report["persons"][0]["after"]
    assert after["mean_support_distance_m"] <= before["mean_support_distance_m"]
