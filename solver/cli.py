"""The `sitrelax` command: composes each package's subcommands."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
from typing import Any, Callable, Iterator

from capture import cli as capture_cli
from capture.cli_output import number
from posedb import cli as posedb_cli

# each command imports its work when it runs (numpy, scipy, h5py, the solver): `sitrelax --help`
# stays fast
from solver.body.sliders import SHAPE_KEYS as SHAPE_PARAMS


@contextlib.contextmanager
def _library_prints_to_stderr() -> Iterator[None]:
    """Standard output sent to standard error while the work runs, Python's (`sys.stdout`)
    and the process's (descriptor 1): the report a command prints then stands alone on
    standard output. Libraries print there past us (OSQP's "ERROR in LDL_factor ..." when a
    programme it is given is not convex, set up not to print or not), which made `--json`
    output no JSON. (As `solver.scene.batch`'s job server does.)"""
    kept = None
    if sys.__stdout__ is not None and sys.__stderr__ is not None:  # (both open at start)
        try:
            if sys.stdout is not None:
                sys.stdout.flush()
            kept = os.dup(1)
            os.dup2(2, 1)
        except (OSError, ValueError):  # (Python's output is moved alone)
            if kept is not None:
                os.close(kept)
                kept = None
    try:
        with contextlib.redirect_stdout(sys.stderr) if sys.stderr is not None else \
                contextlib.nullcontext():
            yield
    finally:
        if kept is not None:
            try:
                if sys.stderr is not None:
                    sys.stderr.flush()
            finally:
                os.dup2(kept, 1)
                os.close(kept)


def _cmd_bench(args: argparse.Namespace) -> int:
    from solver.bench import format_table, run_benchmarks

    def progress(msg: str) -> None:
        print(f"bench {msg}", file=sys.stderr, flush=True)

    rows = run_benchmarks(args.names, repeats=args.repeats, progress=progress)
    print(json.dumps(rows, indent=2) if args.json else format_table(rows))
    return 0




def add_shape_args(parser: argparse.ArgumentParser) -> None:
    """Body shape options, each in [0, 1] (MakeHuman's macro sliders; 0.5 is average)."""
    for name in SHAPE_PARAMS:
        parser.add_argument(f"--{name}", type=float, default=0.5, metavar="X",
                            help=f"body {name} in [0, 1] (default 0.5)")


def shape_from_args(args: argparse.Namespace):
    from solver.body.model import BodyShape

    return BodyShape(**{k: getattr(args, k) for k in SHAPE_PARAMS})


# what `body make --out` and `pose show --out` write: solver.io.export.MESH_FORMATS and a PNG
# (spelled out here: the parser loads no numerical work)
OUT_SUFFIXES = (".obj", ".ply", ".glb", ".png")


def mesh_or_picture_path(text: str) -> str:
    """An --out of `body make` or `pose show`, refused by name before any body is made."""
    if not text.lower().endswith(OUT_SUFFIXES):
        raise argparse.ArgumentTypeError(
            f"expected a file ending in .obj, .ply, .glb or .png, got {text!r}")
    return text


def _save_mesh_or_picture(out: str, vertices, faces, title: str, view: str) -> None:
    from solver.io.export import write_mesh

    if out.lower().endswith(".png"):
        from solver.io.render import MeshView, render_png

        render_png(out, [MeshView(vertices, faces)], title=title, view=view)
    else:
        write_mesh(out, vertices, faces, comment=title)


def _cmd_body_make(args: argparse.Namespace) -> int:
    from solver.body.model import make_body

    body = make_body(shape_from_args(args))
    summary = body.summary()
    summary.update(height_m=body.height_m, mass_kg=body.mass_kg,
                   vertices=len(body.vertices), faces=len(body.faces),
                   joints=len(body.joint_names), joint_names=list(body.joint_names))
    if args.out:
        _save_mesh_or_picture(args.out, body.vertices, body.faces,
                              f"body: height {body.height_m:.2f} m, mass {body.mass_kg:.1f} kg",
                              args.view)
        summary["out"] = args.out
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"body: {body.height_m:.3f} m tall, {body.mass_kg:.1f} kg "
              f"({body.volume_m3 * 1000:.1f} l), {len(body.vertices)} vertices, "
              f"{len(body.faces)} quads, {len(body.joint_names)} joints"
              + (f" -> {args.out}" if args.out else ""))
    return 0


