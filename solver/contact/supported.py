"""A body as a support sees it: the posed skin, where it needs support and how much it weighs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class SupportedBody:
    """A posed body to be supported, as the fit, the evaluation and the relaxation see it.

    vertices : (V, 3) float, metres, in the scene.
    normals : (V, 3) float, unit outward normals.
    importance : (V,) float in [0, 1], the pressure model's rho (zero outside the supported
        parts and where no support can reach).
    label : the name messages use.
    triangles : (F, 3) int, the closed skin (needed by the evaluation and the fit's inside tests).
    areas : (V,) float, m^2, Voronoi areas (needed by the evaluation).
    supported : (V,) bool, the body regions the surface is asked to support (all when None).
    mass_kg : the body's mass (needed by the evaluation).
    regions : (V,) int, optional, each vertex's body region (`solver.body.model.BODY_REGIONS`),
        for the evaluation's figures per region.
    orientation : (3, 3) float, optional, the body's left, up and forward directions as
        columns (how the evaluation names halves: front/back, left/right).
    """

    vertices: np.ndarray
    normals: np.ndarray
    importance: np.ndarray
    label: str = "person"
    triangles: np.ndarray | None = None
    areas: np.ndarray | None = None
    supported: np.ndarray | None = None
    mass_kg: float | None = None
    regions: np.ndarray | None = None
    orientation: np.ndarray | None = None
