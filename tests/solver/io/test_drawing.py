"""Drawings: plane sections, and DXF files that ezdxf reads back with their dimensions."""

import ezdxf
import numpy as np
import pytest

from solver.io.drawing import (DrawingError, boundary_loops, overall_dimensions,
                               plane_section, render_sections, section, write_overall_dxf,
                               write_section_dxf)
from solver.io.solid import thicken


def test_section_of_one_square_is_its_midline():
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1.0]])
    lines = plane_section(square, np.array([[0, 3, 2, 1]]), [0.5, 0, 0], [1, 0, 0])
    assert len(lines) == 1  # through the 0-2 diagonal's middle too
    assert np.allclose(sorted(map(tuple, lines[0])), [(0.5, 0, 0), (0.5, 0, 0.5), (0.5, 0, 1)])


def test_section_of_a_closed_solid_is_a_closed_loop(trough):
    solid = thicken(trough[0], trough[1], 0.005)
    lines = plane_section(solid.vertices, solid.triangles, [0, 0, 0.02], [0, 0, 1])
    assert len(lines) == 1 and np.allclose(lines[0][0], lines[0][-1])


def test_section_runs_across_the_trough_in_plane_coordinates(trough):
    vertices, quads, _ = trough
    sec = section("across", [0.0, 0.0, 0.02], [1.0, 0.0, 0.0], {"SURFACE": (vertices, quads)})
    (lo, hi) = sec.extent()
    assert lo[0] == pytest.approx(-0.04) and hi[0] == pytest.approx(0.04)
    assert lo[1] == pytest.approx(0.1) and hi[1] == pytest.approx(vertices[:, 1].max())


def test_a_vertical_direction_is_refused(trough):
    with pytest.raises(DrawingError, match="horizontal direction"):
        section("up", [0, 0, 0], [0, 1, 0], {"SURFACE": trough[:2]})


def test_boundary_loop_of_a_grid_goes_round_it(trough):
    loops = boundary_loops(trough[1])
    assert len(loops) == 1 and loops[0][0] == loops[0][-1]
    assert len(loops[0]) - 1 == 2 * (161 - 1) + 2 * (9 - 1)


def _measurements(path):
    """The document and its dimensions' measured lengths (mm), each checked to show as it
    measures (the text ezdxf's rendering put in the dimension's block, whole millimetres)."""
    doc = ezdxf.readfile(path)
    dims = doc.modelspace().query("DIMENSION")
    for d in dims:
        shown = [m.plain_text() for m in d.get_geometry_block().query("MTEXT")]
        assert shown == [f"{d.get_measurement():.0f}"], (shown, d.get_measurement())
    return doc, sorted(round(d.get_measurement(), 3) for d in dims)


def test_overall_dxf_has_width_depth_and_height_dimensions(tmp_path, trough):
    vertices, quads, _ = trough
    dims = write_overall_dxf(tmp_path / "overall.dxf", vertices, quads)
    doc, measured = _measurements(tmp_path / "overall.dxf")
    assert doc.header["$INSUNITS"] == 4  # millimetres
    box = vertices.max(axis=0) - vertices.min(axis=0)
    expected = sorted(round(v, 3) for v in (box[0] * 1000, box[2] * 1000,
                                            vertices[:, 1].max() * 1000))
    assert measured == pytest.approx(expected, abs=1e-3)
    assert dims == overall_dimensions(vertices)
    msp = doc.modelspace()
    outlines = msp.query("LWPOLYLINE[layer=='SURFACE']")
    assert len(outlines) == 2 and all(p.closed for p in outlines)  # plan and elevation
    assert len(msp.query("TEXT")) == 1


def test_section_dxf_has_its_curves_and_dimensions(tmp_path, trough):
    vertices, quads, _ = trough
    solid = thicken(vertices, quads, 0.005)
    sec = section("across", [0.0, 0.0, 0.02], [1.0, 0.0, 0.0],
                  {"SURFACE": (vertices, quads), "SOLID": (solid.vertices, solid.triangles)})
    write_section_dxf(tmp_path / "section.dxf", sec)
    doc, measured = _measurements(tmp_path / "section.dxf")
    msp = doc.modelspace()
    assert len(msp.query("LWPOLYLINE[layer=='SURFACE']")) == 1
    solid_cut = msp.query("LWPOLYLINE[layer=='SOLID']")
    assert len(solid_cut) == 1 and solid_cut[0].closed  # a solid's cut is a loop
    assert not msp.query("LWPOLYLINE[layer=='SURFACE']")[0].closed
    assert len(msp.query("LINE[layer=='FLOOR']")) == 1
    assert measured == pytest.approx(sorted([80.0, round(vertices[:, 1].max() * 1000, 3)]),
                                     abs=1e-3)


def test_sections_picture_is_a_png(tmp_path, trough):
    sec = section("across", [0.0, 0.0, 0.02], [1.0, 0.0, 0.0], {"SURFACE": trough[:2]})
    path = render_sections(tmp_path / "sections.png", [sec])
    assert path.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(DrawingError, match="at least one section"):
        render_sections(tmp_path / "none.png", [])


