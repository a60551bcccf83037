"""`sitrelax validate pressure`: the importance model against physical references.

Three poses on the default body: seated (frame 39 of `cmu_75_18_high_sit.bvh`, in the middle of
the held seated phase), a lying T-pose (on the back), and reclining (frame 200 of
`cmu_75_17_medium_sit.bvh` turned 35 degrees back about x, as the `reclining` scenario places
it). Three references, each loaded with 735 N through the centre of mass:

* ``soft layer FE``: the body rigid in a 1 cm elastic layer, finite elements with unilateral
  contact and Coulomb friction (`solver.contact.soft_layer`);
* ``contact programme``: the least complementary energy contact forces of a compliant support
  in the exact friction cone, a conic programme (`solver.contact.programme`);
* ``rigid mould``: the paper's section 4.3 set-up, a penalty solved by root finding
  (`solver.contact.rigid_mould`); it agrees with the model nearly by construction.

What they share with the model, so what agreement does not show: all three rest the body in
an envelope of its own faces pointing down or sideways (the paper's set-up), the programme and
the rigid mould on the model's very vertices, normals and Voronoi areas. The contact programme
is the equilibrium model's own law (springs per unit area, k_t / k_n = 1/6, on the same
vertices, balancing the same load and moment), solved another way with another friction law,
so it checks the equilibrium model's solver more than its physics. The finite elements differ
in more (elasticity with Poisson coupling and shear between neighbours, a decimated body, its
own extruded mould), but a 1 cm layer is close to a bed of springs, the model's premise: with
the product's 10 cm foam instead, the paper's model is 0.048-0.057 from it over all vertices
and 0.089-0.094 over the loaded ones (seated and lying, mu = 0.5), over the 0.05 bar. A model
that ignores orientation (the vertex area alone) scores 0.09-0.10, worse than the all-zero
model on the seated pose: the comparison can tell a wrong field from a right one.

Each is run with friction mu = 0.3, 0.5 and 0.8. Every field, the model's |r_n| and the
reference's normal force, is normalised by its own largest value over the mould's vertices (the
vertices of faces pointing down or sideways) and compared there: RMSE over all of them and over
the loaded ones (reference above `LOADED` of its largest value), each next to the score of a
model that predicts zero everywhere, and Pearson's r.
"""

from __future__ import annotations

import errno

import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from capture.files import results_folder

from solver.body.model import BodyShape, make_body
from solver.body.poses import load_pose, pose_body
from solver.body.rig import t_pose
from solver.body.skinning import skin
from solver.contact.pressure import MODELS, mould_vertices, pressure_field

SEATED = "bundled:cmu_75_18_high_sit.bvh#frame=39"
RECLINING = "bundled:cmu_75_17_medium_sit.bvh#frame=200"
RECLINE_DEG = 35.0
MUS = (0.3, 0.5, 0.8)
LOADED = 0.05  # a vertex is loaded where the reference is above 5 % of its largest value
REFERENCES = ("soft layer FE", "contact programme", "rigid mould")


def validation_poses(shape: BodyShape = BodyShape()) -> dict[str, np.ndarray]:
    """Posed vertices (V, 3) of the three validation poses: seated, lying, reclining."""
    body = make_body(shape)
    seated = pose_body(load_pose(SEATED), body)
    lying = t_pose(body, Rotation.from_euler("x", -90, degrees=True).as_matrix())
    recline = skin(body, pose_body(load_pose(RECLINING), body).frame(0), normals=False)[0]
    back = Rotation.from_euler("x", -RECLINE_DEG, degrees=True).as_matrix()
    return {"seated": skin(body, seated.frame(0), normals=False)[0],
            "lying": skin(body, lying, normals=False)[0],
            "reclining": (recline - recline.mean(axis=0)) @ back.T}


def field_metrics(model: np.ndarray, reference: np.ndarray, loaded: float = LOADED) -> dict:
    """Agreement of two fields (K,) over the same vertices, each normalised by its largest
    value: RMSE over all and over the loaded ones (reference above `loaded`), the all-zero
    model's RMSE on the same sets (the root mean square of the reference), and Pearson's r."""
    ours = model / model.max()
    ref = reference / reference.max()
    mask = ref > loaded
    return {
        "rmse_all": float(np.sqrt(np.mean((ours - ref) ** 2))),
        "zero_all": float(np.sqrt(np.mean(ref ** 2))),
        "rmse_loaded": float(np.sqrt(np.mean((ours[mask] - ref[mask]) ** 2))),
        "zero_loaded": float(np.sqrt(np.mean(ref[mask] ** 2))),
        "pearson_r": float(np.corrcoef(ours, ref)[0, 1]),
        "vertices": int(len(ref)), "loaded_vertices": int(mask.sum()),
    }