def _cmd_pose_show(args: argparse.Namespace) -> int:
    from solver.body.model import make_body
    from solver.body.poses import load_pose, pose_body
    from solver.body.skinning import skin

    from capture.jointmap import read_joint_map

    body = make_body(shape_from_args(args))
    joint_map = read_joint_map(args.joint_map) if args.joint_map else None
    captured = load_pose(args.source, args.db, unit=args.unit, joint_map=joint_map)
    lowest = None if args.as_captured else args.lowest
    motion = pose_body(captured, body, lowest=lowest, pelvis=args.pelvis)
    verts, _ = skin(body, motion.frame(0), normals=False)
    _save_mesh_or_picture(args.out, verts, body.faces, captured.label, args.view)
    result = {"source": args.source, "pose": captured.label, "out": args.out,
              "height_m": body.height_m, "mass_kg": body.mass_kg,
              "pelvis_height_m": float(motion.world.positions[0, 0, 1]),
              "lowest_m": float(verts[:, 1].min()), **_roles_report(captured.skeleton)}
    print(json.dumps(result, indent=2) if args.json else
          f"posed {captured.label} on a {body.height_m:.2f} m, {body.mass_kg:.1f} kg body "
          f"-> {args.out}")
    return 0


def _roles_report(skeleton) -> dict:
    """Which joint plays which role, and how it was found (profile, map, name, structure)."""
    from capture import identify_profile
    from capture.jointmap import guess_joint_map
    from solver.body.retarget import joint_map_for

    roles = joint_map_for(skeleton)
    profile = identify_profile(skeleton.names)
    guess = guess_joint_map(skeleton) if profile is None else None
    given = dict(skeleton.joint_map)
    how = {r: "map" if r in given else (guess.how.get(r, "name") if guess else "profile")
           for r in roles}
    used = {j.removeprefix("end:") for j in roles.values()}
    return {"profile": profile, "roles": roles, "roles_found_by": how,
            "joints_without_role": [n for n in skeleton.names if n not in used]}


def _cmd_fit(args: argparse.Namespace) -> int:
    import sys

    from solver.contact.evaluate import flat_text, peak_text
    from solver.scene.relief import relief_text
    from solver.scene.run import run_fit

    def progress(message: str) -> None:
        print(f"fit: {message}", file=sys.stderr, flush=True)

    workshop = _workshop_options(args)
    formats = [f.strip().lower().lstrip(".") for f in args.format.split(",") if f.strip()]
    with _library_prints_to_stderr():
        report = run_fit(args.scenario, args.out, db=args.db, progress=progress,
                         formats=formats, unit=args.unit, up=args.up, workshop=workshop,
                         pictures=not args.no_pictures)
    problem = (report.get("fabrication", {}).get("solid") or {}).get("problem")
    if args.json:
        print(json.dumps(report, indent=2))
        return 1 if problem else 0
    timing = report["timing"]
    print(f"fitted in {timing['fit_s']:.2f} s, {report['iterations']} iterations "
          f"({timing['total_s']:.2f} s in all, with the evaluation and the files): "
          f"{report['stop_reason']}")
    relief = relief_text(report.get("relief"))
    if relief is not None:
        print(relief)
    for p in report["persons"]:
        loads = ", ".join(f"{name} {round(v['load_share'] * 100) or 0} %" for name, v in
                          p["equilibrium"]["supports"].items())  # (no "-0 %")
        print(f"{p['name']}: coverage {p['coverage']:.2f}, penetration "
              f"{p['max_penetration_m'] * 1000:.0f} mm, peak {peak_text(p)} "
              f"(flat seat {flat_text(p)}), contact {p['contact_area_m2']:.3f} m^2"
              + (f"; load on {loads}" if loads else ""))
    _print_misses(report["misses"])
    print(f"wrote {os.path.join(args.out, 'report.json')} and the surface, control mesh, bodies"
          + (" and pictures" if report["pictures"] else " (pictures skipped: --no-pictures)"))
    if "fabrication" in report:
        _print_fabrication(report["fabrication"])
    return 1 if problem else 0


