"""`sitrelax validate pressure`: the pressure model against the physical reference.

Two poses, as in the paper's figure 4: a seated pose (frame 39 of `cmu_75_18_high_sit.bvh`, in
the middle of the held seated phase) and a lying T-pose, both on the default body. For each, the
model's |r_n| and the reference's reactions are normalised by their largest normal force and
compared over the mould's contact vertices (the vertices of the faces pointing down or sideways).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from solver.body.model import BodyShape, make_body
from solver.body.poses import load_pose, pose_body
from solver.body.rig import t_pose
from solver.contact.pressure import pressure_field
from solver.contact.reference import rigid_contact
from solver.body.skinning import skin

SEATED = "bundled:cmu_75_18_high_sit.bvh#frame=39"


def validation_poses(shape: BodyShape = BodyShape()) -> dict[str, np.ndarray]:
    """Posed vertices (V, 3) of the two validation poses."""
    body = make_body(shape)
    seated = pose_body(load_pose(SEATED), body)
    lying = t_pose(body, Rotation.from_euler("x", -90, degrees=True).as_matrix())
    return {"seated": skin(body, seated.frame(0), normals=False)[0],
            "lying T-pose": skin(body, lying, normals=False)[0]}


def compare(vertices: np.ndarray, triangles: np.ndarray) -> dict:
    """Model and reference on one posed mesh: RMSEs, times and the normalised fields."""
    start = time.perf_counter()
    field = pressure_field(vertices, triangles)
    model_s = time.perf_counter() - start
    start = time.perf_counter()
    ref = rigid_contact(vertices, triangles)
    reference_s = time.perf_counter() - start
    k = ref.vertices
    ours = field.reaction[k] / field.reaction[k].max()
    scale = ref.normal.max()
    reaction, normal = ref.reaction / scale, ref.normal / scale
    return {
        "rmse_reaction": float(np.sqrt(np.mean((ours - reaction) ** 2))),
        "rmse_normal": float(np.sqrt(np.mean((ours - normal) ** 2))),
        "model_s": model_s, "reference_s": reference_s,
        "contact_vertices": int(len(k)), "equilibrium_residual_n": ref.residual,
        "tangential_share": float(np.linalg.norm(ref.tangential_force, axis=1).sum()
                                  / ref.normal.sum()),
        "_fields": (k, ours, reaction, normal),
    }


def validate_pressure(out_dir: str | Path | None = None) -> list[dict]:
    """Runs the comparison on both poses; writes pictures into `out_dir` when given."""
    body = make_body()
    rows = []
    for name, verts in validation_poses().items():
        row = {"pose": name, **compare(verts, body.triangles)}
        k, ours, reaction, _ = row.pop("_fields")
        if out_dir is not None:
            row["picture"] = str(_picture(Path(out_dir), name, body, k, ours, reaction))
        rows.append(row)
    return rows


def _picture(out_dir: Path, name: str, body, k, ours, reaction) -> Path:
    from solver.io.render import MeshView, Panel, field_colors, render_panels

    out_dir.mkdir(parents=True, exist_ok=True)
    display = skin(body, t_pose(body), normals=False)[0]  # shown on a standing T-pose
    panels = []
    diff = np.abs(reaction - ours)
    for label, values in (("reference: |normal + tangential|", reaction),
                          ("model: |r_n| = A max(0, n.g)", ours),
                          (f"|difference| (max {diff.max():.2f})", diff)):
        field = np.zeros(len(display))
        field[k] = values
        colors = field_colors(field)
        for view in ("back", "below"):
            panels.append(Panel([MeshView(display, body.faces, colors)], view,
                                f"{label}, {view}"))
    order = [0, 2, 4, 1, 3, 5]  # rows: back, below; columns: reference, model, difference
    path = out_dir / f"pressure_{name.replace(' ', '_').replace('-', '_').lower()}.png"
    return render_panels(path, [panels[i] for i in order], columns=3,
                         title=f"Pressure on the body, {name}: normalised by the largest normal "
                               "force", colorbar=("normalised force", 0.0, 1.0))
