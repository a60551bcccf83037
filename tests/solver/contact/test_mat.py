"""Mat figures, pressure maps and their CSV, checked on a hand-computed box resting on foam."""

import numpy as np
import pytest

from solver.contact.mat import (G, MatError, PressureGrid, SupportContact, mat_figures,
                                pressure_grid, read_pressure_csv, surface_grid,
                                write_pressure_csv)
from solver.mesh import SurfaceMesh
from solver.surface.subdivision import grid_mesh, subdivision

# the box's bottom face: 0.4 m along x by 0.3 m along z, a vertex every centimetre, centred on
# (0.1, 0.45, -0.05), resting on a flat foam seat at y = 0.45
NX, NZ, STEP, CENTRE = 41, 31, 0.01, np.array([0.1, 0.45, -0.05])
MASS = 30.0
AREA = 0.4 * 0.3


def _box():
    """The bottom face's vertices (V, 3) and Voronoi areas (V,): a quarter cell at the
    corners, a half along the sides, a whole one inside."""
    i, k = np.meshgrid(np.arange(NX), np.arange(NZ), indexing="ij")
    points = CENTRE + np.stack([(i.ravel() - (NX - 1) / 2) * STEP, np.zeros(i.size),
                                (k.ravel() - (NZ - 1) / 2) * STEP], axis=1)
    wx = np.where((i.ravel() == 0) | (i.ravel() == NX - 1), 0.5, 1.0)
    wz = np.where((k.ravel() == 0) | (k.ravel() == NZ - 1), 0.5, 1.0)
    return points, wx * wz * STEP**2, k.ravel()


@pytest.fixture(scope="module")
def seat():
    v, q = grid_mesh((1.2, 0.8), (8, 6), 0.45)
    s = subdivision(len(v), q, 3)
    return s.apply(v), s.faces


def _contact(name, points, force, surface=None, tangential=None, vertices=None):
    k = len(points)
    faces = np.full(k, -1)
    if surface is not None:
        _, _, _, faces, points = SurfaceMesh.from_quads(*surface).closest(points)
    return SupportContact(name, np.arange(k) if vertices is None else vertices, force,
                          np.zeros((k, 3)) if tangential is None else tangential,
                          np.tile([0.0, 1.0, 0.0], (k, 1)), points, faces)


def test_box_on_foam_by_hand(seat):
    """A uniform load m g over the box's 1200 cm^2: peak = mean = PPI = m g / A, contact area
    A, the centre of pressure at the centre, all of the weight on the seat."""
    points, areas, _ = _box()
    assert areas.sum() == pytest.approx(AREA)
    p = MASS * G / AREA  # Pa
    figures = mat_figures([_contact("seat", points, p * areas, seat)], areas, MASS)
    s = figures["supports"]["seat"]
    assert s["load_n"] == pytest.approx(MASS * G) and s["load_share"] == pytest.approx(1.0)
    for key in ("peak_kpa", "mean_kpa", "peak_pressure_index_kpa"):
        assert s[key] == pytest.approx(p / 1e3), key
    assert s["contact_area_cm2"] == pytest.approx(1200.0)
    np.testing.assert_allclose(s["centre_of_pressure_m"], CENTRE, atol=1e-12)
    d = s["distribution"]
    assert d["band_area_cm2"] == pytest.approx([0, 1200.0, 0, 0, 0, 0])  # 2.45 kPa: 2-4
    assert d["band_load_share"] == pytest.approx([0, 1, 0, 0, 0, 0])
    assert d["halves"] == pytest.approx({"front": 0.5, "back": 0.5, "left": 0.5, "right": 0.5})
    assert figures["total"]["load_share"] == pytest.approx(1.0)
    assert figures["body_weight_n"] == pytest.approx(MASS * G)


