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
    doc = ezdxf.readfile(path)
    dims = doc.modelspace().query("DIMENSION")
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
    assert len(msp.query("LWPOLYLINE[layer=='SURFACE']")) == 2  # plan and elevation
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
    assert len(msp.query("LWPOLYLINE[layer=='SOLID']")) == 1
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
