"""Mat-grade figures of a settled body's contacts (placeholder: the contact record only)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class SupportContact:
    """The contact of one body with one support after the settle."""

    name: str
    vertices: np.ndarray
    normal_force: np.ndarray
    tangential_force: np.ndarray
    normals: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    areas: np.ndarray  # (K,) m^2, the skin's footprint on the support at each contact
