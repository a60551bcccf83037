"""`sitrelax relax`'s inputs: the surface's own softness margin is the one judged by, every mesh
format `sitrelax fit` writes is read (a folder or a file), a surface that cannot be used is
refused with one line naming it, and a pose library `--save` cannot store into is refused
before any work, with the error a `db` command gives."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from solver.cli import main
from solver.scene.run import run_fit

SEATED = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios" / "single_seated.toml"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A fit of the seated example (margin 3 cm) in OBJ, PLY and GLB, no pictures."""
    out = tmp_path_factory.mktemp("fit")
    run_fit(SEATED, out, formats=("obj", "ply", "glb"), pictures=False)
    return out


def _scenario(tmp_path: Path, margin: float) -> Path:
    path = tmp_path / "scene.toml"
    path.write_text(SEATED.read_text().replace("margin = 0.03", f"margin = {margin}"))
    return path


def _relax(args, capsys) -> tuple[int, dict | None, str]:
    """main(["relax", *args, "--json"]): the status, the JSON printed and standard error."""
    code = main(["relax", *map(str, args), "--json"])
    captured = capsys.readouterr()
    return code, json.loads(captured.out) if captured.out.strip() else None, captured.err


# -- the margin -----------------------------------------------------------------------------


def test_relax_judges_by_the_margin_the_surface_was_fitted_with(fitted, tmp_path, capsys):
    """A scenario saying 1 cm relaxed onto a surface fitted with 3 cm is judged by 3 cm (the
    foam's own softness): its figures before are the fit's own, and the output says so."""
    fit = json.loads((fitted / "report.json").read_text())
    code, report, err = _relax([_scenario(tmp_path, 0.01), "--surface", fitted,
                                "--out", tmp_path / "out"], capsys)
    assert code == 0, err
    (person,) = report["persons"]  # (judged by 1 cm, its coverage was 0.63 against 0.97)
    assert person["before"]["coverage"] == pytest.approx(fit["persons"][0]["coverage"],
                                                         abs=1e-3)
    assert report["margin_m"] == 0.03 and report["margin_from"] == "surface"
    assert "the surface's own (its fit's report.json), not the scenario's 1 cm" in err


def test_relax_presses_the_foam_the_surface_was_fitted_for(fitted, tmp_path, capsys):
    """The foam's stiffness, thickness and the cover's friction are the surface's too: a
    scenario saying 50 kPa/m, 5 cm and friction 0.3 relaxed onto a fit made for the default
    foam is judged with the fit's foam (its figures before are the fit's own)."""
    fit = json.loads((fitted / "report.json").read_text())
    scenario = _scenario(tmp_path, 0.03)
    scenario.write_text(scenario.read_text() + "\n[evaluation]\nfoam_stiffness = 50.0\n"
                        "foam_thickness = 0.05\nfriction = 0.3\n")
    code, report, err = _relax([scenario, "--surface", fitted, "--out", tmp_path / "out"],
                               capsys)
    assert code == 0, err
    expected = {key: fit["parameters"]["evaluation"][key]
                for key in ("foam_stiffness", "foam_thickness", "friction")}
    assert report["foam"] == expected == {"foam_stiffness": 200.0, "foam_thickness": 0.1,
                                          "friction": 0.5}
    (person,) = report["persons"]
    assert person["before"]["peak_pressure_kpa"] == pytest.approx(
        fit["persons"][0]["peak_pressure_kpa"], rel=1e-3)  # (the OBJ's 6 decimals)
    assert "foam (200 kPa/m, 10 cm, friction 0.5), the surface's own" in err


def test_relax_onto_a_surface_without_a_fits_report_judges_by_the_scenarios_margin(
        fitted, tmp_path, capsys):
    cad = tmp_path / "cad"
    cad.mkdir()
    shutil.copy(fitted / "surface.obj", cad / "seat.obj")
    code, report, err = _relax([_scenario(tmp_path, 0.01), "--surface", cad / "seat.obj",
                                "--out", tmp_path / "out"], capsys)
    assert code == 0, err
    assert report["margin_m"] == 0.01 and report["margin_from"] == "scenario"
    assert "the scenario's (no fit's report.json beside seat.obj)" in err


