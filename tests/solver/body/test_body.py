"""Bodies of any shape: size, mass, parts, weights, and linear blend skinning."""

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from scipy.spatial.transform import Rotation

from capture import WorldPose
from posedb.regions import SUPPORT_GROUPS, SUPPORT_USES, SupportNameError
from solver.body.model import BODY_PARTS, BODY_REGIONS, Body, BodyShape, BodyShapeError, make_body
from solver.body.rig import rest_pose, rig_pose
from solver.body.skinning import skin


@pytest.fixture(scope="module")
def body():
    return make_body()


def test_default_body_is_an_adult(body):
    assert 1.55 <= body.height_m <= 1.95
    assert 55 <= body.mass_kg <= 95
    assert body.vertices.shape == (13380, 3) and body.faces.shape == (13378, 4)
    assert len(body.joint_names) == 31 and body.joint_names[0] == "Hips"


def test_volume_against_trimesh(body):
    mesh = trimesh.Trimesh(body.vertices, body.triangles, process=False)
    assert mesh.is_watertight
    assert body.volume_m3 == pytest.approx(mesh.volume, rel=1e-9)


def test_weight_raises_volume_and_mass_monotonically():
    masses = [make_body(BodyShape(weight=w)).mass_kg for w in np.linspace(0, 1, 6)]
    assert all(b > a for a, b in zip(masses, masses[1:])), masses
    assert masses[-1] - masses[0] > 10


def test_gender_differs_visibly():
    female, male = make_body(BodyShape(gender=0)), make_body(BodyShape(gender=1))
    moved = np.linalg.norm(female.vertices - male.vertices, axis=1)
    assert np.median(moved) > 0.02  # most of the skin moves by more than 2 cm
    assert male.height_m - female.height_m > 0.05


def test_frame_conventions(body):
    assert body.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-12)  # on the floor
    hips = body.joints[body.joint_index("Hips")]
    assert abs(hips[0]) < 1e-12 and abs(hips[2]) < 1e-12  # over the origin
    # facing +Z: toes ahead of the ankles, the left side at +X
    for side in ("Left", "Right"):
        ankle = body.joints[body.joint_index(f"{side}Foot")]
        toe = body.joints[body.joint_index(f"{side}ToeBase")]
        assert toe[2] - ankle[2] > 0.08
    assert body.joints[body.joint_index("LeftArm"), 0] > 0.1
    # head above the pelvis above the knees
    y = lambda name: body.joints[body.joint_index(name), 1]  # noqa: E731
    assert y("Head") > y("Neck") > y("Spine1") > y("Hips") > y("LeftLeg") > y("LeftFoot")


def test_joints_follow_the_shape():
    short, tall = make_body(BodyShape(height=0.2)), make_body(BodyShape(height=0.8))
    head = lambda b: b.joints[b.joint_index("Head"), 1]  # noqa: E731
    assert tall.height_m > short.height_m
    assert head(tall) / tall.height_m == pytest.approx(head(short) / short.height_m, rel=0.03)


def test_weights_and_parts(body):
    w = body.weights
    assert sp.issparse(w) and w.shape == (13380, 31)
    assert w.data.min() >= 0
    np.testing.assert_allclose(np.asarray(w.sum(axis=1)).ravel(), 1.0, atol=1e-9)
    counts = np.bincount(body.parts, minlength=len(BODY_PARTS))
    assert (counts > 200).all(), dict(zip(BODY_PARTS, counts))
    feet = body.vertices[body.part_mask(["feet"])]
    head = body.vertices[body.part_mask(["head"])]
    assert feet[:, 1].max() < 0.2 and head[:, 1].min() > 1.2