def _cmd_design(args: argparse.Namespace) -> int:
    from solver.contact.evaluate import peak_text
    from solver.scene.design import run_design
    from solver.scene.relief import relief_text

    def progress(message: str) -> None:
        print(f"design: {message}", file=sys.stderr, flush=True)

    with _library_prints_to_stderr():
        report = run_design(args.poses, args.out, db=args.db, pictures=not args.no_pictures,
                            progress=progress)
    # a design that someone finds no rest on has failed its purpose: exit 1 (its files are
    # written all the same, to look at)
    unheld = [p["name"] for p in report.get("persons", ()) if p.get("supported") is False]
    if args.json:
        print(json.dumps(report, indent=2))
        return 1 if unheld else 0
    design, g = report["design"], report["guarantees"]
    tried = design["waterfall"] or {}
    waterfall = " with a waterfall front" if tried.get("kept") else ""
    before = f"; after the straight front's fit, {tried['straight_fit_s']:.2f} s" if \
        tried.get("kept") and tried.get("straight_fit_s") is not None else ""
    print(f"{', '.join(design['postures'])}: {design['template']}{waterfall}, fitted in "
          f"{report['timing']['fit_s']:.2f} s ({report['iterations']} iterations{before})")
    relief = relief_text(report.get("relief"))
    if relief is not None:
        print(relief)
    for p in report["persons"]:
        print(f"{p['name']}: coverage {p['coverage']:.2f}, penetration "
              f"{p['max_penetration_m'] * 1000:.0f} mm, peak {peak_text(p)}")
    print(f"surface: {g['folds']} folds (max {g['max_fold_deg']:.0f} degrees), "
          f"{g['self_intersections']} self-intersections, "
          f"{'below the floor' if g['below_floor'] else 'above the floor'}, dense penetration "
          f"{g['max_penetration_dense_m'] * 1000:.0f} mm")
    _print_misses(report["misses"])
    print(f"wrote {os.path.join(args.out, 'scenario.toml')} (go on with `sitrelax fit`), "
          f"report.json and the "
          f"surface, control mesh, bodies" + (" and pictures" if report["pictures"] else ""))
    if unheld:
        print(f"no rest on this design for {', '.join(unheld)} (exit status 1)")
        return 1
    return 0


def _print_misses(misses: list[str]) -> None:
    """The bars a fit misses (report.json's `misses`), or that it meets every one."""
    if not misses:
        print("meets every bar")
        return
    print(f"misses {len(misses)} bar(s):")
    for line in misses:
        print(f"  {line}")


def _workshop_options(args: argparse.Namespace):
    """The workshop files asked for, or None when none is (the solids are not loaded)."""
    if args.solid is None and not args.plinth and not args.drawings and \
            args.tool_radius is None:
        return None
    from solver.scene.workshop import WorkshopOptions

    return WorkshopOptions(solid_thickness=args.solid, plinth=args.plinth,
                           drawings=args.drawings, tool_radius=args.tool_radius)


def _print_fabrication(fab: dict) -> None:
    solid = fab.get("solid")
    if solid and solid["ok"]:
        what = "plinth" if solid["kind"] == "plinth" else \
            f"{solid['thickness_m'] * 1000:.1f} mm offset"
        print(f"solid ({what}): watertight, manifold, {solid['volume_m3'] * 1000:.2f} l "
              f"-> solid.stl, solid.3mf (mm, Z up)")
    elif solid:
        print(f"solid NOT written: {solid['problem']}")
    reach = fab.get("reach")
    if reach:
        print(f"ball-nose radius {reach['tool_radius_m'] * 1000:.1f} mm: "
              f"{reach['unreachable_vertices']} vertices, "
              f"{reach['unreachable_area_m2'] * 1e4:.1f} cm^2 out of reach -> reach.png")
    dims = fab.get("dimensions_mm")
    if dims:
        print(f"overall {dims['width_mm']:.0f} x {dims['depth_mm']:.0f} x "
              f"{dims['height_mm']:.0f} mm ({fab.get('dimensions_of', 'surface')}) -> "
              f"overall.dxf, section_*.dxf, sections.png")