def test_overall_dxf_refuses_a_surface_that_is_not_a_number_or_empty(tmp_path, trough):
    vertices, quads, _ = trough
    bad = np.array(vertices, dtype=float)
    bad[3, 0] = np.nan
    with pytest.raises(DrawingError, match="finite surface vertices, got 1"):
        write_overall_dxf(tmp_path / "nan.dxf", bad, quads)
    with pytest.raises(DrawingError, match="some faces"):
        write_overall_dxf(tmp_path / "empty.dxf", np.zeros((0, 3)), np.zeros((0, 4), int))
    assert not list(tmp_path.glob("*.dxf"))  # nothing half-written


def _inside_triangles(points, corners):
    """Whether each 2D point lies in any of the triangles (T, 3, 2) (barycentric signs)."""
    a, b, c = (corners[None, :, k] for k in range(3))
    p = points[:, None]

    def side(u, v):
        return (v[..., 0] - u[..., 0]) * (p[..., 1] - u[..., 1]) - \
            (v[..., 1] - u[..., 1]) * (p[..., 0] - u[..., 0])

    s1, s2, s3 = side(a, b), side(b, c), side(c, a)
    return (((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) &
                                                    (s3 <= 0))).any(axis=1)


@pytest.mark.parametrize("solid", [False, True])
def test_overall_dxf_outlines_what_the_mesh_covers_from_above_and_the_side(tmp_path, solid):
    """A dish 0.5 m square whose middle (400 mm above the floor) lies 100 mm under its
    corners, and its 10 mm solid (projected whole by manifold3d): the elevation reaches down
    to the middle (its border alone would stop at 450 mm), and each view's closed outlines
    hold a point exactly when a projected triangle does (10,000 random points, checked by
    their barycentric signs and matplotlib's even-odd containment, not by the library that
    drew them)."""
    from matplotlib.path import Path as MplPath

    n = 21
    x, z = np.meshgrid(np.linspace(-0.25, 0.25, n), np.linspace(-0.25, 0.25, n))
    vertices = np.stack([x.ravel(), 0.40 + 0.1 * (x ** 2 + z ** 2).ravel() / 0.125,
                         z.ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]],
                     axis=-1).reshape(-1, 4)
    if solid:
        shell = thicken(vertices, quads, 0.01)
        vertices, tris = shell.vertices, shell.triangles
        write_overall_dxf(tmp_path / "overall.dxf", vertices, tris, what="solid")
    else:
        tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        write_overall_dxf(tmp_path / "overall.dxf", vertices, quads)
    layer = "SOLID" if solid else "SURFACE"  # (the solid's outline on the solid's layer)
    msp = ezdxf.readfile(tmp_path / "overall.dxf").modelspace()
    assert not msp.query(f"LWPOLYLINE[layer=='{'SURFACE' if solid else 'SOLID'}']")
    loops = [np.array([(q[0], q[1]) for q in p.get_points()])
             for p in msp.query(f"LWPOLYLINE[layer=='{layer}']")]
    mm = vertices * 1000.0
    plan = np.stack([mm[:, 0], -mm[:, 2]], axis=1)
    side = np.stack([-mm[:, 2], mm[:, 1]], axis=1)
    shift = plan[:, 0].max() + 200.0 - side[:, 0].min()  # (the elevation beside the plan)
    side[:, 0] += shift
    rng = np.random.default_rng(3)
    for view in (plan, side):
        mine = [lp for lp in loops if (lp[:, 0].min() >= view[:, 0].min() - 0.01) and
                (lp[:, 0].max() <= view[:, 0].max() + 0.01)]
        assert mine
        lo, hi = view.min(axis=0) - 5.0, view.max(axis=0) + 5.0
        points = rng.uniform(lo, hi, size=(10_000, 2))
        held = np.zeros(len(points), dtype=int)
        for lp in mine:
            held += MplPath(lp).contains_points(points)
        agree = (held % 2 == 1) == _inside_triangles(points, view[tris])
        assert agree.mean() > 0.999, agree.mean()
    elevation = np.concatenate([lp for lp in loops if lp[:, 0].min() >= shift - 300])
    assert elevation[:, 1].min() == pytest.approx(mm[:, 1].min(), abs=0.01)
    assert elevation[:, 1].max() == pytest.approx(500.0, abs=0.01)
    assert mm[:, 1].min() == pytest.approx(390.0 if solid else 400.0, abs=0.01)


def _outline_area(loops):
    """The area the outlines enclose (outer loops counter-clockwise, holes clockwise)."""
    return sum(0.5 * float(np.sum(lp[:-1, 0] * lp[1:, 1] - lp[1:, 0] * lp[:-1, 1]))
               for lp in loops)


@pytest.mark.parametrize("order", [[0, 1, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]])
def test_silhouette_of_three_triangles_on_one_edge_is_their_union_in_any_order(order):
    """Two triangles either side of an edge and a third standing on it, seen from above:
    the outline is the two lower ones' rhombus (area 1), whatever order they come in (an edge
    used three times borders the region once)."""
    from solver.io.drawing import silhouette

    points = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0.5, 1.0]])
    tris = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])[order]
    assert _outline_area(silhouette(points, tris)) == pytest.approx(1.0)


def test_silhouette_ignores_a_triangle_with_a_corner_twice():
    """A quad stored with a corner twice (a triangle) beside a unit square: the outline is
    the square and that triangle (area 1.5), not nothing."""
    from solver.io.drawing import silhouette

    points = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], dtype=float)
    loops = silhouette(points, np.array([[0, 1, 2, 3], [1, 4, 2, 2]]))
    assert _outline_area(loops) == pytest.approx(1.5)