def test_legs_split_at_the_knee(body):
    """Thighs and calves are the legs, split without overlap: in the rest pose the thighs lie
    above the knees and the calves below them (within the knee's own flesh, 5 cm)."""
    legs, calves = (body.part_mask([p]) for p in ("legs", "calves"))
    thighs = body.part_mask(["thighs", "calves"]) & ~calves
    assert not (thighs & calves).any() and ((thighs | calves) == legs).all()
    assert thighs.sum() > 300 and calves.sum() > 300
    knee = max(body.joints[body.joint_index(n), 1] for n in ("LeftLeg", "RightLeg"))
    assert body.vertices[thighs, 1].min() > knee - 0.05
    assert body.vertices[calves, 1].max() < knee + 0.05
    np.testing.assert_array_equal(body.part_mask(["thighs", "calves", "feet"]),
                                  legs | body.part_mask(["feet"]))
    with pytest.raises(SupportNameError, match=r"Expected body regions \(head, .*got 'knees'"):
        body.part_mask(["knees"])


def test_rest_pose_skins_to_the_rest_mesh_exactly(body):
    verts, normals = skin(body, rest_pose(body))
    np.testing.assert_allclose(verts, body.vertices, atol=1e-12)
    np.testing.assert_allclose(normals, body.normals, atol=1e-12)
    # and the same through local rotations
    n = len(body.joint_names)
    pose = rig_pose(body, np.broadcast_to(np.eye(3), (n, 3, 3)), body.joints[0])
    np.testing.assert_allclose(skin(body, pose)[0], body.vertices, atol=1e-12)


def test_skinning_refuses_what_is_not_one_pose_by_name(body):
    """An array, or a whole motion's frames, is refused with what was expected."""
    with pytest.raises(TypeError, match="Expected a WorldPose.*got ndarray"):
        skin(body, body.joints)
    n = len(body.joint_names)
    frames = WorldPose(np.zeros((2, n, 3)), np.broadcast_to(np.eye(3), (2, n, 3, 3)))
    with pytest.raises(ValueError, match="Expected one pose of"):
        skin(body, frames)


def test_rigid_motion_moves_every_vertex_rigidly(body):
    n = len(body.joint_names)
    rot = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    local = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    local[0] = rot
    pose = rig_pose(body, local, body.joints[0] + [1.0, 0.5, 0.0])
    verts, normals = skin(body, pose)
    expected = (body.vertices - body.joints[0]) @ rot.T + body.joints[0] + [1.0, 0.5, 0.0]
    np.testing.assert_allclose(verts, expected, atol=1e-12)
    np.testing.assert_allclose(normals, body.normals @ rot.T, atol=1e-12)


def test_blend_of_two_bones_by_hand():
    """Two joints, one vertex weighted half to each: the blend of the two bone transforms."""
    base = make_body()
    tiny = Body(base.shape, np.array([[0.0, 2.0, 0.0]]), np.zeros((0, 4), dtype=int),
                ("a", "b"), np.array([-1, 0]), np.array([[0.0, 0, 0], [0.0, 1, 0]]),
                np.array([[0.0, 1, 0], [0.0, 2, 0]]),
                sp.csr_matrix(np.array([[0.5, 0.5]])), np.zeros(1, dtype=np.int8))
    turn = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    pose = WorldPose(np.array([[0.0, 0, 0], [0.0, 1, 0]]), np.stack([np.eye(3), turn]))
    verts, _ = skin(tiny, pose, normals=False)
    # joint a leaves the vertex at (0, 2, 0); joint b turns it about (0, 1, 0) to (-1, 1, 0)
    np.testing.assert_allclose(verts, [[-0.5, 1.5, 0.0]], atol=1e-12)


@pytest.mark.parametrize("kwargs, message", [
    (dict(weight=1.2), r"weight in \[0, 1\], got 1.2 \(a shape slider, not a measure"),
    (dict(gender="heavy"), "Expected a number for body gender"),
    (dict(african=0, asian=0, caucasian=0), "race weights"),
])
def test_bad_shapes_are_named(kwargs, message):
    with pytest.raises(BodyShapeError, match=message):
        BodyShape(**kwargs)
    with pytest.raises(BodyShapeError, match="Expected body parameters"):
        BodyShape.from_mapping({"wieght": 0.5})


def test_package_data_is_compact():
    from importlib import resources

    data = resources.files("solver") / "data" / "makehuman_body.npz.xz"
    assert len(data.read_bytes()) < 10e6


