"""sitrelax's solver: bodies, their support, surfaces fitted to them, and scenes.

Conventions as everywhere: metres, seconds, Y up, gravity along -Y, a body in rest pose faces +Z.

The solver is in layers, each a subpackage; a layer imports only those before it:

* `solver.mesh`: triangle and quad meshes (normals, areas, closest points);
* `solver.body`: the body model, its rig, skinning, retargeting, pose sources, relaxation;
* `solver.contact`: the pressure model (where a body needs support), the evaluation of a
  surface under a body, the physical references;
* `solver.surface`: Catmull-Clark subdivision, its limit surface (masks; NURBS of a grid) and
  the constrained surface fit;
* `solver.io`: mesh files, Rhino documents (.3dm) and pictures;
* `solver.scene`: scenarios, people placed in a scene, and the pipelines behind `sitrelax fit`,
  `relax`, `batch` and `demo` (the only layer that uses all the others).

This module is the facade: the names a user calls, loaded when first used.
"""

from __future__ import annotations

from capture.lazy import lazy_exports

_EXPORTS = {
    "solver.body.model": ("BODY_PARTS", "BODY_REGIONS", "Body", "BodyShape", "BodyShapeError",
                          "make_body"),
    "solver.body.poses": ("CapturedPose", "PoseSourceError", "load_pose", "pose_body"),
    "solver.body.retarget": ("RetargetError", "joint_map_for", "place", "retarget",
                             "retarget_pose"),
    "solver.body.rig": ("RigMotion", "rest_pose", "rig_pose"),
    "solver.body.skinning": ("skin",),
    "solver.body.relax": ("RelaxError", "RelaxProblem", "RelaxResult", "relax"),
    "solver.contact.pressure": ("PressureField", "pressure_field"),
    "solver.contact.supported": ("SupportedBody",),
    "solver.contact.evaluate": ("evaluate_person",),
    "solver.contact.settle": ("Foam", "Settled", "Support", "settle"),
    "solver.contact.mat": ("SupportContact", "mat_figures", "pressure_grid"),
    "solver.mesh": ("SurfaceMesh", "SurfaceMeshError"),
    "solver.surface.subdivision": ("MeshError", "Subdivision", "grid_mesh", "subdivision"),
    "solver.surface.fit": ("FitError", "FitParams", "FitResult", "fit_surface"),
    "solver.surface.limit": ("limit_matrix", "limit_positions"),
    "solver.surface.nurbs": ("BSplineSurface", "bspline_of_grid", "grid_layout"),
    "solver.scene.scenario": ("Scenario", "ScenarioError", "load_scenario", "parse_scenario"),
    "solver.scene.placement": ("PlacedPerson", "place_person"),
    "solver.scene.run": ("fit_scene", "relax_problem", "run_fit", "run_relax"),
    "solver.io.export": ("ExportError", "write_mesh"),
    "solver.io.rhino": ("write_3dm",),
    "solver.io.render": ("MeshView", "render_png"),
}
__all__, _HOME, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
