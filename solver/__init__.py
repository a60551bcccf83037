"""Body model, retargeting, skinning, pressure, Catmull-Clark fitting, relaxation, evaluation,
export and batch runs. Depends on `capture` and `posedb`.

Conventions as everywhere: metres, Y up, gravity along -Y, bodies face +Z.
"""

from .body import BODY_PARTS, Body, BodyShape, BodyShapeError, make_body
from .export import ExportError, write_mesh
from .poses import CapturedPose, PoseSourceError, load_pose, pose_body
from .relax import RelaxError, RelaxProblem, RelaxResult, problem_for, relax
from .render import MeshView, render_png
from .retarget import RetargetError, RigMotion, joint_map_for, place, retarget, retarget_pose
from .skinning import rest_pose, rig_pose, skin

__all__ = [
    "BODY_PARTS",
    "Body",
    "BodyShape",
    "BodyShapeError",
    "CapturedPose",
    "ExportError",
    "MeshView",
    "PoseSourceError",
    "RelaxError",
    "RelaxProblem",
    "RelaxResult",
    "RetargetError",
    "RigMotion",
    "joint_map_for",
    "load_pose",
    "make_body",
    "place",
    "pose_body",
    "problem_for",
    "relax",
    "render_png",
    "rest_pose",
    "retarget",
    "retarget_pose",
    "rig_pose",
    "skin",
    "write_mesh",
]
