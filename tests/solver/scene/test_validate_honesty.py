"""`sitrelax validate pressure` can fail: a wrong field is told from a right one on the real
seated body, hand cases of the metrics, and a reference that did not converge is reported so."""

from types import SimpleNamespace

import numpy as np
import pytest

import solver.scene.validate as validate
from solver.scene.validate import field_metrics, validate_pressure


def test_the_metrics_on_fields_worked_by_hand():
    same = field_metrics(np.array([1.0, 2.0, 4.0]), np.array([0.5, 1.0, 2.0]))
    assert same["rmse_all"] == 0.0 and same["pearson_r"] == pytest.approx(1.0)
    # each normalised by its largest value: (1, 0) against (0, 1)
    crossed = field_metrics(np.array([2.0, 0.0]), np.array([0.0, 3.0]))
    assert crossed["rmse_all"] == pytest.approx(1.0)
    assert crossed["zero_all"] == pytest.approx(np.sqrt(0.5))
    assert crossed["rmse_loaded"] == pytest.approx(1.0) and crossed["loaded_vertices"] == 1


@pytest.fixture(scope="module")
def seated():
    from solver.body.model import make_body
    from solver.contact.pressure import mould_vertices, pressure_field
    from solver.contact.programme import contact_programme

    body = make_body()
    vertices = validate.validation_poses()["seated"]
    contact = mould_vertices(vertices, body.triangles)
    field = pressure_field(vertices, body.triangles)
    reference = contact_programme(vertices, body.triangles, mu=0.5)
    assert np.array_equal(reference.vertices, contact)
    return field.reaction[contact], field.area[contact], reference


def test_a_field_that_ignores_how_the_skin_faces_fails_where_the_model_passes(seated):
    """The vertex area alone (the paper's model without max(0, n . g)) against the contact
    programme: far over the 0.05 bar and no better than the all-zero model, where the paper's
    model is under the bar and several times better."""
    model, area, reference = seated
    right = field_metrics(model, reference.normal)
    wrong = field_metrics(area, reference.normal)
    assert right["rmse_all"] < 0.05 and right["zero_all"] > 2 * right["rmse_all"]
    assert wrong["rmse_all"] > 0.05 and wrong["rmse_all"] > right["zero_all"]
    assert wrong["rmse_loaded"] > 2 * right["rmse_loaded"]


def test_the_model_beats_the_crude_baseline_not_only_the_all_zero_one(seated):
    """Beating the all-zero field shows little (a field that only knows where the skin faces
    down does it): the crude baseline of `validate pressure` is that field, the skin's area
    wherever it faces down at all, and the paper's model is well over twice as close to the
    contact programme as it is."""
    model, area, reference = seated
    from solver.body.model import make_body

    crude = validate._crude_field(validate.validation_poses()["seated"], make_body().triangles,
                                  reference.vertices)
    np.testing.assert_array_equal(crude > 0, model > 0)  # (the same vertices, unweighted)
    right = field_metrics(model, reference.normal)
    rough = field_metrics(crude, reference.normal)
    assert rough["rmse_all"] > 2 * right["rmse_all"], (rough, right)
    assert rough["rmse_all"] < rough["zero_all"]  # (it does beat the all-zero field)


def test_a_reference_that_did_not_converge_says_so(monkeypatch):
    contact = np.arange(3)
    stopped = SimpleNamespace(vertices=contact, normal=np.array([1.0, 2.0, 3.0]),
                              reaction=np.array([1.0, 2.0, 3.0]), residual=0.5,
                              converged=False)
    monkeypatch.setattr(validate, "make_body",
                        lambda *a, **k: SimpleNamespace(triangles=np.zeros((1, 3), int)))
    monkeypatch.setattr(validate, "validation_poses", lambda *a, **k: {"seated": np.zeros((3, 3))})
    monkeypatch.setattr(validate, "mould_vertices", lambda verts, tris: contact)
    monkeypatch.setattr(validate, "_model_fields",
                        lambda verts, tris, contact: {"paper": (np.array([1.0, 2.0, 3.0]), 1.0)})
    monkeypatch.setattr(validate, "run_reference", lambda name, verts, tris, mu: stopped)
    (row,) = validate_pressure(mus=[0.5], references=["soft layer FE"])
    assert row["converged"] is False and row["residual"] == 0.5