def test_a_peak_shows_in_peak_and_index_but_barely_in_the_mean():
    points, areas, _ = _box()
    force = 1000.0 * areas
    centre = np.argmin(np.linalg.norm(points - CENTRE, axis=1))
    force[centre] = 20e3 * areas[centre]  # 20 kPa on one 1 cm^2 vertex
    s = mat_figures([_contact("seat", points, force)], areas, MASS)["supports"]["seat"]
    assert s["peak_kpa"] == pytest.approx(20.0)
    # about 10 cm^2 around it: the peak vertex and its neighbours within 1.78 cm (9 of 1 cm^2)
    ring = np.linalg.norm(points - points[centre], axis=1) <= np.sqrt(10e-4 / np.pi)
    assert s["peak_pressure_index_kpa"] == pytest.approx((20 + (ring.sum() - 1)) / ring.sum())
    assert s["mean_kpa"] == pytest.approx(force.sum() / AREA / 1e3)
    assert s["distribution"]["band_area_cm2"][5] == pytest.approx(1.0)


def test_two_supports_share_the_weight_80_20(seat):
    """The seat carries 80 % of m g through the box, the floor 20 % through a foot patch; a
    friction pair (seat +x, floor -x) changes the supports' whole forces but not their shares
    of the weight (the vertical part) nor the total."""
    points, areas, _ = _box()
    foot = np.array([[0.0, 0.0, 0.3], [0.05, 0.0, 0.3], [0.0, 0.0, 0.35], [0.05, 0.0, 0.35]])
    all_areas = np.concatenate([areas, np.full(4, 4e-4)])
    seat_n = 0.8 * MASS * G * areas / areas.sum()
    friction = np.zeros((len(points), 3))
    friction[:, 0] = 0.1 * seat_n
    c_seat = _contact("seat", points, seat_n, seat, friction)
    c_floor = _contact("floor", foot, np.full(4, 0.05 * MASS * G), None,
                       np.tile([-0.1 * 0.2 * MASS * G, 0, 0], (4, 1)),
                       np.arange(len(points), len(points) + 4))
    figures = mat_figures([c_seat, c_floor], all_areas, MASS)
    s, f, t = figures["supports"]["seat"], figures["supports"]["floor"], figures["total"]
    assert s["normal_load_n"] / (MASS * G) == pytest.approx(0.8)
    assert s["load_share"] == pytest.approx(0.8)  # the vertical part: friction is sideways
    assert s["load_n"] == pytest.approx(0.8 * MASS * G * np.hypot(1, 0.1))
    assert f["normal_load_n"] / (MASS * G) == pytest.approx(0.2)
    assert f["contact_area_cm2"] == pytest.approx(16.0)
    assert f["mean_kpa"] == pytest.approx(0.2 * MASS * G / 16e-4 / 1e3)
    assert f["load_share"] == pytest.approx(0.2)
    assert f["load_n"] == pytest.approx(0.2 * MASS * G * np.hypot(1, 0.4))
    assert t["load_share"] == pytest.approx(1.0)  # the frictions cancel
    assert t["normal_load_n"] == pytest.approx(MASS * G)
    assert t["contact_area_cm2"] == pytest.approx(1216.0)


def test_total_load_is_the_magnitude_of_the_summed_force():
    points, areas, _ = _box()
    n = MASS * G * areas / areas.sum()
    tang = np.zeros((len(points), 3))
    tang[:, 2] = 0.2 * n
    figures = mat_figures([_contact("seat", points, n, None, tang)], areas, MASS)
    assert figures["total"]["load_n"] == pytest.approx(MASS * G * np.hypot(1, 0.2))


def test_regions_on_a_hand_made_labelling():
    """The box's back rows (z index below 15) labelled pelvis, the rest thighs: with a uniform
    load each region carries its share of the area, 14.5 / 30 and 15.5 / 30."""
    points, areas, row = _box()
    labels = np.where(row < 15, 1, 0)
    p = MASS * G / AREA
    figures = mat_figures([_contact("seat", points, p * areas)], areas, MASS, labels,
                          ("thighs", "pelvis"))
    regions = figures["supports"]["seat"]["regions"]
    assert set(regions) == {"thighs", "pelvis"}
    assert regions["pelvis"]["load_share"] == pytest.approx(14.5 / 30)
    assert regions["thighs"]["load_share"] == pytest.approx(15.5 / 30)
    assert regions["pelvis"]["contact_area_cm2"] == pytest.approx(40 * 14.5)
    assert regions["pelvis"]["mean_kpa"] == pytest.approx(p / 1e3)
    assert regions["pelvis"]["centre_of_pressure_m"][2] < CENTRE[2]
    assert figures["total"]["regions"]["thighs"]["load_share"] == pytest.approx(15.5 / 30)


