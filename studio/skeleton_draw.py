"""Skeletons as the studio's Record and Library views draw them: bone segments for the 3D scene,
small thumbnails rendered on the server (a numpy raster, no display needed), and the average body
posed by a skeleton (the solver's retargeting and skinning, as `sitrelax fit` poses people).

Positions are world joint positions in metres, Y up, a body in rest pose facing +Z (the
project's frame). A thumbnail looks at the body from the front and a little to its right, as
the studio's camera does.
"""

from __future__ import annotations

import base64
import io

import numpy as np
from scipy.spatial.transform import Rotation

from capture import Skeleton, WorldPose
from capture.skeleton import forward_kinematics
from solver.io.render import SKIN

THUMBNAIL_SIZE = 112  # pixels, square
BONE_COLOR = (40, 110, 220)
BODY_COLOR = tuple(int(round(255 * c)) for c in SKIN)  # the pictures' skin
JOINT_COLOR = (30, 30, 38)
_VIEW = Rotation.from_euler("y", -30.0, degrees=True)  # the thumbnail's turn about Y


def pose_world(skeleton: Skeleton, local_rotations: np.ndarray,
               root_position: np.ndarray) -> WorldPose:
    """World joint frames (J,) of a library pose: its own rotations (J, 4) xyzw, the skeleton's
    offsets, and the root at `root_position` (3,) m."""
    rot = np.asarray(local_rotations, dtype=np.float64)
    if rot.shape != (skeleton.num_joints, 4):
        raise ValueError(f"Expected rotations ({skeleton.num_joints}, 4), got {rot.shape}")
    translations = skeleton.offsets_m.copy()
    translations[0] = np.asarray(root_position, dtype=np.float64)
    return forward_kinematics(skeleton.parents, Rotation.from_quat(rot).as_matrix(),
                              translations, skeleton.levels)


def posed_body(skeleton: Skeleton, world: WorldPose) -> tuple[np.ndarray, np.ndarray]:
    """The average body in a skeleton's posture, its pelvis (the rig's root) on the skeleton's
    root joint: vertices (V, 3) float32 m and triangles (F, 3). About 30 ms.

    world : the skeleton's world frames of one posture, (J,) or (1, J).
    """
    from solver.body.model import make_body
    from solver.body.poses import CapturedPose, pose_body
    from solver.body.skinning import skin

    if world.positions.ndim == 2:
        world = WorldPose(world.positions[None], world.rotmats[None])
    body = make_body()
    motion = pose_body(CapturedPose(skeleton, world, "the studio's skeleton"), body,
                       lowest=None)
    pose = motion.frame(0)
    vertices, _ = skin(body, pose, normals=False)
    vertices += world.positions[0, 0] - pose.positions[0]
    return vertices.astype(np.float32), body.triangles


def bone_segments(positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(B, 2, 3) float32 segments, one per joint with a parent: parent to joint.

    positions : (J, 3) m; parents : (J,) int, -1 for roots.
    """
    parents = np.asarray(parents)
    child = np.flatnonzero(parents >= 0)
    p = np.asarray(positions, dtype=np.float32)
    return np.stack([p[parents[child]], p[child]], axis=1)


def skeleton_thumbnail(positions: np.ndarray, parents: np.ndarray,
                       size: int = THUMBNAIL_SIZE) -> np.ndarray:
    """A (size, size, 3) uint8 picture of a skeleton on white: bones as 2-pixel blue lines,
    joints dark, the body scaled to fill the square with a margin (orthographic view).

    positions : (J, 3) m, finite; parents : (J,) int, -1 for roots.
    """
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
        raise ValueError(f"Expected finite joint positions (J, 3), got shape {p.shape}")
    xy = _VIEW.apply(p)[:, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = max(float((hi - lo).max()), 1e-6)
    margin = 0.08 * size
    scale = (size - 2 * margin) / span
    centre = (lo + hi) / 2
    px = (xy - centre) * scale + size / 2
    px[:, 1] = size - px[:, 1]  # image rows grow downwards, Y up
    img = np.full((size, size, 3), 255, dtype=np.uint8)
    seg = bone_segments(np.c_[px, np.zeros(len(px))], parents)[..., :2]
    for a, b in seg:
        steps = int(np.ceil(np.abs(b - a).max())) + 1
        line = a + np.linspace(0.0, 1.0, steps)[:, None] * (b - a)
        _stamp(img, line, 1, BONE_COLOR)
    _stamp(img, px, 2, JOINT_COLOR)
    return img


def _stamp(img: np.ndarray, points: np.ndarray, radius: int, color) -> None:
    """Sets a (2 radius)-pixel square around each point (x, y) to `color`, within the image."""
    size = img.shape[0]
    base = np.floor(points).astype(np.int64)
    for dx in range(-radius + 1, radius + 1):
        for dy in range(-radius + 1, radius + 1):
            x, y = base[:, 0] + dx, base[:, 1] + dy
            ok = (x >= 0) & (x < size) & (y >= 0) & (y < size)
            img[y[ok], x[ok]] = color


def png_base64(img: np.ndarray) -> str:
    """A picture (H, W, 3) uint8 as base64 PNG text (for an inline `data:` URL)."""
    from matplotlib.image import imsave

    buffer = io.BytesIO()
    imsave(buffer, img, format="png")
    return base64.b64encode(buffer.getvalue()).decode("ascii")


class SceneFigure:
    """A skeleton (and optionally a body) a view draws in its part of the scene (`prefix`),
    made on first use and then only moved: each update sends the new points, not new nodes."""

    def __init__(self, scene, prefix: str):
        self.scene, self.prefix = scene, prefix
        self.bones = self.joints = self.body = None

    def show(self, positions: np.ndarray, parents: np.ndarray) -> None:
        """Draws the skeleton at `positions` (J, 3) m."""
        segments = bone_segments(positions, parents)
        points = np.asarray(positions, dtype=np.float32)
        if self.bones is None:
            self.bones = self.scene.add_line_segments(f"{self.prefix}/bones", segments,
                                                      BONE_COLOR, thickness=0.012)
            self.joints = self.scene.add_point_cloud(f"{self.prefix}/joints", points,
                                                     JOINT_COLOR, point_size=0.02)
        else:
            self.bones.points = segments
            self.joints.points = points
            self.bones.visible = self.joints.visible = True

    def hide(self) -> None:
        """Hides the skeleton and the body (the next `show` draws them again)."""
        for handle in (self.bones, self.joints):
            if handle is not None:
                handle.visible = False
        self.show_body(None)

    def show_body(self, vertices: np.ndarray | None, triangles: np.ndarray | None = None
                  ) -> None:
        """Draws the body's skin (V, 3) m over triangles (F, 3); None hides it."""
        if vertices is None:
            if self.body is not None:
                self.body.visible = False
            return
        if self.body is None:
            self.body = self.scene.add_mesh_simple(f"{self.prefix}/body", vertices, triangles,
                                                   color=BODY_COLOR, opacity=0.55)
        else:
            self.body.vertices = vertices
            self.body.visible = True
