"""The pressure model (section 4) and its rigid-mould reference."""

import igl
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from solver.body.model import make_body
from solver.body.poses import load_pose, pose_body
from solver.contact.pressure import pressure_field
from solver.mesh import vertex_normals, voronoi_areas
from solver.contact.pressure import mould_vertices
from solver.contact.rigid_mould import rigid_mould_contact
from solver.mesh import volume_centroid
from solver.body.skinning import skin


@pytest.fixture(scope="module")
def seated():
    body = make_body()
    motion = pose_body(load_pose("bundled:cmu_75_18_high_sit.bvh#frame=39"), body)
    return body, skin(body, motion.frame(0), normals=False)[0]


def test_areas_and_normals_match_libigl(seated):
    body, verts = seated
    t = body.triangles
    mass = igl.massmatrix(verts, t, igl.MASSMATRIX_TYPE_VORONOI)
    np.testing.assert_allclose(voronoi_areas(verts, t), mass.diagonal(), rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(vertex_normals(verts, t), igl.per_vertex_normals(
        verts, t, igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA), atol=1e-12)
    # Voronoi areas tile the surface
    assert voronoi_areas(verts, t).sum() == pytest.approx(
        trimesh.Trimesh(verts, t, process=False).area, rel=1e-12)


def test_plates_by_hand():
    # a square plate of two triangles facing down (normal -Y), then turned up and sideways
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], dtype=float)
    down = np.array([[0, 1, 2], [0, 2, 3]])
    f = pressure_field(v, down)
    np.testing.assert_allclose(f.pressure, 1.0)
    np.testing.assert_allclose(f.area.sum(), 1.0)
    np.testing.assert_allclose(f.reaction, f.area)
    assert f.importance.max() == 1.0
    up = down[:, ::-1]
    np.testing.assert_allclose(pressure_field(v, up).pressure, 0.0)
    side = v[:, [0, 2, 1]]  # the plate stood up in the XY plane
    np.testing.assert_allclose(pressure_field(side, down).pressure, 0.0, atol=1e-15)
    tilted = v @ Rotation.from_euler("z", 60, degrees=True).as_matrix().T
    np.testing.assert_allclose(pressure_field(tilted, down).pressure, 0.5, atol=1e-12)


def test_turning_body_and_gravity_together_changes_nothing(seated):
    body, verts = seated
    rot = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    a = pressure_field(verts, body.triangles)
    b = pressure_field(verts @ rot.T, body.triangles, gravity=rot @ [0, -1, 0])
    np.testing.assert_allclose(b.importance, a.importance, atol=1e-12)


def test_importance_is_restricted_to_chosen_parts(seated):
    body, verts = seated
    mask = body.part_mask(["torso", "legs"])
    f = pressure_field(verts, body.triangles, mask=mask)
    assert f.importance.max() == pytest.approx(1.0)
    assert (f.importance[~mask] == 0).all()
    assert (f.importance[mask] > 0).mean() > 0.3
    # seated: the underside of the thighs and the buttocks carry the most
    top = np.argsort(f.importance)[-200:]
    assert np.isin(body.parts[top], [1, 4]).all()
    assert np.median(verts[top, 1]) < 0.6


def test_reference_without_friction_is_the_model_on_a_sphere():
    """A sphere in its mould, loaded through its centre, sinks straight down; without friction
    every contact force is then exactly k A max(0, -n_y): the model's."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    sol = rigid_mould_contact(v, t, mu=0.0)
    assert sol.residual < 1e-6
    np.testing.assert_allclose(sol.rotation, 0.0, atol=1e-15)
    model = pressure_field(v, t).reaction[sol.vertices]
    np.testing.assert_allclose(sol.normal / sol.normal.max(), model / model.max(), atol=1e-6)
    assert np.abs(sol.tangential_force).max() == 0.0


def test_reference_balances_the_load(seated):
    body, verts = seated
    sol = rigid_mould_contact(verts, body.triangles, load=735.0)
    total = (sol.normal_force + sol.tangential_force).sum(axis=0)
    # the force the body puts on the support (`ContactForces`), as the other references give it
    np.testing.assert_allclose(total, [0.0, -735.0, 0.0], atol=1e-6)
    centre = volume_centroid(verts, body.triangles)
    moment = np.cross(verts[sol.vertices] - centre, sol.normal_force + sol.tangential_force)
    np.testing.assert_allclose(moment.sum(axis=0), 0.0, atol=1e-6)
    # Coulomb: no tangential force exceeds mu times its normal force
    ratio = np.linalg.norm(sol.tangential_force, axis=1) / np.maximum(sol.normal, 1e-300)
    assert ratio.max() <= 0.5 + 1e-9
    assert set(sol.vertices) == set(mould_vertices(verts, body.triangles))


@pytest.mark.slow
def test_model_against_every_reference_on_every_pose():
    """Acceptance 4: on every pose, reference and mu, the paper's model at least twice as good
    as the all-zero model (over all mould vertices and over the loaded ones), and the
    equilibrium model within RMSE 0.05 of the finite-element reference."""
    from solver.scene.validate import validate_pressure

    rows = validate_pressure()
    assert {r["pose"] for r in rows} == {"seated", "lying", "reclining"}
    assert len(rows) == 3 * 3 * 3 * 2
    for r in rows:
        assert r["residual"] < 1e-3, r
        if r["model"] == "paper":
            assert r["zero_all"] >= 2 * r["rmse_all"], r
            assert r["zero_loaded"] >= 2 * r["rmse_loaded"], r
        if r["model"] == "equilibrium" and r["reference"] == "soft layer FE":
            assert r["rmse_all"] <= 0.05 and r["rmse_loaded"] <= 0.05, r


def test_bad_gravity_is_named(seated):
    body, verts = seated
    with pytest.raises(ValueError, match="non-zero gravity"):
        pressure_field(verts, body.triangles, gravity=(0, 0, 0))


def test_bad_bodies_are_named_not_given_zero_importance():
    """A vertex that is not a number would leave every importance 0 with no word; it, an index
    past the vertices, a flat array and a mask of another length are refused by name."""
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    t = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
    assert pressure_field(v, t).importance.max() == 1.0
    bad = v.copy()
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="finite vertices, got 1 that are not .*vertex 2"):
        pressure_field(bad, t)
    with pytest.raises(ValueError, match=r"indices in 0..3, got 0..4"):
        pressure_field(v, np.array([[0, 1, 4]]))
    with pytest.raises(ValueError, match=r"\(V, 3\) vertices"):
        pressure_field(v[:, :2], t)
    with pytest.raises(ValueError, match="a mask of 4 entries"):
        pressure_field(v, t, mask=np.ones(3, dtype=bool))


def test_the_equilibrium_model_balances_the_body_or_says_it_cannot(seated):
    """The equilibrium compression carries the unit load (its springs' forces and moments
    balance it); when its Newton steps stop short of a balance, it says so rather than
    returning the compression of the last step."""
    from solver.contact.equilibrium import equilibrium_compression

    body, verts = seated
    t = body.triangles
    n, a = vertex_normals(verts, t), voronoi_areas(verts, t)
    g, c = np.array([0.0, -1.0, 0.0]), volume_centroid(verts, t)
    delta = equilibrium_compression(verts, n, a, g, c, mu=0.0)
    force = ((a * delta)[:, None] * n).sum(axis=0)  # springs push along -n on the skin ...
    assert np.allclose(-force / np.linalg.norm(force), -g, atol=1e-6)  # ... against gravity
    with pytest.raises(ValueError, match="finds no balance on its envelope of springs within 0"):
        equilibrium_compression(verts, n, a, g, c, max_iterations=0)