def test_figures_are_json_ready_without_contact():
    import json

    points, areas, _ = _box()
    empty = SupportContact("back", np.zeros(0, int), np.zeros(0), np.zeros((0, 3)),
                           np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int))
    figures = mat_figures([empty, _contact("seat", points, 100 * areas)], areas, MASS,
                          np.zeros(len(areas), int))
    back = figures["supports"]["back"]
    assert back["mean_kpa"] is None and back["centre_of_pressure_m"] is None
    assert back["peak_kpa"] == 0.0 and back["regions"] == {}
    text = json.dumps(figures, allow_nan=False)
    assert "NaN" not in text
    assert pressure_grid(empty).pressure_kpa.shape == (0, 0)


@pytest.mark.parametrize("kwargs, message", [
    ({"normal_force": [-1.0]}, "normal forces >= 0"),
    ({"points": np.zeros((2, 3))}, r"points of shape \(1, 3\)"),
    ({"vertices": [0.5]}, "integer vertices"),
    ({"normal_force": [np.nan]}, "finite normal_force"),
])
def test_bad_contacts_are_named(kwargs, message):
    fields = dict(name="seat", vertices=[0], normal_force=[1.0], tangential_force=np.zeros((1, 3)),
                  normals=[[0, 1, 0]], points=np.zeros((1, 3)), faces=[-1])
    fields.update(kwargs)
    with pytest.raises(MatError, match=message):
        SupportContact(**fields)


def test_duplicate_supports_and_bad_mass_are_refused():
    points, areas, _ = _box()
    c = _contact("seat", points, areas)
    with pytest.raises(MatError, match="one contact per support"):
        mat_figures([c, c], areas, MASS)
    with pytest.raises(MatError, match="mass > 0"):
        mat_figures([c], areas, 0.0)


def test_surface_grid_recovers_the_rows_and_columns(seat):
    vertices, faces = seat
    vertex_grid, face_grid = surface_grid(faces)
    assert sorted(face_grid.shape) == [48, 64]
    assert sorted(np.unique(face_grid).tolist()) == list(range(len(faces)))
    nodes = vertices[vertex_grid]
    # neighbours along the grid are about one quad apart (1.875 or 1.667 cm), never across it
    for axis in (0, 1):
        step = np.linalg.norm(np.diff(nodes, axis=axis), axis=-1)
        assert step.min() > 0.015 and step.max() < 0.02
    ell = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6]])  # three quads in an L
    assert surface_grid(ell) is None
    assert surface_grid(np.array([[0, 1, 2, 3]]))[1].tolist() == [[0]]
    again = surface_grid(faces.copy())  # the same quads again: the grid found before, kept
    assert again[0] is vertex_grid and not again[0].flags.writeable
    assert surface_grid(faces[::-1].copy())[1] is not face_grid  # other quads: found afresh


