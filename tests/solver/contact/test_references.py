"""The independent references for the pressure model (soft-layer FE, contact programme), the
equilibrium-aware model, and the validation's metrics."""

import time

import numpy as np
import pytest
import trimesh

from solver.body.model import make_body
from solver.body.poses import load_pose, pose_body
from solver.body.skinning import skin
from solver.contact import equilibrium
from solver.contact.pressure import mould_vertices, pressure_field
from solver.contact.programme import contact_programme
from solver.contact.soft_layer import layer_mesh, soft_layer_contact
from solver.mesh import triangle_mesh, volume_centroid
from solver.scene.validate import field_metrics


@pytest.fixture(scope="module")
def seated():
    body = make_body()
    motion = pose_body(load_pose("bundled:cmu_75_18_high_sit.bvh#frame=39"), body)
    return body, skin(body, motion.frame(0), normals=False)[0]


def _sphere():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    return np.asarray(s.vertices), np.asarray(s.faces)


def test_a_flat_block_sinks_into_its_layer_by_the_oedometric_law():
    """A wide rigid block pressed into a thin layer: away from the edges the layer is in
    uniaxial strain, so the pressure is E_oed d / h with E_oed = E (1 - nu) / ((1 + nu)(1 - 2 nu)),
    and the forces balance the load."""
    box = trimesh.creation.box(extents=(0.6, 0.06, 0.6))
    box = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(box.vertices, box.faces, 0.04))
    v, t = np.asarray(box.vertices), np.asarray(box.faces)
    youngs, nu, h = 1e5, 0.4, 0.01
    sol = soft_layer_contact(v, t, mu=0.0, thickness=h, youngs=youngs, poisson=nu, faces=0,
                             layers=2)
    assert sol.converged and sol.residual < 1e-6 * 735
    total = (sol.normal_force + sol.tangential_force).sum(axis=0)
    np.testing.assert_allclose(total, [0.0, -735.0, 0.0], atol=0.005 * 735)  # interpolated
    np.testing.assert_allclose(sol.rotation[[0, 2]], 0.0, atol=1e-8)  # it does not tip
    e_oed = youngs * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    sink = -sol.translation[1]
    area = triangle_mesh(t, len(v)).measures(v)[0][sol.vertices]
    p = v[sol.vertices]
    inner = (p[:, 1] < -0.029) & (np.abs(p[:, 0]) < 0.15) & (np.abs(p[:, 2]) < 0.15)
    pressure = sol.normal[inner] / area[inner]
    np.testing.assert_allclose(pressure, e_oed * sink / h, rtol=0.01)
    # most of the load goes through the bottom, at about the load over its area
    assert 0.9 < pressure.mean() * 0.36 / 735 < 1.1


def test_layer_prisms_are_conforming_and_positive():
    v, t = _sphere()
    n = triangle_mesh(t, len(v)).measures(v)[1]
    mesh = layer_mesh(v, t, n, 0.01, layers=2)
    assert len(mesh.tetrahedra) == 3 * 2 * len(t)
    p = mesh.points[mesh.tetrahedra]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    assert (vol > 0).all()
    # a closed shell: the volumes add up to the layer's, and every inner face is shared twice
    outer = 4 / 3 * np.pi * ((0.31) ** 3 - 0.3 ** 3)
    assert vol.sum() / 6 == pytest.approx(outer, rel=0.02)
    faces = np.sort(np.concatenate([mesh.tetrahedra[:, list(c)] for c in
                                    ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3))]), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert set(counts) == {1, 2}
    assert (counts == 1).sum() == 2 * len(t)  # only the inner and outer faces are boundary


def test_frictionless_programme_is_the_model_on_a_sphere():
    v, t = _sphere()
    sol = contact_programme(v, t, mu=0.0)
    assert sol.residual < 1e-6
    model = pressure_field(v, t).reaction[sol.vertices]
    # to the interior-point method's complementarity tolerance
    np.testing.assert_allclose(sol.normal / sol.normal.max(), model / model.max(), atol=1e-4)
    np.testing.assert_allclose(sol.tangential_force, 0.0, atol=1e-9)