def test_relax_refuses_a_fit_report_it_cannot_read(fitted, tmp_path, capsys):
    shutil.copytree(fitted, tmp_path / "fit")
    (tmp_path / "fit" / "report.json").write_text("{ not json")
    out = tmp_path / "out"
    code, report, err = _relax([SEATED, "--surface", tmp_path / "fit", "--out", out], capsys)
    assert code == 2 and report["exit_status"] == 2
    assert report["error"].startswith("Expected the report of the fit that wrote surface.obj")
    assert "report.json cannot be read" in report["error"] and not out.exists()


@pytest.mark.parametrize("margin", [7.0, -0.01, "3 cm", None])
def test_relax_refuses_a_fit_report_whose_margin_no_scenario_may_hold(fitted, tmp_path, capsys,
                                                                      margin):
    """A report's margin is the fit's only within a scenario's bounds (0-0.5 m): 7 m was
    used as the depth bodies may sink (only a negative or non-number one was refused)."""
    shutil.copytree(fitted, tmp_path / "fit")
    report_path = tmp_path / "fit" / "report.json"
    report = json.loads(report_path.read_text())
    report["parameters"]["margin"] = margin
    report_path.write_text(json.dumps(report))
    out = tmp_path / "out"
    code, answer, err = _relax([SEATED, "--surface", tmp_path / "fit", "--out", out], capsys)
    assert code == 2 and answer["error"].startswith("Expected the fit's margin in metres in "), \
        answer
    assert not out.exists()


# -- the surface's formats and paths ---------------------------------------------------------


@pytest.mark.parametrize("kept", ["surface.ply", "surface.glb"])
def test_relax_reads_a_fit_folder_without_surface_obj(fitted, kept, tmp_path, capsys):
    """`fit --format ply` (or glb) writes no surface.obj: relax reads what it wrote, the same
    surface (its before figures are the OBJ's)."""
    folder = tmp_path / "fit"
    folder.mkdir()
    shutil.copy(fitted / kept, folder / kept)
    shutil.copy(fitted / "report.json", folder / "report.json")
    code, report, err = _relax([SEATED, "--surface", folder, "--out", tmp_path / "out"],
                               capsys)
    assert code == 0, err
    assert f"surface from {folder / kept}" in err and report["margin_from"] == "surface"
    fit = json.loads((fitted / "report.json").read_text())
    assert report["persons"][0]["before"]["coverage"] == pytest.approx(
        fit["persons"][0]["coverage"], abs=1e-3)


def test_relax_reads_the_surface_file_named(fitted, tmp_path, capsys):
    code, report, err = _relax([SEATED, "--surface", fitted / "surface.obj",
                                "--out", tmp_path / "out"], capsys)
    assert code == 0, err
    assert report["margin_from"] == "surface"


def test_relax_reads_a_triangulated_obj_from_cad(fitted, tmp_path, capsys):
    """A CAD export: triangles, in millimetres as its header states."""
    from solver.io.export import write_mesh
    from solver.io.obj import read_quad_obj
    from solver.mesh import quad_triangles

    v, quads = read_quad_obj(fitted / "surface.obj")
    write_mesh(tmp_path / "tris.obj", v, quad_triangles(quads), unit="mm")
    code, report, err = _relax([SEATED, "--surface", tmp_path / "tris.obj",
                                "--out", tmp_path / "out"], capsys)
    assert code == 0, err
    assert report["margin_from"] == "scenario"
    fit = json.loads((fitted / "report.json").read_text())
    assert report["persons"][0]["before"]["coverage"] == pytest.approx(
        fit["persons"][0]["coverage"], abs=1e-3)


def test_relax_names_what_it_reads_when_the_folder_holds_only_scene_3dm(tmp_path, capsys):
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "scene.3dm").write_bytes(b"3dm")
    code, report, err = _relax([SEATED, "--surface", tmp_path / "fit",
                                "--out", tmp_path / "out"], capsys)
    assert code == 2
    assert report["error"] == (
        f"Expected a `sitrelax fit` folder holding surface.obj, surface.ply, surface.glb, got "
        f"{tmp_path / 'fit'}, which holds none of them; its scene.3dm is not read: fit again "
        f"with --format obj (or ply, glb)")
    assert err.strip().splitlines()[-1] == f"sitrelax: error: {report['error']}"