def test_pressure_grid_conserves_force_and_finds_the_box(seat):
    """Draped on the seat's own grid: the cells carry the whole normal force; cells inside the
    box (2 cm in from its edges) read m g / A, cells 2 cm outside it nothing."""
    points, areas, _ = _box()
    p = MASS * G / AREA
    contact = _contact("seat", points, p * areas, seat)
    grid = pressure_grid(contact, *seat, areas)
    assert isinstance(grid, PressureGrid) and grid.draped
    assert grid.normal_load_n == pytest.approx(MASS * G, rel=1e-9)
    assert max(grid.cell_size_m) <= 0.02
    np.testing.assert_allclose(grid.column_axis, [1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(grid.row_axis, [0, 0, 1], atol=1e-9)
    offset = np.abs(grid.centres_m - CENTRE)
    inside = (offset[..., 0] < 0.2 - 0.02) & (offset[..., 2] < 0.15 - 0.02)
    outside = (offset[..., 0] > 0.2 + 0.02) | (offset[..., 2] > 0.15 + 0.02)
    assert inside.sum() > 100 and outside.sum() > 50
    np.testing.assert_allclose(grid.pressure_kpa[inside], p / 1e3, rtol=1e-6)
    assert (grid.pressure_kpa[outside] == 0).all()
    # without areas, point loads: the same total
    assert pressure_grid(contact, *seat).normal_load_n == pytest.approx(MASS * G)



def test_skin_gathered_onto_fewer_cells_reads_its_own_pressure_and_keeps_its_load(seat):
    """The box's skin, its vertices drawn halfway in towards its middle (as the closest points
    of skin sunk into a hollow crowd), lands on a quarter of the cells it covers flat: those
    cells read the skin's pressure m g / A, not four times it, each as pressed taking four
    times its area on the surface, and the cells carry the whole load."""
    points, areas, _ = _box()
    p = MASS * G / AREA
    gathered = CENTRE + 0.5 * (points - CENTRE)
    contact = _contact("seat", gathered, p * areas, seat)
    grid = pressure_grid(contact, *seat, areas)
    assert grid.normal_load_n == pytest.approx(MASS * G, rel=1e-9)
    offset = np.abs(grid.centres_m - CENTRE)
    inside = (offset[..., 0] < 0.1 - 0.02) & (offset[..., 2] < 0.075 - 0.02)
    assert inside.sum() > 20
    np.testing.assert_allclose(grid.pressure_kpa[inside], p / 1e3, rtol=1e-6)
    assert grid.pressure_kpa.max() <= p / 1e3 * (1 + 1e-9)
    flat = pressure_grid(_contact("seat", points, p * areas, seat), *seat, areas)
    np.testing.assert_allclose(np.median(grid.cell_area_m2[inside]),
                               4 * np.median(flat.cell_area_m2[flat.pressure_kpa > 0]), rtol=0.05)

def test_draped_cells_tile_a_curved_surface_exactly():
    """Quads split into many cells each (about 7 x 7) on a bumpy surface: the cells' areas add up
    to the surface's, and a load anywhere stays whole."""
    v, q = grid_mesh((1.2, 0.8), (8, 6), 0.45)
    s = subdivision(len(v), q, 2)
    vertices = s.apply(v)
    vertices[:, 1] += 0.05 * np.sin(4 * vertices[:, 0]) * np.cos(3 * vertices[:, 2])
    rng = np.random.default_rng(3)
    probe = np.c_[rng.uniform(-0.5, 0.5, 300), np.full(300, 0.5), rng.uniform(-0.3, 0.3, 300)]
    contact = _contact("seat", probe, rng.uniform(0, 2, 300), (vertices, s.faces))
    grid = pressure_grid(contact, vertices, s.faces, cell_m=0.0055, margin_m=10.0)
    surface_area = 0.5 * np.linalg.norm(np.cross(
        *(vertices[SurfaceMesh.from_quads(vertices, s.faces).triangles[:, k]]
          - vertices[SurfaceMesh.from_quads(vertices, s.faces).triangles[:, 0]]
          for k in (1, 2))), axis=1).sum()
    assert grid.cell_area_m2.sum() == pytest.approx(surface_area, rel=1e-9)
    rows, cols = sorted(grid.pressure_kpa.shape)
    assert rows % 24 == 0 and cols % 32 == 0 and rows // 24 >= 6 and cols // 32 >= 6
    assert grid.normal_load_n == pytest.approx(contact.normal_force.sum(), rel=1e-9)


def test_floor_map_is_an_xz_grid():
    foot = np.array([[0.105, 0.0, 0.305], [0.135, 0.0, 0.305], [0.105, 0.0, 0.415]])
    contact = _contact("floor", foot, np.array([10.0, 20.0, 30.0]))
    grid = pressure_grid(contact, cell_m=0.02, margin_m=0.015)
    assert not grid.draped
    np.testing.assert_allclose(grid.column_axis, [1, 0, 0])
    np.testing.assert_allclose(grid.row_axis, [0, 0, 1])
    assert grid.column_edges_m[0] == pytest.approx(0.08) and grid.row_edges_m[0] == \
        pytest.approx(0.28)
    assert grid.normal_load_n == pytest.approx(60.0)
    # the 30 N point at (0.105, 0.415) lands in the cell x 0.10..0.12, z 0.40..0.42
    r = np.searchsorted(grid.row_edges_m, 0.415) - 1
    c = np.searchsorted(grid.column_edges_m, 0.105) - 1
    assert grid.column_edges_m[c] == pytest.approx(0.10) and grid.row_edges_m[r] == \
        pytest.approx(0.40)
    assert grid.pressure_kpa[r, c] == pytest.approx(30.0 / 4e-4 / 1e3)


def test_csv_round_trips(tmp_path, seat):
    points, areas, _ = _box()
    grid = pressure_grid(_contact("seat", points, 2000 * areas, seat), *seat, areas)
    floor = pressure_grid(_contact("floor", points[:5] * [1, 0, 1], np.ones(5)))
    write_pressure_csv(tmp_path / "seat.csv", grid)
    text = (tmp_path / "seat.csv").read_text()
    assert "kPa" in text and "cm" in text
    back = np.loadtxt(tmp_path / "seat.csv", delimiter=",")
    np.testing.assert_allclose(back, grid.pressure_kpa, atol=1e-4)
    write_pressure_csv(tmp_path / "maps.csv", [grid, floor])
    maps = read_pressure_csv(tmp_path / "maps.csv")
    assert list(maps) == ["seat", "floor"]
    np.testing.assert_allclose(maps["floor"], floor.pressure_kpa, atol=1e-4)


def test_render_pressure_maps(tmp_path, seat):
    from PIL import Image

    from solver.io.render import MapPanel, render_pressure_maps

    points, areas, _ = _box()
    grid = pressure_grid(_contact("seat", points, 2000 * areas, seat), *seat, areas)
    path = render_pressure_maps(tmp_path / "maps.png", [
        grid, MapPanel(np.zeros((0, 0)), np.zeros(1), np.zeros(1), "back")], columns=2,
        panel_size=(200, 220))
    with Image.open(path) as im:
        assert im.size == (500, 230)


def test_draped_cells_measure_each_half_of_an_uneven_quad():
    """One trapezoid quad whose triangles differ in area by more than half: a uniform load laid
    on it finely, triangle by triangle, reads the same pressure in every cell."""
    quad = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1], [0.1, 0.0, 0.05], [0.1, 0.0, 0.0]])
    faces = np.array([[0, 1, 2, 3]])
    area = [0.5 * np.linalg.norm(np.cross(quad[b] - quad[0], quad[c] - quad[0]))
            for b, c in ((1, 2), (2, 3))]
    assert area[0] / area[1] > 1.5
    n = 240
    a, b = (g.ravel() for g in np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n))
    first = b <= a  # the half that triangle (0, 1, 2) maps onto
    points = np.where(first[:, None], quad[0] + a[:, None] * (quad[1] - quad[0])
                      + b[:, None] * (quad[2] - quad[1]),
                      quad[0] + b[:, None] * (quad[3] - quad[0])
                      + a[:, None] * (quad[2] - quad[3]))
    pressure = 3000.0
    force = pressure * np.where(first, 2 * area[0], 2 * area[1]) / n**2
    contact = SupportContact("seat", np.arange(n * n), force, np.zeros((n * n, 3)),
                             np.tile([0.0, 1.0, 0.0], (n * n, 1)), points,
                             np.where(first, 0, 1))
    grid = pressure_grid(contact, quad, faces, cell_m=0.025, margin_m=1.0)
    assert sorted(grid.pressure_kpa.shape) == [3, 5]  # 7.5 and 10.6 cm median sides
    np.testing.assert_allclose(grid.pressure_kpa, pressure / 1e3, rtol=0.02)