def _cmd_batch(args: argparse.Namespace) -> int:
    from solver.scene.batch import BatchError, expand_jobs, parse_grid, run_batch

    if args.scenarios and args.from_db:
        raise BatchError("Give scenario files or --from-db, not both")
    jobs = expand_jobs(args.scenarios, grid=parse_grid(args.grid), from_db=args.from_db,
                       template=args.template, db=args.db)

    def progress(c: dict) -> None:
        print(f"\rbatch: {c['done'] + c['failed']}/{c['total'] - c['skipped']} done, "
              f"{c['failed']} failed, {c['running']} to go, ~{c['left_s']:.0f} s left  ",
              end="", file=sys.stderr, flush=True)

    print(f"batch: {len(jobs)} jobs", file=sys.stderr, flush=True)
    result = run_batch(jobs, args.out, db=args.db, workers=args.workers,
                       scheduler=args.scheduler, progress=progress,
                       time_limit=args.job_time_limit)
    print(file=sys.stderr)
    failed = 1 if result["counts"]["failed"] else 0  # (status 1 when a job failed)
    if args.json:
        print(json.dumps(result, indent=2))
        return failed
    c = result["counts"]
    print(f"{c['total']} jobs: {c['done']} done, {c['failed']} failed ({c['timed_out']} timed "
          f"out), {c['skipped']} skipped "
          f"(finished before) in {result['seconds']:.1f} s; summary in "
          f"{os.path.join(args.out, 'summary.csv')}"
          + (f"; {len(result['stored'])} stored in {args.db}" if result["stored"] else ""))
    for row in result["jobs"]:
        if row["status"] != "ok":
            print(f"  {row['job']} failed: {row['error']}")
    return failed


def _cmd_demo(args: argparse.Namespace) -> int:
    from solver.scene.demo import format_summary, run_demo

    with _library_prints_to_stderr():
        summary = run_demo(args.out, progress=lambda m: print(f"demo: {m}", file=sys.stderr,
                                                               flush=True))
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0


def _cmd_relax(args: argparse.Namespace) -> int:
    from solver.contact.evaluate import peak_text
    import sys

    from solver.scene.run import foam_text, run_relax

    from posedb.locking import lock_timeout_of

    wait = lock_timeout_of(args)
    with _library_prints_to_stderr():
        report = run_relax(args.scenario, args.out, surface_dir=args.surface,
                           person=args.person, db=args.db, save=args.save, lock_timeout=wait,
                           progress=lambda m: print(f"relax: {m}", file=sys.stderr,
                                                    flush=True))
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    if report["surface"] != "fitted":
        print(f"surface {report['surface']}: margin {report['margin_m'] * 100:g} cm, foam "
              f"{foam_text(report['foam'])}, " +
              ("the surface's own (its fit's report.json)" if report["margin_from"] == "surface"
               else "the scenario's (no fit's report beside the surface)"))
    for p in report["persons"]:
        b, a = p["before"], p["after"]
        print(f"{p['name']}: support distance {b['mean_support_distance_m'] * 100:.1f} -> "
              f"{a['mean_support_distance_m'] * 100:.1f} cm, coverage {b['coverage']:.2f} -> "
              f"{a['coverage']:.2f}, contact {b['contact_coverage']:.2f} -> "
              f"{a['contact_coverage']:.2f}, deepest cut {b['max_penetration_m'] * 1000:.0f} -> "
              f"{a['max_penetration_m'] * 1000:.0f} mm, peak {peak_text(b)} -> {peak_text(a)} "
              f"({p['seconds']:.2f} s)")
        print(f"  {p['relaxation']['summary']}")
        if "saved_pose" in p:  # (as the studio's button, a kept captured pose is stored too)
            kept = "" if p["relaxation"]["accepted"] else \
                ", the captured pose as it was: the relaxation kept it"
            print(f"  saved as pose {p['saved_pose']['name']!r} ({p['saved_pose']['id']}){kept}")
    return 0


