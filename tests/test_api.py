"""The public API of each package, snapshotted so a change to it is deliberate."""

import subprocess
import sys

import capture


def test_capture_public_api():
    assert sorted(capture.__all__) == sorted([
        "Bvh", "BvhParseError", "CHANNEL_NAMES", "LayoutMismatchError", "Motion",
        "NeuronFrame", "NeuronStreamError", "PROFILES", "Profile", "RawCaptureError",
        "RawCaptureWriter", "Replay", "ReplayError", "ReplayThread", "Skeleton", "SkeletonError",
        "Source", "StreamDecoder", "StreamLayout", "StreamSourceError", "UNITS", "UnitError",
        "UnitUnknownError", "WorldPose", "bundled_recordings", "decode_all", "encode_frame",
        "format_bvh", "forward_kinematics", "identify_profile", "joint_levels", "open_source",
        "parse_bvh", "read_bvh", "read_raw_capture", "resolve_path", "resolve_unit",
        "skeleton_fk", "write_bvh",
    ])
    for name in capture.__all__:
        assert hasattr(capture, name)


def test_posedb_public_api():
    import posedb

    assert sorted(posedb.__all__) == sorted([
        "DuplicateNameError", "Editor", "HeldPosture", "LibraryError", "LockedError",
        "NotFoundError", "PoseInfo", "PoseLibrary", "PosePlacement", "SCHEMA_VERSION",
        "SchemaError", "TagError", "TakeData", "TakeInfo", "TakeRecorder", "compile_expression",
        "held_postures", "record",
        "recordings", "recover",
        "BODY_REGIONS", "DEFAULT_SUPPORT", "SUPPORT_USES", "SupportNameError", "support_regions",
    ])
    for name in ("DuplicateNameError", "LockedError", "NotFoundError", "SchemaError",
                 "TagError"):
        assert issubclass(getattr(posedb, name), posedb.LibraryError)
    assert issubclass(posedb.LibraryError, ValueError)


def test_solver_public_api():
    import solver

    assert sorted(solver.__all__) == sorted([
        "BODY_PARTS", "BODY_REGIONS", "BSplineSurface", "Body", "BodyShape", "BodyShapeError", "CapturedPose",
        "ExportError", "bspline_of_grid", "grid_layout", "limit_matrix", "limit_positions",
        "write_3dm",
        "FitError", "FitParams", "FitResult", "MeshError", "MeshView", "PlacedPerson",
        "PoseSourceError", "PressureField", "RelaxError", "RelaxProblem", "RelaxResult",
        "RetargetError", "RigMotion", "Scenario", "ScenarioError", "Subdivision",
        "SupportedBody", "SurfaceMesh", "SurfaceMeshError", "evaluate_person", "fit_scene",
        "fit_surface",
        "grid_mesh", "joint_map_for", "load_pose", "load_scenario", "make_body",
        "parse_scenario", "place", "place_person", "pose_body", "pressure_field", "relax",
        "relax_problem", "render_png", "rest_pose", "retarget", "retarget_pose", "rig_pose",
        "run_fit", "run_relax", "skin", "subdivision", "write_mesh",
        "Foam", "Settled", "Support", "settle", "SupportContact", "mat_figures", "pressure_grid",
    ])
    for name in ("BodyShapeError", "ExportError", "FitError", "MeshError", "PoseSourceError",
                 "RelaxError", "RetargetError", "ScenarioError",
                 "SurfaceMeshError"):
        assert issubclass(getattr(solver, name), ValueError)


def test_errors_are_value_errors():
    for name in ("BvhParseError", "SkeletonError", "UnitError", "UnitUnknownError",
                 "NeuronStreamError", "LayoutMismatchError", "RawCaptureError", "ReplayError",
                 "StreamSourceError"):
        assert issubclass(getattr(capture, name), ValueError)


def test_packages_import_without_optional_heavy_modules():
    # the capture layer must not pull in the solver's dependencies
    code = ("import sys, capture; "
            "bad = [m for m in ('igl', 'trimesh', 'osqp', 'h5py', 'posedb', 'solver') "
            "if m in sys.modules]; assert not bad, bad; "
            "import posedb; bad = [m for m in ('igl', 'trimesh', 'osqp', 'solver') "
            "if m in sys.modules]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)
