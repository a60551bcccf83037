"""Pose relaxation: analytic Jacobians, settling onto a surface, and BVH of relaxed poses."""

import dataclasses
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
    STEP_SCALES,
    JOINT_LIMITS,
    RelaxProblem,
    _Model,
    joint_bounds,
    penetration_step,
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
    # and the full residual Jacobian, penetration term included, with guarded vertices
    unsupported = np.setdiff1d(np.arange(len(problem.body.vertices)), problem.vertex_ids)
    model = _Model(dataclasses.replace(problem, guard_ids=unsupported[::40]))
    assert model.m > model.supported == len(problem.vertex_ids)
    theta = rng.normal(scale=0.1, size=3 * model.n + 3)
    v = model.vertices(theta)[0]
    allowed = rng.uniform(0.0, 0.03, len(v))
    # surface points above the skin: each vertex 4 mm deeper than it may sink, on the steep
    # part of the step
    closest = v + np.outer(allowed + 0.004, [0.0, 1.0, 0.0])
    normals = np.tile([0.0, 1.0, 0.0], (len(v), 1))
    weights = rng.uniform(0.1, 1.0, len(v))
    args = (model, closest, normals, weights, allowed)
    jac = residual_jacobian(theta, *args)
    num = np.zeros_like(jac)
    for k in range(len(theta)):
        step = np.zeros_like(theta)
        step[k] = 1e-7
        num[:, k] = (residuals(theta + step, *args) - residuals(theta - step, *args)) / 2e-7
    assert np.abs(jac - num).max() / np.abs(num).max() < 1e-5
    pen = slice(4 * model.supported, 4 * model.supported + model.m)  # the penetration rows
    assert np.abs(jac[pen]).max() > 0.1 * np.abs(jac).max()


def test_penetration_step_pushes_only_skin_sunk_past_the_margin():
    margin = 0.03
    signed = np.array([0.02, 0.0, -0.01, -0.0299, -0.0301, -0.031, -0.04, -0.2])
    step, slope = penetration_step(signed, margin)
    # in front of the surface and sunk by less than the margin: no push at all
    assert np.all(step[:4] == 0.0) and np.all(slope[:4] == 0.0)
    # past it the step rises, steeply at first, towards 1, and pushes out (s up lowers it)
    assert np.all(np.diff(step[3:]) > 0) and step[-1] > 0.99
    assert np.all(slope[4:] < 0) and slope[4] < 4 * slope[6]
    # the paper's step (a = 1000, b = 10) pushes skin in front of the surface
    paper = 0.5 - np.arctan(1000 * signed[:4] + 10) / np.pi
    assert np.all(paper > 0.01)


def test_hovering_body_settles_onto_the_seat(hovering):
    body, verts, field, mask, problem, gv, gf = hovering
    # 5 cm above the seat: more rounds than the default three (rounds after the first get half
    # the evaluations, to keep a judged relaxation under 0.2 s)
    result = relax(problem, rounds=6)
    surface = SurfaceMesh.from_quads(gv, gf)
    before, _ = evaluate_person(surface, _supported(body, verts, field.importance, mask), 0.03,
                                Foam(200e3))
    after, _ = evaluate_person(surface, _supported(body, result.vertices, field.importance, mask),
                               0.03, Foam(200e3))
    # about half (0.5005 of it on one machine, under 0.5 on another: the pose's optimiser
    # follows the BLAS's rounding); a body left hovering keeps all of it
    assert after["mean_support_distance_m"] <= 0.6 * before["mean_support_distance_m"]
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
    margin = 0.03
    # the armrests and the seat allow the softness the evaluation allows: only skin sunk past
    # it is pushed out (the ungated least squares, without the evaluation's veto)
    result = relax(RelaxProblem(body, local, root, ids, field.importance[ids], sv, tris,
                                margin=margin))

    surface = SurfaceMesh.from_quads(sv, sq)

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
    for person in (heavy, thin):  # relaxing never makes the evaluation's figures worse
        before, after = person["before"], person["after"]
        assert after["mean_support_distance_m"] <= before["mean_support_distance_m"]
        assert after["coverage"] >= before["coverage"]
        assert after["contact_coverage"] >= before["contact_coverage"]
        assert after["max_penetration_m"] <= before["max_penetration_m"]
    # the overweight body, hovering over the thin body's seat, settles into it: its coverage
    # improves, and the report says which round was accepted and what it gained
    assert heavy["after"]["coverage"] > heavy["before"]["coverage"] + 0.1
    assert heavy["relaxation"]["accepted"]
    assert "accepted: better support distance, coverage" in heavy["relaxation"]["summary"]
    # the thin body sits in the heavy seat without cutting in; the heavy one sinks deeper into
    # the thin seat than the thin one into the heavy seat (the paper also had the heavy body
    # farther from its support after relaxing; here the thin body's relaxation may be refused,
    # its captured pose kept, so the distances are not ranked)
    margin = 0.03
    assert thin["after"]["max_penetration_m"] <= margin
    assert heavy["after"]["max_penetration_m"] > thin["after"]["max_penetration_m"]


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
    assert stored.name == "perched-relaxed-take"  # (takes and poses share one namespace)

    # the stored pose, put on the same body in the same scene, is the relaxed body moved
    spec = load_scenario(scenario).persons[0]
    again = place_person(type(spec)(**{**spec.__dict__, "pose": f"db:{pose.name}"}), db)
    relaxed = trimesh.load(out / "person_1_relaxed.obj", process=False).vertices
    np.testing.assert_allclose(again.vertices - again.vertices.mean(0),
                               relaxed - relaxed.mean(0), atol=2e-5)

    # a second save of the same origin takes the next free name
    assert main(["relax", str(scenario), "--db", str(db), "--save", "--out", str(out)]) == 0
    assert "perched-relaxed-2" in capsys.readouterr().out