def _cmd_validate_pressure(args: argparse.Namespace) -> int:
    from solver.scene.validate import REFERENCES, validate_pressure

    refs = args.reference or [r for r in REFERENCES if not (args.quick and r == "soft layer FE")]
    with _library_prints_to_stderr():  # (the solvers' own prints: --json stays JSON)
        rows = validate_pressure(args.out, mus=args.mu, references=refs,
                                 progress=lambda line: print(line, file=sys.stderr, flush=True))
    missed = _validation_misses(rows, args.bar)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 1 if missed else 0
    print("RMSE of each field normalised by its largest value, over all mould vertices and the "
          "loaded ones (reference above 5 % of its largest); in brackets the all-zero model's "
          "RMSE and a crude model's (the area of the skin facing down, whatever its angle); "
          "Pearson r")
    pose = None
    for r in rows:
        if r["pose"] != pose:
            pose = r["pose"]
            print(f"\n{pose} ({r['vertices']} mould vertices)")
            print(f"  {'reference':<18} {'mu':>4} {'model':<12} {'RMSE all':>23} "
                  f"{'RMSE loaded':>23} {'r':>6} {'model':>8} {'reference':>9}")
        unsettled = "  reference not converged" if r.get("converged") is False else ""
        print(f"  {r['reference']:<18} {r['mu']:>4.1f} {r['model']:<12} "
              f"{r['rmse_all']:.3f} ({r['zero_all']:.3f}, {r['crude_all']:.3f}) "
              f"{r['rmse_loaded']:>9.3f} ({r['zero_loaded']:.3f}, {r['crude_loaded']:.3f}) "
              f"{r['pearson_r']:>6.3f} {r['model_ms']:>5.1f} ms "
              f"{r['reference_s']:>7.1f} s{unsettled}")
    paper = [r for r in rows if r["model"] == "paper"]
    if paper:
        def better(r: dict) -> float:  # (an RMSE of 0: infinitely better)
            return r["zero_all"] / r["rmse_all"] if r["rmse_all"] > 0 else math.inf

        worst = min(paper, key=better)
        gain = "equal to the reference (RMSE 0)" if better(worst) == math.inf else \
            f"at least {better(worst):.1f}x better"
        print(f"\npaper model vs the all-zero model: {gain} over all vertices "
              f"({worst['pose']}, {worst['reference']}, mu = {worst['mu']})")
        crude = min(paper, key=lambda r: r["crude_all"] / r["rmse_all"] if r["rmse_all"] > 0
                    else math.inf)
        if crude["rmse_all"] > 0:
            print(f"paper model vs the crude model: at least "
                  f"{crude['crude_all'] / crude['rmse_all']:.1f}x better over all vertices "
                  f"({crude['pose']}, {crude['reference']}, mu = {crude['mu']})")
        if not any(r["reference"] == "soft layer FE" for r in rows):
            print("  (without the finite elements: the references left share the model's "
                  "vertices and contact law, so their agreement checks its solver more than "
                  "its physics)")
    for model in sorted({r["model"] for r in rows}):
        fe = [r for r in rows if r["model"] == model and r["reference"] == "soft layer FE"]
        if fe:
            top = max(fe, key=lambda r: r["rmse_loaded"])
            print(f"{model} model vs the FE reference: RMSE all at most "
                  f"{max(r['rmse_all'] for r in fe):.3f}, loaded at most {top['rmse_loaded']:.3f}"
                  f" ({top['pose']}, mu = {top['mu']})")
    pictures = sorted({r["picture"] for r in rows if "picture" in r})
    for path in pictures:
        print(f"-> {path}")
    unconverged = {(r["pose"], r["reference"], r["mu"]): r.get("residual") for r in rows
                   if r.get("converged") is False}
    for (pose, reference, mu), residual in unconverged.items():
        left = "" if residual is None else f" (residual {residual:.3g})"
        print(f"warning: {pose}, {reference}, mu = {mu}: the reference did not converge"
              f"{left}; its rows are no evidence")
    for line in missed:
        print(f"misses the bar: {line}")
    return 1 if missed else 0


