"""Length units of motion-capture files, and how to name them.

The library works in metres. A BVH file stores lengths in whatever unit its exporter chose, so a
file's unit is recorded as *metres per file unit* and applied when metric values are derived.
Perception Neuron (Axis Neuron and Axis Studio) writes centimetres; the CMU BVH conversion uses
1 unit = 0.056444 m (inches scaled by 1/0.45).
"""

from __future__ import annotations

import math

#: Metres per file unit for the unit names accepted everywhere a unit is asked for.
UNITS: dict[str, float] = {
    "m": 1.0,
    "dm": 0.1,
    "cm": 0.01,
    "mm": 0.001,
    "in": 0.0254,
    "cmu": 0.056444,
}


MIN_UNIT, MAX_UNIT = 1e-6, 1e3  # metres per file unit: a micrometre to a kilometre


class UnitError(ValueError):
    """A length unit that is neither a known name nor a positive number."""


def resolve_unit(unit: str | float) -> float:
    """Metres per file unit for a unit name (see `UNITS`) or a positive number.

    >>> resolve_unit("cm")
    0.01
    """
    if isinstance(unit, str):
        key = unit.strip().lower()
        if key in UNITS:
            return UNITS[key]
        try:
            value = float(key)
        except ValueError:
            raise UnitError(
                f"Expected a length unit ({', '.join(UNITS)}) or metres per unit as a number, "
                f"got {unit!r}"
            ) from None
    else:
        value = float(unit)
    if not (math.isfinite(value) and MIN_UNIT <= value <= MAX_UNIT):
        raise UnitError(f"Expected a positive, finite number of metres per unit "
                        f"({MIN_UNIT:g}..{MAX_UNIT:g}), got {unit!r}")
    return value