def test_programme_balances_the_load_in_the_friction_cone(seated):
    body, verts = seated
    sol = contact_programme(verts, body.triangles, mu=0.3)
    total = (sol.normal_force + sol.tangential_force).sum(axis=0)
    np.testing.assert_allclose(total, [0.0, -735.0, 0.0], atol=1e-5)
    centre = volume_centroid(verts, body.triangles)
    moment = np.cross(verts[sol.vertices] - centre, sol.normal_force + sol.tangential_force)
    np.testing.assert_allclose(moment.sum(axis=0), 0.0, atol=1e-5)
    tang = np.linalg.norm(sol.tangential_force, axis=1)
    assert (tang <= 0.3 * sol.normal + 1e-6).all()
    assert tang.sum() > 0.05 * sol.normal.sum()  # friction carries some of the load
    assert set(sol.vertices) == set(mould_vertices(verts, body.triangles))


def test_equilibrium_model_is_the_paper_model_on_a_sphere():
    v, t = _sphere()
    paper = pressure_field(v, t)
    balanced = pressure_field(v, t, model="equilibrium", mu=0.5)
    np.testing.assert_allclose(balanced.importance, paper.importance, atol=1e-6)


def test_equilibrium_jacobian_is_the_finite_difference(seated):
    body, verts = seated
    a, n = triangle_mesh(body.triangles, len(verts)).measures(verts)
    keep = n @ [0, -1, 0] >= 0
    x = verts[keep] - volume_centroid(verts, body.triangles)
    x = x / np.linalg.norm(x, axis=1).max()
    n, a = n[keep], a[keep]
    w = np.concatenate([n, np.cross(x, n)], axis=1)
    z = np.array([0.2, -1.0, 0.3, 0.3, 0.15, -0.2]) / np.sum(a * n[:, 1] ** 2)
    _, jac, _ = equilibrium._balance(z, n, a, x, w, 0.5, equilibrium.SHEAR_RATIO)
    h = 1e-7 * np.abs(z).max()
    fd = np.stack([(equilibrium._balance(z + h * e, n, a, x, w, 0.5, equilibrium.SHEAR_RATIO)[0]
                    - equilibrium._balance(z - h * e, n, a, x, w, 0.5,
                                           equilibrium.SHEAR_RATIO)[0]) / (2 * h)
                   for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(jac, fd, atol=1e-6 * np.abs(jac).max())


def test_equilibrium_model_is_a_field_on_the_same_vertices(seated):
    body, verts = seated
    paper = pressure_field(verts, body.triangles)
    balanced = pressure_field(verts, body.triangles, model="equilibrium")
    assert balanced.importance.max() == pytest.approx(1.0)
    assert (balanced.importance[paper.reaction == 0] == 0).all()
    assert balanced.pressure.max() == pytest.approx(1.0)
    np.testing.assert_allclose(balanced.reaction, balanced.area * balanced.pressure)
    # close to the paper's, but not the same: the body turns
    diff = np.abs(balanced.importance - paper.importance)
    assert 0.01 < diff.max() < 0.5


def test_bad_model_is_named(seated):
    body, verts = seated
    with pytest.raises(ValueError, match="model in"):
        pressure_field(verts, body.triangles, model="abaqus")


def test_field_metrics_by_hand():
    ref = np.array([0.0, 0.02, 0.5, 1.0])
    m = field_metrics(2 * np.array([0.0, 0.0, 0.5, 1.0]), ref, loaded=0.05)
    assert m["loaded_vertices"] == 2
    assert m["rmse_all"] == pytest.approx(0.01)  # sqrt(0.02^2 / 4)
    assert m["rmse_loaded"] == 0.0
    assert m["zero_all"] == pytest.approx(np.sqrt((0.02 ** 2 + 0.25 + 1) / 4))
    assert m["zero_loaded"] == pytest.approx(np.sqrt(1.25 / 2))
    assert m["pearson_r"] == pytest.approx(np.corrcoef([0, 0, 0.5, 1], ref)[0, 1])


@pytest.mark.slow
def test_soft_layer_on_a_real_pose_under_a_minute():
    """Acceptance 5 (part): the finite-element reference on the lying pose (the slowest) for all
    three friction coefficients within a minute, balanced, and the paper's model at least
    twice as good as the all-zero model; the equilibrium model within 0.05 of it."""
    from solver.scene.validate import MUS, validation_poses

    body = make_body()
    verts = validation_poses()["lying"]
    paper = pressure_field(verts, body.triangles)
    balanced = pressure_field(verts, body.triangles, model="equilibrium")
    start = time.perf_counter()
    for mu in MUS:
        sol = soft_layer_contact(verts, body.triangles, mu=mu)
        assert sol.converged and sol.residual < 1e-3
        m = field_metrics(paper.reaction[sol.vertices], sol.normal)
        assert m["zero_all"] >= 2 * m["rmse_all"] and m["pearson_r"] > 0.9, m
        m = field_metrics(balanced.reaction[sol.vertices], sol.normal)
        assert m["rmse_all"] <= 0.05 and m["rmse_loaded"] <= 0.05, m
    assert time.perf_counter() - start < 60.0


def _slab_response(points, tetrahedra, h, youngs, nu):
    """A rigid flat block pressed by 735 N into a slab layer (top face y = 0, bottom y = -h
    fixed), solved by the soft layer's finite elements on the given tetrahedra: the sink (m)
    and the total force (3,) on the layer."""
    from solver.contact.soft_layer import LayerMesh, _TrescaProblem, _stiffness

    top = np.flatnonzero(np.abs(points[:, 1]) < 1e-9)
    order = np.concatenate([top, np.setdiff1d(np.arange(len(points)), top)])  # contact first
    renumber = np.empty(len(points), dtype=np.int64)
    renumber[order] = np.arange(len(points))
    p = points[order]
    tets = renumber[tetrahedra]
    q = p[tets]
    vol = np.einsum("ij,ij->i", np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), q[:, 3] - q[:, 0])
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]
    outer = np.flatnonzero(np.abs(p[:, 1] + h) < 1e-9)
    mesh = LayerMesh(p, tets, np.arange(len(top)), outer)
    stiff, free = _stiffness(mesh, youngs, nu)
    k = len(top)
    normals = np.tile([0.0, -1.0, 0.0], (k, 1))
    problem = _TrescaProblem(stiff, free, normals, p[:k] - [0.0, 0.03, 0.0],
                             np.array([0.0, -735.0, 0.0]))
    force, motion = problem.solve(np.zeros(k))
    return -motion[1], force.sum(axis=0)