def _validation_misses(rows: list[dict], bar: float | None) -> list[str]:
    """With `--bar`, each row whose model is further than `bar` (RMSE over all mould
    vertices) from its reference, or whose reference did not converge; none without."""
    if bar is None:
        return []
    return [f"{r['pose']}, {r['model']} model vs {r['reference']}, mu = {r['mu']}: "
            + ("the reference did not converge" if r.get("converged") is False else
               f"RMSE {r['rmse_all']:.3f} over {bar:g}")
            for r in rows if r.get("converged") is False or r["rmse_all"] > bar]


class _Parser(argparse.ArgumentParser):
    """A parser (and, through `add_subparsers`, its subcommands' parsers) that remembers its
    usage error, so that `run` can give it to a `--json` reader too."""

    last_error: str | None = None

    def error(self, message: str):
        _Parser.last_error = message
        super().error(message)


def build_parser(extra: Callable[[Any], None] | None = None) -> argparse.ArgumentParser:
    """The `sitrelax` parser; `extra(subparsers)` adds the subcommands of a package above."""
    parser = _Parser(
        prog="sitrelax",
        description="Turn motion-captured poses into furniture surfaces that support them.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True)
    groups = capture_cli.register(sub)
    posedb_cli.register(sub, groups)
    _register_bodies(sub)
    _register_fitting(sub)
    _register_checks(sub)
    if extra is not None:
        extra(sub)
    return parser


def _register_bodies(sub) -> None:
    """`body make` and `pose show`."""
    from solver.io.views import VIEWS

    body = sub.add_parser("body", help="bodies of any shape")
    bsub = body.add_subparsers(dest="body_command", required=True)
    make = bsub.add_parser("make", help="make a body and write it (OBJ, PLY, GLB or PNG)")
    add_shape_args(make)
    make.add_argument("--out", type=mesh_or_picture_path,
                      help="body.obj|.ply|.glb or a .png picture")
    make.add_argument("--view", choices=sorted(VIEWS), default="front")
    make.add_argument("--json", action="store_true", help="machine-readable output")
    make.set_defaults(func=_cmd_body_make)

    pose = sub.add_parser("pose", help="captured poses on bodies")
    psub = pose.add_subparsers(dest="pose_command", required=True)
    show = psub.add_parser("show", help="pose a body and write it (mesh or PNG)")
    show.add_argument("source", help="db:NAME (with --db) or [bvh:]FILE.bvh#frame=N")
    show.add_argument("--db", default=None, help="pose library for db: sources")
    show.add_argument("--unit", default=None, help="length unit of a BVH file no profile "
                      "knows: m, dm, cm, mm, in, cmu or metres per unit")
    show.add_argument("--joint-map", default=None, help="joint-map file (TOML, role = "
                      "\"joint\") for a skeleton no profile knows (default: read from the "
                      "joint names and the hierarchy)")
    add_shape_args(show)
    show.add_argument("--out", required=True, type=mesh_or_picture_path,
                      help="posed.obj|.ply|.glb or a .png picture")
    height = show.add_mutually_exclusive_group()
    height.add_argument("--lowest", type=number(-100.0, 100.0), default=0.0,
                        help="put the lowest skin point at this height, m (default 0: the "
                             "floor)")
    height.add_argument("--pelvis", type=number(-100.0, 100.0), default=None,
                        help="put the pelvis at this height instead, m")
    height.add_argument("--as-captured", action="store_true",
                        help="keep the captured height (scaled by leg length)")
    show.add_argument("--view", choices=sorted(VIEWS), default="three-quarter")
    show.add_argument("--json", action="store_true", help="machine-readable output")
    show.set_defaults(func=_cmd_pose_show)


def _register_fitting(sub) -> None:
    """`fit`, `batch`, `demo` and `relax`."""
    fit = sub.add_parser("fit", help="fit a supporting surface to a scenario")
    fit.add_argument("scenario", help="scenario file (TOML)")
    fit.add_argument("--db", default=None, help="pose library for db: poses")
    fit.add_argument("--out", required=True, help="output folder")
    fit.add_argument("--json", action="store_true", help="print the report")
    fit.add_argument("--solid", type=float, default=None, metavar="THICKNESS_M",
                     help="also a solid this many metres thick, offset away from the bodies "
                          "(solid.stl, solid.3mf; mm, Z up)")
    fit.add_argument("--plinth", action="store_true",
                     help="the solid fills down to the floor instead of a constant thickness")
    fit.add_argument("--drawings", action="store_true",
                     help="sections through each person and overall dimensions (DXF in mm, "
                          "sections.png)")
    fit.add_argument("--tool-radius", type=float, default=None, metavar="METRES",
                     help="ball-nose cutter radius: where it cannot reach (reach.png)")
    fit.add_argument("--format", default="obj,ply,glb", metavar="LIST",
                     help="surface formats, comma-separated, of obj, ply, glb, 3dm (scene.3dm: "
                          "control net, NURBS limit surface, bodies); default obj,ply,glb")
    fit.add_argument("--unit", choices=("m", "cm", "mm", "in", "ft"), default=None,
                     help="length unit of the files (default: m, and mm for .3dm)")
    fit.add_argument("--up", choices=("y", "z"), default=None,
                     help="up axis of the files (default: y, and z for .3dm; GLB stays m, y)")
    fit.add_argument("--no-pictures", action="store_true",
                     help="skip scene.png, pressure.png and pressure_map.png (faster; the "
                          "report says \"pictures\": false)")
    fit.set_defaults(func=_cmd_fit)

    design = sub.add_parser("design", help="furniture for poses: classify, choose a template, "
                                           "place it, fit and evaluate")
    design.add_argument("poses", nargs="+", metavar="POSE",
                        help="a pose as a scenario names it: bvh:FILE#frame=N, "
                             "bvh:bundled:NAME.bvh#frame=N or db:NAME; several sit side by side")
    design.add_argument("--out", default="design", help="output folder (default ./design)")
    design.add_argument("--db", default=None, help="pose library for db: poses")
    design.add_argument("--json", action="store_true", help="print the report")
    design.add_argument("--no-pictures", action="store_true",
                        help="skip scene.png, pressure.png and pressure_map.png")
    design.set_defaults(func=_cmd_design)

    batch = sub.add_parser("batch", help="fit many scenarios and parameter sets, in parallel")
    batch.add_argument("scenarios", nargs="*", help="scenario files (TOML)")
    batch.add_argument("--from-db", help="tag expression: every matching library pose in "
                       "--template")
    batch.add_argument("--template", help="scenario whose people take each pose of --from-db")
    batch.add_argument("--grid", action="append", default=[],
                       help="KEY=V1,V2,...: sigma, tau_max, margin, level, surface.KEY, "
                            "evaluation.KEY, relief.KEY, body.KEY, person.KEY "
                            "(repeatable)")
    batch.add_argument("--db", default=None, help="pose library: db: poses, and where the "
                       "results are stored as scenarios")
    batch.add_argument("--out", required=True, help="output folder (a re-run skips what "
                       "finished)")
    batch.add_argument("--workers", type=number(1, 256, whole=True), default=2,
                       help="local worker processes (default 2)")
    batch.add_argument("--scheduler", help="an existing Dask scheduler, tcp://HOST:8786")
    batch.add_argument("--job-time-limit", type=number(0, 1e6, low_open=True), default=1800.0,
                       metavar="SECONDS",
                       help="a job running longer is stopped and recorded as timed out "
                            "(default 1800)")
    batch.add_argument("--json", action="store_true", help="print the result as JSON")
    batch.set_defaults(func=_cmd_batch)

    demo = sub.add_parser("demo", help="the whole chain on the bundled recordings")
    demo.add_argument("--out", default="sitrelax-demo", help="an empty or new folder "
                      "(default: sitrelax-demo)")
    demo.add_argument("--json", action="store_true", help="print the summary as JSON")
    demo.set_defaults(func=_cmd_demo)

    rx = sub.add_parser("relax", help="let the scenario's people settle onto the surface")
    rx.add_argument("scenario", help="scenario file (TOML)")
    rx.add_argument("--surface", metavar="FIT_DIR|FILE",
                    help="the surface: a `sitrelax fit` folder (its surface.obj, else "
                         "surface.ply, else surface.glb) or a surface file (.obj of quads or "
                         "triangles, .ply, .glb; in the unit and up axis it states); default: "
                         "fit now. The bodies sink in by the margin and press the foam the "
                         "surface was fitted with (its fit's report.json), whatever the "
                         "scenario's surface.margin and evaluation say; by the scenario's for a "
                         "surface without a fit's report (from CAD)")
    rx.add_argument("--person", type=int, help="only this person (1-based)")
    rx.add_argument("--db", default=None, help="pose library for db: poses")
    rx.add_argument("--save", action="store_true",
                    help="store the relaxed poses in the --db library, linked to their origin "
                         "(the library is checked before the work: a damaged, read-only or "
                         "locked one is refused at once)")
    posedb_cli.add_lock_timeout_option(rx, "with --save: ")
    rx.add_argument("--out", required=True, help="output folder")
    rx.add_argument("--json", action="store_true", help="print the report")
    rx.set_defaults(func=_cmd_relax)


def _register_checks(sub) -> None:
    """`validate` and `bench`."""
    validate = sub.add_parser("validate", help="check models against physical references")
    vsub = validate.add_subparsers(dest="validate_command", required=True)
    vp = vsub.add_parser("pressure", help="the importance model against physical references "
                         "(finite elements, a contact programme, the rigid mould), about a "
                         "minute; --quick skips the finite elements")
    vp.add_argument("--out", help="folder for the side-by-side pictures")
    vp.add_argument("--mu", type=number(0, 10), nargs="+", default=[0.3, 0.5, 0.8],
                    help="friction coefficients (default: 0.3 0.5 0.8)")
    vp.add_argument("--reference", action="append",
                    choices=["soft layer FE", "contact programme", "rigid mould"],
                    help="only this reference (repeatable; default: all three)")
    vp.add_argument("--quick", action="store_true",
                    help="skip the finite-element reference (a few seconds instead of a minute)")
    vp.add_argument("--bar", type=number(0, 1), default=None, metavar="RMSE",
                    help="exit with status 1 when a model is further than this from a reference "
                         "(RMSE over all mould vertices), or a reference did not converge "
                         "(default: report only)")
    vp.add_argument("--json", action="store_true", help="machine-readable output")
    vp.set_defaults(func=_cmd_validate_pressure)

    bench = sub.add_parser("bench", help="run the benchmarks (medians, speed-ups)")
    bench.add_argument("names", nargs="*", help="entries to run (default: all)")
    bench.add_argument("--repeats", type=number(1, 10000, whole=True), default=None,
                       help="timed runs per entry (default: per entry)")
    bench.add_argument("--json", action="store_true", help="machine-readable output")
    bench.set_defaults(func=_cmd_bench)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser(), argv)


