"""Pose relaxation: analytic Jacobians, settling onto a surface, and BVH of relaxed poses."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from capture import Motion, identify_profile, read_bvh, resolve_path, write_bvh
from solver.body.model import make_body
from solver.contact.settle import Foam
from solver.contact.evaluate import evaluate_person
from solver.contact.supported import SupportedBody
from solver.mesh import SurfaceMesh
from solver.body.poses import load_pose, pose_body
from solver.contact.pressure import pressure_field
from solver.mesh import triangle_mesh
from solver.body.relax import (
    DEFAULT_LIMIT,
    JOINT_LIMITS,
    RelaxProblem,
    _Model,
    joint_bounds,
    relax,
    residual_jacobian,
    residuals,
)
from solver.body.rig import pose_channels, rig_pose, rig_skeleton
from solver.body.skinning import skin
from solver.surface.subdivision import grid_mesh

EXAMPLES = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios"


@pytest.fixture(scope="module")
def hovering():
    """A seated body 5 cm above a flat seat under its thighs."""
    body = make_body()
    motion = pose_body(load_pose("bundled:cmu_75_18_high_sit.bvh#frame=39"), body)
    verts, _ = skin(body, motion.frame(0), normals=False)
    mask = body.part_mask(["torso", "legs"])
    field = pressure_field(verts, body.triangles, mask=mask)
    ids = np.flatnonzero(field.importance > 0.02)
    seat_y = np.quantile(verts[ids, 1], 0.05) - 0.05
    gv, gf = grid_mesh((1.0, 1.0), (10, 10), seat_y)
    gv[:, 2] += verts[ids, 2].mean()
    tris = np.concatenate([gf[:, [0, 1, 2]], gf[:, [0, 2, 3]]])
    problem = RelaxProblem(body, motion.local_rotmats[0], motion.root_positions[0], ids,
                           field.importance[ids], gv, tris)
    return body, verts, field, mask, problem, gv, gf


def test_analytic_jacobian_matches_finite_differences(hovering):
    *_, problem, gv, gf = hovering
    model = _Model(problem)
    rng = np.random.default_rng(4)
    for _ in range(3):
        theta = rng.normal(scale=0.15, size=3 * model.n + 3)
        _, jac = model.jacobian_vertices(theta)
        num = np.zeros_like(jac)
        for k in range(jac.shape[2]):
            step = np.zeros_like(theta)
            step[k] = 1e-6
            num[:, :, k] = (model.vertices(theta + step)[0] - model.vertices(theta - step)[0]) / 2e-6
        assert np.abs(jac - num).max() / np.abs(num).max() < 1e-5
    # and the full residual Jacobian, penetration term included
    theta = rng.normal(scale=0.1, size=3 * model.n + 3)
    v = model.vertices(theta)[0]
    closest = v - [0.0, 0.004, 0.0]  # points just under the skin: the arctan term is steep
    normals = np.tile([0.0, 1.0, 0.0], (len(v), 1))
    facing = np.ones(len(v))
    jac = residual_jacobian(theta, model, closest, normals, facing)
    num = np.zeros_like(jac)
    for k in range(len(theta)):
        step = np.zeros_like(theta)
        step[k] = 1e-7
        num[:, k] = (residuals(theta + step, model, closest, normals, facing)
                     - residuals(theta - step, model, closest, normals, facing)) / 2e-7
    assert np.abs(jac - num).max() / np.abs(num).max() < 1e-5


def test_hovering_body_settles_onto_the_seat(hovering):
    body, verts, field, mask, problem, gv, gf = hovering
    result = relax(problem)
    surface = SurfaceMesh.from_quads(gv, gf)
    before, _ = evaluate_person(surface, _supported(body, verts, field.importance, mask), 0.03,
                                Foam(200e3))
    after, _ = evaluate_person(surface, _supported(body, result.vertices, field.importance, mask),
                               0.03, Foam(200e3))
    assert after["mean_support_distance_m"] <= 0.5 * before["mean_support_distance_m"]
    assert after["max_penetration_m"] <= 0.03
    lo, hi = joint_bounds(body)
    assert np.all(result.theta >= lo - 1e-9) and np.all(result.theta <= hi + 1e-9)


def _supported(body, verts, importance, mask):
    areas, normals = triangle_mesh(body.triangles, len(verts)).measures(verts)
    return SupportedBody(verts, normals, importance, "body", body.triangles, areas, mask,
                         body.mass_kg)


def test_relaxed_pose_as_bvh(hovering, tmp_path):
    body, *_ = hovering
    motion = pose_body(load_pose("bundled:cmu_75_18_high_sit.bvh#frame=39"), body)
    skeleton, order = rig_skeleton(body)
    channels = pose_channels(body, motion.local_rotmats[0], motion.root_positions[0])
    write_bvh(tmp_path / "relaxed.bvh", skeleton, Motion(channels[None], 1 / 30))
    again = read_bvh(tmp_path / "relaxed.bvh")  # the rig's profile knows its unit
    assert identify_profile(again.skeleton.names) == "sitrelax_rig"
    np.testing.assert_allclose(again.world_positions()[0], motion.world.positions[0][order],
                               atol=1e-6)


def _joined_quads(*meshes):
    verts, quads, offset = [], [], 0
    for v, q in meshes:
        verts.append(v)
        quads.append(q + offset)
        offset += len(v)
    return np.concatenate(verts), np.concatenate(quads)


def test_forearms_hovering_over_armrests_come_down_onto_them():
    """Arms held out to the sides, 5 cm above two armrests; the seat is under the buttocks."""
    body = make_body()
    motion = pose_body(load_pose("bundled:cmu_75_18_high_sit.bvh#frame=39"), body)
    names = body.joint_names
    local, root = motion.local_rotmats[0].copy(), motion.root_positions[0]
    for side, degrees in (("Left", 30.0), ("Right", -30.0)):  # abduct clear of the thighs
        j = names.index(side + "Arm")
        parent = motion.world.rotmats[0][body.parents[j]]
        turn = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
        local[j] = parent.T @ turn @ parent @ local[j]
    world = rig_pose(body, local, root)
    verts, _ = skin(body, world, normals=False)
    mask = body.part_mask(["torso", "legs", "arms"])
    field = pressure_field(verts, body.triangles, mask=mask)
    ids = np.flatnonzero(field.importance > 0.02)
    joints = world.positions
    seat = grid_mesh((0.6, 0.7), (8, 8), verts[ids[body.part_mask(["torso"])[ids]], 1].min())
    seat[0][:, [0, 2]] += joints[0, [0, 2]] + [0.0, 0.2]
    dominant = np.asarray(body.weights.argmax(axis=1)).ravel()
    forearms = np.isin(dominant, [names.index("LeftForeArm"), names.index("RightForeArm")])
    rests = []
    for side in ("Left", "Right"):
        elbow, hand = joints[names.index(side + "ForeArm")], joints[names.index(side + "Hand")]
        near = ids[forearms[ids] & (np.linalg.norm(verts[ids] - elbow, axis=1) < 0.3)]
        rest = grid_mesh((0.14, 0.45), (2, 6), verts[near, 1].min() - 0.05)
        rest[0][:, [0, 2]] += (elbow[[0, 2]] + hand[[0, 2]]) / 2
        rests.append(rest)
    sv, sq = _joined_quads(seat, *rests)
    tris = np.concatenate([sq[:, [0, 1, 2]], sq[:, [0, 2, 3]]])
    result = relax(RelaxProblem(body, local, root, ids, field.importance[ids], sv, tris))

    surface = SurfaceMesh.from_quads(sv, sq)
    margin = 0.03

    def evaluate(v, part):
        return evaluate_person(surface, _supported(body, v, field.importance * part, mask),
                               margin, Foam(200e3))[0]

    before, after = evaluate(verts, forearms), evaluate(result.vertices, forearms)
    # the forearms hovered: nothing of them touched before
    assert before["mean_support_distance_m"] >= 0.05 and before["coverage"] == 0.0
    assert after["mean_support_distance_m"] <= 0.5 * before["mean_support_distance_m"]
    assert after["coverage"] > 0.3
    everything = evaluate(result.vertices, np.ones(len(verts)))
    assert everything["max_penetration_m"] <= margin
    lo, hi = joint_bounds(body)
    assert np.all(result.theta >= lo - 1e-9) and np.all(result.theta <= hi + 1e-9)
    # the limits hold on the relaxed rotations too: three turns of at most L each compose to
    # at most 3 L (triangle inequality of the rotation angle)
    turned = np.degrees(Rotation.from_matrix(
        np.swapaxes(local, 1, 2) @ result.local).magnitude())
    allowed = np.array([JOINT_LIMITS.get(n, DEFAULT_LIMIT) for n in names])
    assert np.all(turned <= 3 * allowed + 1e-3)


@pytest.mark.slow
def test_figure_8_heavy_body_fits_the_thin_seat_worse(tmp_path, capsys):
    """The paper's figure 8 through the command line: a seat fitted for a thin body and one for
    an overweight body, each relaxed into by the other body."""
    import json

    from solver.cli import main

    for who in ("thin", "heavy"):
        assert main(["fit", str(EXAMPLES / f"seat_for_{who}.toml"),
                     "--out", str(tmp_path / f"{who}_seat")]) == 0
    reports = {}
    for who, seat in (("heavy", "thin"), ("thin", "heavy")):
        out = tmp_path / f"{who}_on_{seat}"
        capsys.readouterr()
        assert main(["relax", str(EXAMPLES / f"seat_for_{who}.toml"), "--surface",
                     str(tmp_path / f"{seat}_seat"), "--out", str(out), "--json"]) == 0
        printed = json.loads(capsys.readouterr().out)
        reports[who] = json.loads((out / "report.json").read_text())
        assert printed["persons"] == reports[who]["persons"]
        assert (out / "relax.png").stat().st_size > 10_000
        (person,) = reports[who]["persons"]
        for name in person["files"]:
            assert (out / name).stat().st_size > 1000
    heavy, thin = reports["heavy"]["persons"][0], reports["thin"]["persons"][0]
    # coverage after relaxing is within 0.2 % for the two (0.893 and 0.891 on the limit
    # surfaces surface.obj holds, 0.8926 and 0.8935 on the level-3 meshes it held before), too
    # close to rank them; the heavy body stays farther from its support and cuts in deeper
    assert heavy["after"]["mean_support_distance_m"] > thin["after"]["mean_support_distance_m"]
    # the thin body sits in the heavy seat without cutting in; the heavy one cannot
    margin = 0.03
    assert thin["after"]["max_penetration_m"] <= margin
    assert heavy["after"]["max_penetration_m"] > margin


@pytest.mark.slow
def test_relaxed_poses_saved_to_the_library_link_their_origin(tmp_path, capsys):
    import json

    import trimesh

    from posedb import PoseLibrary
    from solver.cli import main
    from solver.scene.scenario import load_scenario
    from solver.scene.placement import place_person

    db = tmp_path / "poses.h5"
    lib = PoseLibrary(db, create=True)
    take = lib.import_bvh(resolve_path("bundled:cmu_75_18_high_sit.bvh"), name="high_sit")
    origin = lib.add_pose(take.id, 39, "perched", tags=["sitting"])
    scenario = tmp_path / "perched.toml"
    scenario.write_text((EXAMPLES / "single_seated.toml").read_text().replace(
        'pose = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"', 'pose = "db:perched"'))
    before = db.read_bytes()
    # saving needs the library named: a clear error, and the library as it was
    assert main(["relax", str(scenario), "--save", "--out", str(tmp_path / "no")]) == 2
    assert "--db" in capsys.readouterr().err

    out = tmp_path / "relaxed"
    assert main(["relax", str(scenario), "--db", str(db), "--save", "--out", str(out),
                 "--json"]) == 0
    assert db.read_bytes() != before
    saved = json.loads(capsys.readouterr().out)["persons"][0]["saved_pose"]
    lib = PoseLibrary(db)
    pose = lib.pose(saved["name"])
    assert pose.name == "perched-relaxed" and saved["id"] == pose.id
    assert set(pose.tags) == {"sitting", "relaxed"}
    stored = lib.take(pose.take)
    assert stored.source == origin.id and stored.kind == "relaxed"

    # the stored pose, put on the same body in the same scene, is the relaxed body moved
    spec = load_scenario(scenario).persons[0]
    again = place_person(type(spec)(**{**spec.__dict__, "pose": f"db:{pose.name}"}), db)
    relaxed = trimesh.load(out / "person_1_relaxed.obj", process=False).vertices
    np.testing.assert_allclose(again.vertices - again.vertices.mean(0),
                               relaxed - relaxed.mean(0), atol=2e-5)

    # a second save of the same origin takes the next free name
    assert main(["relax", str(scenario), "--db", str(db), "--save", "--out", str(out)]) == 0
    assert "perched-relaxed-2" in capsys.readouterr().out