def test_regions_partition_the_body_and_sit_where_they_should(body):
    """Every vertex has one region, inside its part; the thighs and calves are the legs' split;
    each region lies around its bones (the pelvis about the Hips joint, and so on)."""
    from solver.body.model import BODY_REGIONS, REGION_PART

    regions = body.regions
    assert regions.shape == (len(body.vertices),)
    assert regions.min() >= 0 and regions.max() < len(BODY_REGIONS)
    part_of = np.array([BODY_PARTS.index(REGION_PART[r]) for r in BODY_REGIONS])
    np.testing.assert_array_equal(part_of[regions], body.parts)
    counts = np.bincount(regions, minlength=len(BODY_REGIONS))
    assert (counts > 50).all(), dict(zip(BODY_REGIONS, counts))
    mask = {r: regions == k for k, r in enumerate(BODY_REGIONS)}
    np.testing.assert_array_equal(mask["thighs"] & ~body.popliteal, body.part_mask(["thighs"]))
    np.testing.assert_array_equal(mask["calves"], body.part_mask(["calves"]))
    centre = {r: body.vertices[m].mean(axis=0) for r, m in mask.items()}
    joint = {n: body.joints[body.joint_index(n)] for n in ("Hips", "LowerBack", "Spine1", "Neck")}
    assert np.linalg.norm(centre["pelvis"] - joint["Hips"]) < 0.06
    assert np.linalg.norm(centre["lower_back"] - joint["LowerBack"]) < 0.1
    heights = [centre[r][1] for r in ("feet", "calves", "thighs", "pelvis", "lower_back",
                                      "upper_back", "head")]
    assert heights == sorted(heights)
    assert body.vertices[mask["head"], 1].min() > joint["Neck"][1] - 0.05
    assert body.vertices[mask["feet"], 1].max() < 0.15
    # the buttocks (behind the hips, at their height) are pelvis, not thighs
    behind = (body.vertices[:, 2] < joint["Hips"][2] - 0.08) & \
        (np.abs(body.vertices[:, 1] - joint["Hips"][1] + 0.03) < 0.04)
    assert mask["pelvis"][behind].mean() > 0.8


def test_the_arms_split_at_the_elbow(body):
    """Along each arm (0 at the shoulder joint, 1 at the elbow, 2 at the wrist, in the rest
    pose) the upper arms lie before the elbow and the forearms after it, within the elbow's own
    flesh (a tenth of a segment)."""
    from solver.body.model import BODY_REGIONS

    joint = lambda name: body.joints[body.joint_index(name)]  # noqa: E731
    for side in ("Left", "Right"):
        s, e, w = joint(f"{side}Arm"), joint(f"{side}ForeArm"), joint(f"{side}Hand")
        this_side = np.sign(body.vertices[:, 0]) == np.sign(s[0])

        def along(p):
            upper = ((p - s) @ (e - s)) / ((e - s) @ (e - s))
            lower = ((p - e) @ (w - e)) / ((w - e) @ (w - e))
            return np.where(upper < 1.0, upper, 1.0 + np.maximum(lower, 0.0))

        for region, low, high in (("upper_arms", -0.3, 1.1), ("forearms", 0.9, 2.1)):
            mask = this_side & (body.regions == BODY_REGIONS.index(region))
            t = along(body.vertices[mask])
            assert mask.sum() > 200 and low < t.min() and t.max() < high, (side, region)


@pytest.mark.parametrize("shape", [BodyShape(), BodyShape(gender=1.0, weight=0.9),
                                   BodyShape(gender=0.0, weight=0.1, height=0.2)])
def test_the_coarse_parts_are_the_unions_of_their_regions(shape):
    """torso, arms and legs name exactly the vertices of that part (the bones' part), as they
    did before the regions refined them; a use names the union of its regions."""
    body = make_body(shape)
    for part, regions in SUPPORT_GROUPS.items():
        np.testing.assert_array_equal(body.part_mask([part]),
                                      body.parts == BODY_PARTS.index(part))
        union = np.zeros(len(body.vertices), dtype=bool)
        for r in regions:
            one = body.regions == BODY_REGIONS.index(r)
            assert one.any() and not (one & union).any(), r
            assert not (body.part_mask([r]) & ~one).any(), r  # a region names only its own
            union |= one
        np.testing.assert_array_equal(union, body.part_mask(part))
    for use, regions in SUPPORT_USES.items():
        if use != "bed":
            np.testing.assert_array_equal(body.part_mask(use), body.part_mask(list(regions)))
    # a bed keeps the trunk's front (a body may lie on it face down) and leaves the forearms
    # and hands out
    free = np.isin(body.regions, [BODY_REGIONS.index(r) for r in ("forearms", "hands")])
    np.testing.assert_array_equal(body.part_mask("bed"), ~free)