def run_reference(name: str, vertices: np.ndarray, triangles: np.ndarray, mu: float):
    """One reference's solution (with `vertices`, `normal`, `reaction` and `residual`)."""
    if name == "soft layer FE":
        from solver.contact.soft_layer import soft_layer_contact

        return soft_layer_contact(vertices, triangles, mu=mu)
    if name == "contact programme":
        from solver.contact.programme import contact_programme

        return contact_programme(vertices, triangles, mu=mu)
    if name == "rigid mould":
        from solver.contact.rigid_mould import rigid_mould_contact

        return rigid_mould_contact(vertices, triangles, mu=mu)
    raise ValueError(f"Expected a reference in {REFERENCES}, got {name!r}")


def _model_fields(vertices, triangles, contact, repeats: int = 5) -> dict:
    """Each model's |r_n| on the contact vertices and its median time in ms."""
    out = {}
    for model in MODELS:
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            field = pressure_field(vertices, triangles, model=model)
            times.append(time.perf_counter() - start)
        out[model] = (field.reaction[contact], 1e3 * float(np.median(times)))
    return out


def _crude_field(vertices, triangles, contact) -> np.ndarray:
    """A crude baseline on the contact vertices: each vertex's area where the skin faces down
    at all, whatever its angle (the paper's field without its n . g): a model that beats the
    all-zero field but not this one has learnt only where the body faces down."""
    field = pressure_field(vertices, triangles)
    return (field.area * (field.pressure > 0))[contact]


def validate_pressure(out_dir: str | Path | None = None, *, mus: Sequence[float] = MUS,
                      references: Sequence[str] = REFERENCES,
                      progress: Callable[[str], None] | None = None) -> list[dict]:
    """The comparison on the three poses, every reference and friction coefficient.

    Parameters
    ----------
    out_dir : str or Path, optional
        Where to write a picture per pose (the first reference at mu = 0.5, or the first mu):
        the folder is made before the work, the pictures moved in once all are drawn (a run
        that fails leaves it as it was).
    mus : sequence of float
        Friction coefficients, each >= 0 (a repeated one is run once).
    references : sequence of str
        Names from `REFERENCES` (a repeated one is run once).
    progress : callable, optional
        Called with a line of text before each reference run.

    Returns
    -------
    list of dict
        One row per pose, reference, mu and model: `field_metrics`, the crude baseline's
        RMSE over all and loaded vertices (`crude_all`, `crude_loaded`: `_crude_field`), the
        RMSE against the reference's whole reaction (normal and tangential, each field
        normalised by its own largest value: `rmse_all_reaction`), the model's time
        (`model_ms`), the reference's (`reference_s`), its equilibrium residual, whether it
        `converged` (the finite elements' friction fixed point may stop at its most
        iterations: its figures are then not a solution's; None for the references that
        report their `residual` alone), and for the first model of a
        pose with pictures, `picture`.

    Raises
    ------
    ValueError
        For no friction coefficient or reference, a negative or non-finite one, an unknown
        reference, or an empty `out_dir` name; OSError when `out_dir` cannot be made or
        written into (a file, a file on its way, no right to write). Both before the work.
    """
    mus = _friction_coefficients(mus)
    references = _references(references)
    if out_dir is None:
        return _compare(None, mus, references, progress)
    if Path(out_dir).exists() and not Path(out_dir).is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "Expected a folder for the pictures, got a "
                                                "file", str(out_dir))  # (before the work)
    # the folder made (or refused: an empty name, a file on the way, no right to write) before
    # the work, and the pictures moved in only when every one is drawn: a run that fails or is
    # interrupted leaves the folder as it was
    with results_folder(out_dir) as stage:
        rows = _compare(stage, mus, references, progress)
    for row in rows:
        if "picture" in row:
            row["picture"] = str(Path(out_dir) / Path(row["picture"]).name)
    return rows