class _CentroidGate:
    """A stand-in for the evaluation: one figure, how far the skin's centroid moved from where
    it started (m), worse when beyond `limit`; counts what it was asked."""

    def __init__(self, start: np.ndarray, limit: float):
        self.start, self.limit, self.asked = start.mean(axis=0), limit, 0

    def figures(self, vertices, reference=None):
        self.asked += 1
        return {"moved_m": float(np.linalg.norm(vertices.mean(axis=0) - self.start))}

    def worse(self, before, after):
        return ["moved_m"] if after["moved_m"] > self.limit else []


def test_a_round_worse_by_the_gate_is_retried_shorter_and_otherwise_refused(hovering):
    body, verts, *_, problem, gv, gf = hovering
    free = relax(problem, rounds=1)
    moved = float(np.linalg.norm(free.vertices.mean(axis=0) - verts.mean(axis=0)))
    assert moved > 0.01  # the hovering body comes down

    # a gate that allows three quarters of the move: the round's solution is refused, half of
    # its step accepted
    gate = _CentroidGate(verts, 0.75 * moved)
    half = relax(problem, rounds=1, gate=gate)
    first, second = half.steps
    assert (first.round, first.scale, first.accepted, first.worse) == (1, 1.0, False,
                                                                        ("moved_m",))
    assert (second.scale, second.accepted, second.worse) == (0.5, True, ())
    np.testing.assert_allclose(half.theta, 0.5 * free.theta, atol=1e-12)
    assert half.accepted and half.figures == second.figures
    assert half.figures["moved_m"] <= gate.limit
    assert gate.asked == 3  # the captured pose, then the two steps

    # a gate that allows no move at all: the captured pose is kept, and no later round is run
    still = _CentroidGate(verts, 0.0)
    kept = relax(problem, rounds=3, gate=still, figures_before={"moved_m": 0.0})
    assert not kept.accepted and kept.rounds == 1
    assert [s.scale for s in kept.steps] == list(STEP_SCALES)
    assert not np.any(kept.theta)
    np.testing.assert_allclose(kept.vertices, verts, atol=1e-7)
    assert kept.figures == {"moved_m": 0.0} and still.asked == len(STEP_SCALES)


def test_a_problem_of_the_wrong_shape_is_refused_by_name():
    """Rotations, a root, indices or importances of the wrong shape (or not numbers) are
    refused when the problem is made, naming what is wrong, not deep in a solver."""
    from solver.body.model import make_body
    from solver.body.relax import RelaxError, RelaxProblem

    body = make_body()
    joints = len(body.joint_names)
    good = dict(local0=np.tile(np.eye(3), (joints, 1, 1)), root0=np.zeros(3),
                vertex_ids=np.arange(3), importance=np.ones(3),
                surface_vertices=np.zeros((3, 3)), surface_triangles=np.array([[0, 1, 2]]))
    RelaxProblem(body, **good)  # (the good one is made)
    for name, bad, said in (("local0", np.eye(3), "local0"),
                            ("root0", np.array([0.0, np.nan, 0.0]), "root0"),
                            ("vertex_ids", np.array([0, 1, len(body.vertices)]), "vertex_ids"),
                            ("vertex_ids", np.array([0.0, 1.0, 2.0]), "vertex_ids"),
                            ("importance", np.ones(2), "importance"),
                            ("surface_vertices", np.zeros(9), "surface_vertices")):
        with pytest.raises(RelaxError, match=said):
            RelaxProblem(body, **{**good, name: bad})