@pytest.mark.parametrize("region", ["upper_back", "lower_back", "pelvis"])
def test_a_trunk_region_named_for_support_is_its_back_not_its_front(region):
    """A backrest carries the back, a seat the buttocks: named as a region (or by a chair's
    use), the trunk's regions leave out the skin facing forward in the rest pose (the chest and
    belly, the groin); the whole torso keeps it."""
    body = make_body()
    whole = body.regions == BODY_REGIONS.index(region)
    named = body.part_mask([region])
    forward = body.normals[:, 2] > 0.5
    backward = body.normals[:, 2] < -0.5
    assert (whole & backward).any() and (whole & forward).any()
    assert named[whole & backward].all() and not named[whole & forward].any()
    assert body.part_mask(["torso"])[whole].all()
    assert not body.part_mask("chair")[whole & forward].any()


def test_thighs_without_the_calves_leave_the_back_of_the_knee_free(body):
    """Asked for alone (a seat), the thighs stop 11 cm before each knee along the thigh bone,
    the same on both legs; with the calves (a bed, a floor cushion) the whole leg counts."""
    from solver.body.model import POPLITEAL_CLEARANCE

    thighs = body.regions == BODY_REGIONS.index("thighs")
    free = body.popliteal
    assert free.any() and not (free & ~thighs).any()
    seat = body.part_mask("seat")
    assert not (seat & free).any() and (seat | free)[thighs].all()
    assert body.part_mask(["thighs", "calves"])[free].all()
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        hip = body.joints[body.joint_index(f"{side}UpLeg")]
        knee = body.joints[body.joint_index(f"{side}Leg")]
        axis = (knee - hip) / np.linalg.norm(knee - hip)
        mine = thighs & (np.sign(body.vertices[:, 0]) == np.sign(hip[0]))
        past = (body.vertices - knee) @ axis  # metres past the knee along the bone
        assert past[mine & free].min() > -POPLITEAL_CLEARANCE - 1e-9
        assert past[mine & ~free].max() <= -POPLITEAL_CLEARANCE + 1e-9
        assert 60 < (mine & free).sum() < 0.4 * mine.sum()


def test_a_deep_knee_bend_leaves_the_thighs_skin_beside_the_calves_free(body):
    """Knees bent 130 degrees (the calves folded up under the thighs): a seat's thighs leave
    free, besides the back of the knee, every thigh vertex within KNEE_CREASE of a calf vertex
    in that pose (found here by brute force), and no other; a support of the calves too keeps
    them all."""
    from solver.body.model import KNEE_CREASE

    n = len(body.joint_names)
    local = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for side in ("Left", "Right"):
        local[body.joint_index(f"{side}Leg")] = Rotation.from_euler("x", 130, degrees=True
                                                                    ).as_matrix()
    posed, _ = skin(body, rig_pose(body, local, body.joints[0]))
    thighs = np.flatnonzero(body.regions == BODY_REGIONS.index("thighs"))
    calves = posed[body.regions == BODY_REGIONS.index("calves")]
    nearest = np.array([np.min(np.linalg.norm(calves - p, axis=1)) for p in posed[thighs]])
    seat = body.part_mask("seat", posed)
    rest = body.part_mask("seat")
    crease = np.zeros(len(posed), dtype=bool)
    crease[thighs[nearest <= KNEE_CREASE]] = True
    np.testing.assert_array_equal(seat, rest & ~crease)
    assert (rest & crease).sum() > 20  # the premise: the bend brings thigh beside calf (40)
    np.testing.assert_array_equal(body.part_mask(["thighs", "calves"], posed),
                                  body.part_mask(["thighs", "calves"]))