@pytest.mark.parametrize("name, problem", [
    ("missing", "no such file or folder"),
    ("seat.3dm", "expected a surface file ending in .obj, .ply, .glb"),
    ("nan.ply", "expected finite coordinates, got vertex 2 at [nan, 0.5, 0.0]"),
    ("empty.ply", "expected faces, found none"),
    ("truncated.ply", "expected a PLY header ending in 'end_header'"),
    ("truncated.glb", "cannot be read as a mesh"),
    ("empty.obj", "expected quad faces, found none"),
])
def test_relax_refuses_a_surface_it_cannot_use_before_the_work(name, problem, tmp_path,
                                                               capsys, monkeypatch):
    import solver.scene.run as run
    from solver.io.export import ply_bytes

    def no_work(*args, **kwargs):
        raise AssertionError("the people were posed before the surface was checked")

    monkeypatch.setattr(run, "place_scene", no_work)
    path = tmp_path / name
    if name == "nan.ply":
        v = np.array([[0, 0.5, 0], [np.nan, 0.5, 0], [0, 0.5, 0.5]], dtype=float)
        path.write_bytes(ply_bytes(v, np.array([[0, 1, 2]])))
    elif name == "empty.ply":
        path.write_bytes(ply_bytes(np.zeros((0, 3)), np.zeros((0, 3), dtype=int)))
    elif name != "missing":
        path.write_bytes(b"")
    out = tmp_path / "out"
    code, report, err = _relax([SEATED, "--surface", path, "--out", out], capsys)
    assert code == 2 and report == {"error": report["error"], "exit_status": 2}
    assert problem in report["error"] and str(path) in report["error"]
    assert "Traceback" not in err and not out.exists()


# -- --save's library --------------------------------------------------------------------------


def _db_error(db: Path, capsys) -> str:
    """The error `sitrelax db tag` gives for the library `db`."""
    code = main(["db", "tag", "perch", "seen", "--db", str(db)])
    assert code == 2
    return capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.parametrize("kind", ["folder", "not a library", "read-only", "locked"])
def test_relax_save_checks_the_library_before_the_work(kind, fitted, tmp_path, capsys,
                                                       monkeypatch):
    import contextlib

    import solver.scene.run as run
    from posedb.locking import exclusive
    from tests.conftest import high_sit_library

    def no_work(*args, **kwargs):
        raise AssertionError("the relaxation's work began before the library was checked")

    monkeypatch.setattr(run, "place_scene", no_work)
    monkeypatch.setenv("SITRELAX_LOCK_TIMEOUT", "0")
    db = tmp_path / "poses.h5"
    if kind == "folder":
        db.mkdir()
    elif kind == "not a library":
        db.write_text("not a pose library")
    else:
        high_sit_library(db)
        if kind == "read-only":
            db.chmod(0o444)
    held = exclusive(db, timeout=0) if kind == "locked" else contextlib.nullcontext()
    with held:
        expected = _db_error(db, capsys)
        before = db.read_bytes() if db.is_file() else None
        out = tmp_path / "out"
        code = main(["relax", str(SEATED), "--surface", str(fitted), "--db", str(db), "--save",
                     "--out", str(out)])
    assert code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == expected
    assert not out.exists()
    assert before is None or db.read_bytes() == before


def test_relax_save_takes_the_lock_timeout_the_db_commands_take(fitted, tmp_path, capsys,
                                                                monkeypatch):
    """`--lock-timeout S`, as every `db` command has it (the locked library's message names
    it): with another writer holding the library, relax waits S seconds and then refuses,
    whatever $SITRELAX_LOCK_TIMEOUT says; a NaN is refused by name."""
    import time

    from posedb.locking import exclusive
    from tests.conftest import high_sit_library

    monkeypatch.setenv("SITRELAX_LOCK_TIMEOUT", "none")  # (would wait as long as it is held)
    db = high_sit_library(tmp_path / "poses.h5")
    with exclusive(db, timeout=0):
        start = time.monotonic()
        code = main(["relax", str(SEATED), "--surface", str(fitted), "--db", str(db), "--save",
                     "--lock-timeout", "0.3", "--out", str(tmp_path / "out")])
        waited = time.monotonic() - start
    assert code == 2 and 0.3 <= waited < 5.0, waited
    assert "lock" in capsys.readouterr().err.lower()
    assert main(["relax", str(SEATED), "--surface", str(fitted), "--db", str(db), "--save",
                 "--lock-timeout", "nan", "--out", str(tmp_path / "out")]) == 2
    assert "--lock-timeout" in capsys.readouterr().err
