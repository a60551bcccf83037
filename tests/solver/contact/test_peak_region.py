"""The region of the surface's peak pressure: where the highest skin pressure from the surface
(not the floor) lies."""

import numpy as np

from solver.body.model import BODY_REGIONS
from solver.contact.evaluate import peak_region, skin_pressure
from solver.contact.mat import SupportContact
from solver.contact.settle import Settled


def _contact(name: str, vertices, forces, face: int) -> SupportContact:
    k = len(vertices)
    return SupportContact(name, np.array(vertices), np.array(forces, dtype=float),
                          np.zeros((k, 3)), np.tile([0.0, 1.0, 0.0], (k, 1)), np.zeros((k, 3)),
                          np.full(k, face), areas=np.full(k, 1e-3))


def _settled(stable: bool = True) -> Settled:
    """Four vertices: 0 and 1 on the seat (10 N and 30 N over 10 cm^2: 10 and 30 kPa), 1 also
    on the back (10 N more), 3 on the floor (100 N: 100 kPa)."""
    contacts = [_contact("seat", [0, 1], [10.0, 30.0], 0),
                _contact("back", [1], [10.0], 1),
                _contact("floor", [3], [100.0], -1)]
    z = np.zeros(3)
    return Settled(stable, None if stable else "tips over", np.zeros((4, 3)), z, z, z,
                   contacts, z, z, 150.0)


REGIONS = np.array([BODY_REGIONS.index(r) for r in ("pelvis", "thighs", "calves", "feet")])


def test_the_surface_s_pressure_leaves_the_floor_out():
    """Vertex 1 carries 40 N over its 20 cm^2 on seat and back (20 kPa), vertex 0 10 kPa; the
    floor's 100 kPa under vertex 3 counts only when all supports are asked for."""
    settled = _settled()
    surface = skin_pressure(settled, 4, ("seat", "back", "leg rest"))
    assert np.allclose(surface, [10.0, 20.0, 0.0, 0.0])
    assert np.allclose(skin_pressure(settled, 4), [10.0, 20.0, 0.0, 100.0])


def test_the_peak_region_is_the_surface_peak_s_not_the_floor_s():
    assert peak_region(_settled(), REGIONS) == "thighs"


def test_no_region_without_regions_or_without_rest():
    assert peak_region(_settled(), None) is None
    assert peak_region(_settled(stable=False), REGIONS) is None
