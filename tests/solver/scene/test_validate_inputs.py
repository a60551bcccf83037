"""`sitrelax validate pressure`'s inputs: what it refuses before the work (a minute with the
finite elements), and a pictures folder written whole or not at all."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

import solver.scene.validate as validate
from solver.cli import main
from solver.scene.validate import validate_pressure


class _WorkStarted(Exception):
    """Raised by the stand-ins below: the refusal came too late."""


@pytest.fixture
def no_work(monkeypatch):
    def started(*args, **kwargs):
        raise _WorkStarted

    monkeypatch.setattr(validate, "make_body", started)
    monkeypatch.setattr(validate, "validation_poses", started)


@pytest.fixture
def quick_work(monkeypatch):
    """The comparison on two stand-in poses of three vertices: every step but the numbers."""
    contact = np.arange(3)
    field = np.array([1.0, 2.0, 3.0])
    ref = SimpleNamespace(vertices=contact, normal=np.array([1.0, 2.0, 3.5]),
                          reaction=np.array([1.0, 2.0, 3.5]), residual=0.0)
    monkeypatch.setattr(validate, "make_body",
                        lambda *a, **k: SimpleNamespace(triangles=np.zeros((1, 3), int)))
    monkeypatch.setattr(validate, "validation_poses",
                        lambda *a, **k: {"seated": np.zeros((3, 3)), "lying": np.zeros((3, 3))})
    monkeypatch.setattr(validate, "mould_vertices", lambda verts, tris: contact)
    monkeypatch.setattr(validate, "_model_fields",
                        lambda verts, tris, contact: {"paper": (field, 1.0)})
    monkeypatch.setattr(validate, "run_reference", lambda name, verts, tris, mu: ref)
    drawn = []

    def picture(out_dir, pose, *rest):
        drawn.append(pose)
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / f"pressure_{pose}.png"
        path.write_bytes(b"png")
        return path

    monkeypatch.setattr(validate, "_picture", picture)
    return drawn


@pytest.mark.parametrize("out, error, message", [
    ("", ValueError, "Expected a results folder, got an empty name"),
    ("a_file/pictures", OSError, "Not a directory"),
])
def test_a_pictures_folder_that_cannot_be_made_is_refused_before_the_work(tmp_path, no_work,
                                                                          out, error, message):
    (tmp_path / "a_file").write_text("mine")
    with pytest.raises(error, match=message):
        validate_pressure(str(tmp_path / out) if out else out)
    assert (tmp_path / "a_file").read_text() == "mine"


@pytest.mark.parametrize("kwargs, message", [
    ({"mus": [0.5, -0.1]}, r"friction coefficients >= 0 \(finite\), got -0.1"),
    ({"mus": [float("nan")]}, r"friction coefficients >= 0 \(finite\), got nan"),
    ({"mus": []}, "at least one friction coefficient"),
    # (not a list: the message itself raised a TypeError)
    ({"mus": 0.5}, r"friction coefficients as a list of numbers, got 0.5"),
    ({"mus": ["high"]}, r"friction coefficients as a list of numbers, got \['high'\]"),
    ({"references": ["rigid mould", "soft layer"]}, "Expected a reference in .*got 'soft layer'"),
    ({"references": []}, "at least one reference"),
])
def test_bad_friction_coefficients_and_references_are_refused_before_the_work(no_work, kwargs,
                                                                               message):
    with pytest.raises(ValueError, match=message):
        validate_pressure(**kwargs)


def test_a_run_that_fails_half_way_leaves_no_pictures_behind(tmp_path, monkeypatch,
                                                              quick_work):
    draw = validate._picture

    def second_fails(out_dir, pose, *rest):
        if quick_work:  # (the second picture)
            raise OSError(28, "No space left on device", str(out_dir / f"pressure_{pose}.png"))
        return draw(out_dir, pose, *rest)

    monkeypatch.setattr(validate, "_picture", second_fails)
    with pytest.raises(OSError, match="No space left"):
        validate_pressure(tmp_path / "pictures", mus=[0.5], references=["rigid mould"])
    assert not (tmp_path / "pictures").exists()
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "notes.txt").write_text("mine")
    quick_work.clear()
    with pytest.raises(OSError, match="No space left"):
        validate_pressure(tmp_path / "kept", mus=[0.5], references=["rigid mould"])
    assert sorted(p.name for p in (tmp_path / "kept").iterdir()) == ["notes.txt"]


def test_pictures_are_named_in_the_folder_asked_for_and_repeats_run_once(tmp_path, quick_work):
    rows = validate_pressure(tmp_path / "pictures", mus=[0.5, 0.5, 0.3],
                             references=["rigid mould", "rigid mould"])
    assert [(r["pose"], r["mu"]) for r in rows] == [("seated", 0.5), ("seated", 0.3),
                                                    ("lying", 0.5), ("lying", 0.3)]
    assert {r["picture"] for r in rows} == {str(tmp_path / "pictures" / "pressure_seated.png"),
                                           str(tmp_path / "pictures" / "pressure_lying.png")}
    assert sorted(p.name for p in (tmp_path / "pictures").iterdir()) == [
        "pressure_lying.png", "pressure_seated.png"]  # (no hidden folder left)


def test_the_command_refuses_an_empty_out_in_json_before_the_work(tmp_path, no_work, capsys,
                                                                   monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["validate", "pressure", "--quick", "--out", "", "--json"]) == 2
    captured = capsys.readouterr()
    assert json.loads(captured.out) == {
        "error": "Expected a results folder, got an empty name", "exit_status": 2}
    assert "Traceback" not in captured.err
    assert list(tmp_path.iterdir()) == []


def test_what_the_solvers_print_leaves_the_json_alone(monkeypatch, capfd):
    # (OSQP and the like print past Python onto descriptor 1, as `sitrelax fit` knows)
    import os

    def chatty(out_dir, *, mus, references, progress):
        print("solver says hello")
        os.write(1, b"ERROR in LDL_factor\n")
        return []

    monkeypatch.setattr(validate, "validate_pressure", chatty)
    assert main(["validate", "pressure", "--quick", "--json"]) == 0
    captured = capfd.readouterr()
    assert json.loads(captured.out) == []
    assert "solver says hello" in captured.err and "LDL_factor" in captured.err


def _rows(rmse: float, converged=True) -> list[dict]:
    return [{"pose": "seated", "vertices": 3, "reference": "soft layer FE", "mu": 0.5,
             "model": "paper", "rmse_all": rmse, "zero_all": 0.5, "rmse_loaded": rmse,
             "zero_loaded": 0.5, "crude_all": 0.2, "crude_loaded": 0.3, "pearson_r": 0.9, "model_ms": 1.0, "reference_s": 1.0,
             "residual": 0.0, "converged": converged}]


@pytest.mark.parametrize("rows, bar, status, said", [
    (_rows(0.04), None, 0, None),  # (reports only, as before)
    (_rows(0.06), None, 0, None),
    (_rows(0.04), 0.05, 0, None),
    (_rows(0.06), 0.05, 1, "paper model vs soft layer FE, mu = 0.5: RMSE 0.060 over 0.05"),
    (_rows(0.01, converged=False), 0.05, 1, "the reference did not converge"),
])
def test_a_bar_makes_validate_fail_where_a_model_misses_it(monkeypatch, capsys, rows, bar,
                                                           status, said):
    """`--bar RMSE`: exit status 1 (for a script or CI) when a model is further than that from
    a reference, or a reference did not converge; without it the command reports only."""
    import solver.scene.validate as module

    monkeypatch.setattr(module, "validate_pressure", lambda *a, **k: rows)
    args = ["validate", "pressure", "--quick"] + (["--bar", str(bar)] if bar else [])
    assert main(args) == status
    out = capsys.readouterr().out
    assert (said in out) if said else "misses the bar" not in out
    assert main(args + ["--json"]) == status
    assert json.loads(capsys.readouterr().out) == rows


def test_the_text_says_when_a_reference_did_not_converge_or_matches_exactly(monkeypatch,
                                                                           capsys):
    """Without --bar the text report flagged nothing of a reference that did not converge (a
    perfect-looking row, exit 0), and an RMSE of exactly 0 ended it in a ZeroDivisionError; a
    run without the finite elements says what its references share with the model."""
    import solver.scene.validate as module

    rows = _rows(0.0, converged=False)
    monkeypatch.setattr(module, "validate_pressure", lambda *a, **k: rows)
    assert main(["validate", "pressure", "--quick"]) == 0
    out = capsys.readouterr().out
    assert "reference not converged" in out
    assert "warning: seated, soft layer FE, mu = 0.5: the reference did not converge" in out
    assert "equal to the reference (RMSE 0)" in out
    rows[0].update(reference="contact programme", converged=None, rmse_all=0.01)
    assert main(["validate", "pressure", "--quick"]) == 0
    out = capsys.readouterr().out
    assert "warning" not in out and "50.0x better" in out
    assert "share the model's vertices and contact law" in out