def _friction_coefficients(mus: Sequence[float]) -> list[float]:
    """`mus` as floats, each once (in the order given); ValueError for none, or one that is
    not a finite number >= 0."""
    try:
        values = [float(mu) for mu in mus]
    except (TypeError, ValueError):
        raise ValueError(f"Expected friction coefficients as a list of numbers, got "
                         f"{mus!r}") from None
    if not values:
        raise ValueError("Expected at least one friction coefficient, got none")
    for mu in values:
        if not np.isfinite(mu) or mu < 0:
            raise ValueError(f"Expected friction coefficients >= 0 (finite), got {mu}")
    return list(dict.fromkeys(values))


def _references(references: Sequence[str]) -> list[str]:
    """`references` each once (in the order given); ValueError for none, or a name not in
    `REFERENCES`."""
    if isinstance(references, str):
        references = [references]
    names = list(dict.fromkeys(references))
    if not names:
        raise ValueError(f"Expected at least one reference of {list(REFERENCES)}, got none")
    for name in names:
        if name not in REFERENCES:
            raise ValueError(f"Expected a reference in {list(REFERENCES)}, got {name!r}")
    return names


def _compare(out_dir: Path | None, mus: list[float], references: list[str],
             progress: Callable[[str], None] | None) -> list[dict]:
    """`validate_pressure`'s work, its pictures (if any) drawn into `out_dir`."""
    body = make_body()
    rows = []
    for pose, verts in validation_poses().items():
        contact = mould_vertices(verts, body.triangles)
        models = _model_fields(verts, body.triangles, contact)
        crude = _crude_field(verts, body.triangles, contact)
        shown = None
        for ref_name in references:
            for mu in mus:
                if progress is not None:
                    progress(f"{pose}: {ref_name}, mu = {mu}")
                start = time.perf_counter()
                ref = run_reference(ref_name, verts, body.triangles, mu)
                seconds = time.perf_counter() - start
                assert np.array_equal(ref.vertices, contact)
                if shown is None or (ref_name == shown[0] and mu == 0.5):
                    shown = (ref_name, mu, ref.normal)
                baseline = field_metrics(crude, ref.normal)
                for model, (field, ms) in models.items():
                    rows.append({"pose": pose, "reference": ref_name, "mu": float(mu),
                                 "model": model, **field_metrics(field, ref.normal),
                                 "crude_all": baseline["rmse_all"],
                                 "crude_loaded": baseline["rmse_loaded"],
                                 "rmse_all_reaction": float(np.sqrt(np.mean(
                                     (field / field.max() - ref.reaction / ref.reaction.max())
                                     ** 2))),
                                 "model_ms": ms, "reference_s": seconds,
                                 "residual": float(ref.residual),
                                 "converged": None if getattr(ref, "converged", None) is None
                                 else bool(ref.converged)})
        if out_dir is not None and shown is not None:
            path = _picture(Path(out_dir), pose, body, contact, shown,
                            {m: f for m, (f, _) in models.items()})
            for row in rows:
                if row["pose"] == pose:
                    row["picture"] = str(path)
    return rows


def _picture(out_dir: Path, pose: str, body, contact, shown, models) -> Path:
    from solver.io.render import MeshView, Panel, field_colors, render_panels

    out_dir.mkdir(parents=True, exist_ok=True)
    display = skin(body, t_pose(body), normals=False)[0]  # shown on a standing T-pose
    ref_name, mu, normal = shown
    ref = normal / normal.max()
    paper = models["paper"] / models["paper"].max()
    columns = [(f"{ref_name}, mu = {mu}: normal force", ref),
               ("paper: A max(0, n.g)", paper)]
    columns += [(f"{m} model", f / f.max()) for m, f in models.items() if m != "paper"]
    diff = np.abs(paper - ref)
    columns.append((f"|paper - reference| (max {diff.max():.2f})", diff))
    panels = {}
    for label, values in columns:
        field = np.zeros(len(display))
        field[contact] = values
        colors = field_colors(field, 0.0, 1.0)
        for view in ("back", "below"):
            panels[label, view] = Panel([MeshView(display, body.faces, colors)], view,
                                        f"{label}, {view}")
    order = [panels[label, view] for view in ("back", "below") for label, _ in columns]
    return render_panels(out_dir / f"pressure_{pose}.png", order, columns=len(columns),
                         title=f"Pressure on the body, {pose}: each field normalised by its "
                               "largest value", colorbar=("normalised force", 0.0, 1.0))