def run(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Parses and runs one command; errors become one line and exit status 2 (with `--json`,
    also a JSON object `{"error": ..., "exit_status": 2}` on standard output)."""
    _Parser.last_error = None
    try:
        args = parser.parse_args(argv)
    except SystemExit as stop:  # a usage error (argparse printed it) or --help
        words = sys.argv[1:] if argv is None else argv
        if stop.code == 2 and _Parser.last_error is not None and "--json" in words:
            print(json.dumps({"error": _Parser.last_error, "exit_status": 2}))
        raise
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("sitrelax: interrupted", file=sys.stderr)
        if getattr(args, "json", False):  # a reader of --json output learns why there is none
            print(json.dumps({"error": "interrupted", "exit_status": 130}))
        return 130
    except BrokenPipeError:  # the reader stopped (`sitrelax ... --json | head`): no more output
        if args.debug:
            raise
        try:
            out = sys.stdout.fileno()
        except (OSError, ValueError):  # (an output in memory has no descriptor to close)
            return 1
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, out)  # (the interpreter's last flush goes nowhere)
        finally:
            os.close(devnull)
        return 1
    except (ValueError, OSError, KeyError) as exc:
        if args.debug:
            raise
        if isinstance(exc, KeyError) and exc.args:
            message = exc.args[0]
        elif isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
            message = f"{exc.strerror}: {exc.filename}"
        else:
            message = exc
        print(f"sitrelax: error: {message}", file=sys.stderr)
        if getattr(args, "json", False):  # a reader of --json output gets the error as JSON
            print(json.dumps({"error": str(message), "exit_status": 2}))
        return 2


if __name__ == "__main__":
    sys.exit(main())