def test_the_layer_elements_agree_on_a_mesh_made_by_tetgen():
    """The soft layer's finite elements on two meshes of one 60 x 60 cm, 1 cm slab: tetgen's
    (a Delaunay mesher we did not write, from the slab's closed surface) and our prism
    extrusion. Both sink the block a little more than uniaxial strain gives, 735 N h /
    (E_oed A), the free edges being softer (by under 5 %), and agree with each other within
    1.5 %."""
    import tetgen

    from solver.contact.soft_layer import layer_mesh

    h, youngs, nu = 0.01, 1e5, 0.4
    box = trimesh.creation.box(extents=(0.6, h, 0.6))
    box = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(box.vertices, box.faces, 0.03))
    v = np.asarray(box.vertices) - [0.0, h / 2, 0.0]  # top at y = 0
    nodes, tets = tetgen.TetGen(v, np.asarray(box.faces)).tetrahedralize(switches="pYq1.5Q")[:2]
    sink_tetgen, total = _slab_response(np.asarray(nodes), np.asarray(tets, dtype=np.int64), h,
                                        youngs, nu)
    np.testing.assert_allclose(total, [0.0, -735.0, 0.0], atol=1e-6 * 735)
    # the extrusion of the same top face's grid, two prisms through the thickness
    grid = np.stack(np.meshgrid(np.linspace(-0.3, 0.3, 21), np.linspace(-0.3, 0.3, 21)), -1)
    top = np.column_stack([grid[..., 0].ravel(), np.zeros(441), grid[..., 1].ravel()])
    quads = np.array([[i * 21 + j, i * 21 + j + 1, (i + 1) * 21 + j + 1, (i + 1) * 21 + j]
                      for i in range(20) for j in range(20)])
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    layer = layer_mesh(top, tris, np.tile([0.0, -1.0, 0.0], (441, 1)), h, 2)
    sink_prisms, _ = _slab_response(layer.points, layer.tetrahedra, h, youngs, nu)
    e_oed = youngs * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    uniaxial = 735.0 * h / (e_oed * 0.36)
    # measured: uniaxial 95.3 um, tetgen 98.3 um, prisms 97.8 um (the free edges are softer)
    assert 1.0 < sink_tetgen / uniaxial < 1.05 and 1.0 < sink_prisms / uniaxial < 1.05
    assert abs(sink_tetgen / sink_prisms - 1) < 0.015
