"""A workshop's review of the files `sitrelax fit` writes for it, checked with libraries of
its own (igl's exact winding number, trimesh, ezdxf) rather than the solid module's checks."""

import igl
import numpy as np
import pytest

from solver.io.solid import check_solid, thicken
from solver.mesh import face_normals


def v_crease(flank_deg: float = 60.0, columns: int = 41, rows: int = 9, width: float = 0.04,
             length: float = 0.02, height: float = 0.1):
    """Two flat flanks rising at `flank_deg` from a sharp crease along z (a hollow seen from
    above, the bodies' side; a seat meeting a back): quads counter-clockwise seen from above.
    At 60 degrees the faces either side of the crease turn by 120 degrees."""
    x = np.linspace(-width / 2, width / 2, columns)
    y = height + np.abs(x) * np.tan(np.radians(flank_deg))
    z = np.linspace(0.0, length, rows)
    xx, zz = np.meshgrid(x, z)
    vertices = np.stack([xx.ravel(), np.broadcast_to(y, xx.shape).ravel(), zz.ravel()], axis=1)
    idx = np.arange(rows * columns).reshape(rows, columns)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]],
                     axis=-1).reshape(-1, 4)
    return vertices, quads


def in_front_of_surface(solid, probe: float = 1e-4) -> int:
    """How many of the surface's triangles have the solid `probe` metres in front of their
    middle (towards the bodies), by igl's exact winding number."""
    top = solid.vertices[:solid.n_surface]
    tris = solid.surface_triangles
    points = top[tris].mean(axis=1) + probe * face_normals(top, tris)
    return int(np.sum(np.abs(igl.winding_number(solid.vertices, solid.triangles, points)) > 0.5))


def test_a_solid_under_a_sharp_crease_never_stands_in_front_of_the_surface():
    """Under a crease whose faces turn by more than 90 degrees the offset is trimmed; the pieces
    swept along the normals around the crease's corners (those of both flanks) reached through
    the surface where the crease meets the border, and the check passed the solid. A solid
    the workshop receives lies behind the surface everywhere, or is refused."""
    vertices, quads = v_crease()
    solid = thicken(vertices, quads, 0.005, check=False)
    check = check_solid(solid)
    assert solid.trimmed > 0
    if check.ok:
        assert in_front_of_surface(solid) == 0
    else:
        assert "in front of the surface" in check.problem()
    assert check.over_surface == in_front_of_surface(solid)


def test_dxf_dimension_styles_themselves_show_millimetres(tmp_path):
    """The drawings are in millimetres. Their DIMENSION entities' own style (the DIMSTYLE
    table entry) showed lengths times 100 (ezdxf's EZDXF style is made for metres shown in
    centimetres), corrected only by an override in each entity's XDATA: a CAD program that
    regenerates a dimension from its style alone would write 49555 for 496 mm. Read back by
    ezdxf, the style itself must show the drawing's millimetres as they are."""
    import ezdxf

    from solver.io.drawing import section, write_overall_dxf, write_section_dxf

    vertices, quads = v_crease()
    write_overall_dxf(tmp_path / "overall.dxf", vertices, quads)
    sec = section("across", [0.0, 0.1, 0.01], [1.0, 0.0, 0.0], {"SURFACE": (vertices, quads)})
    write_section_dxf(tmp_path / "section.dxf", sec)
    for name, count in (("overall.dxf", 3), ("section.dxf", 2)):
        doc = ezdxf.readfile(tmp_path / name)
        assert doc.header["$INSUNITS"] == 4
        assert not doc.audit().has_errors
        dims = doc.modelspace().query("DIMENSION")
        assert len(dims) == count
        for dim in dims:
            style = doc.dimstyles.get(dim.dxf.dimstyle)
            assert style.dxf.get("dimlfac", 1.0) == 1.0
            assert style.dxf.get("dimdec") == 0  # whole millimetres, as the texts say
            shown = [e.dxf.text for e in doc.blocks.get(dim.dxf.geometry) if
                     e.dxftype() == "TEXT"] + [e.text for e in doc.blocks.get(
                         dim.dxf.geometry) if e.dxftype() == "MTEXT"]
            assert shown == [f"{dim.get_measurement():.0f}"]


@pytest.mark.slow
def test_the_fit_command_never_writes_a_solid_through_its_surface(tmp_path, capsys):
    """`reclining`'s 3 cm solid, trimmed under its tight bends (a 12 mm radius, quads about
    2 cm), stood up to about 4 mm in front of the surface at 19 of its triangles, where the
    body lies, and was written. Read back as the workshop has them (surface.obj and solid.stl,
    millimetres, Z up), a solid written lies behind the surface at every triangle's middle
    (igl's exact winding number 0.1 mm in front of it); one that does not is refused, named
    and not written, and the command exits 1."""
    import json
    from pathlib import Path

    import trimesh

    from studio.cli import main

    scenario = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios" / "reclining.toml"
    out = tmp_path / "fit"
    code = main(["fit", str(scenario), "--out", str(out), "--solid", "0.03", "--format", "obj",
                 "--unit", "mm", "--up", "z", "--no-pictures"])
    report = json.loads((out / "report.json").read_text())
    solid = report["fabrication"]["solid"]
    if (out / "solid.stl").exists():
        assert code == 0 and solid["ok"]
        surface = trimesh.load(out / "surface.obj", process=False)  # (quads split by trimesh)
        stl = trimesh.load(out / "solid.stl")
        probes = surface.triangles_center + 0.1 * surface.face_normals
        winding = igl.winding_number(np.asarray(stl.vertices, dtype=np.float64),
                                     np.asarray(stl.faces, dtype=np.int64), probes)
        assert int(np.sum(np.abs(winding) > 0.5)) == 0
    else:
        assert code == 1 and not solid["ok"]
        assert "in front of the surface" in solid["problem"]
        assert "solid NOT written" in capsys.readouterr().out
        assert "solid_stl" not in report["files"]
