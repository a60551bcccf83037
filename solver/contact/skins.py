"""The search structures of a closed skin, built once per skin and kept: its fast winding number
tree (inside tests), its bounding-box tree (closest points) and the k-d tree of its vertices
(nearest vertices).

A scene's placement (which skin a support can reach), its evaluation (where a surface cuts into
the body, how deep) and the fit's guarantees (the dense penetration) all ask about the same
posed bodies; the structures are kept by the skin's content, so each is built once however
many of them ask.
"""

from __future__ import annotations

import numpy as np

import solver.threads  # noqa: F401  (libigl's thread count, set before libigl first runs)
from solver.kept import KeptByContent

KEPT_SKINS = 16  # skins whose structures are kept (a scene of several people asks for each)
_SKINS = KeptByContent(KEPT_SKINS)


def _kept(vertices: np.ndarray, triangles: np.ndarray | None) -> dict:
    """The structures kept for a skin (vertices (V, 3) float64, triangles (F, 3) int64 or None
    for the vertices alone), by content."""
    return _SKINS.entry(vertices, triangles)


def _skin_tree(vertices: np.ndarray, triangles: np.ndarray, kind: str):
    """libigl's `kind` tree ("FastWindingNumberBVH" or "AABB") of the closed skin, built on
    first use and kept."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    kept = _kept(v, t)
    if kind not in kept:
        import igl

        tree = getattr(igl, kind)()
        tree.init(v, t)
        kept[kind] = tree
    return kept[kind]


def body_winding(vertices: np.ndarray, triangles: np.ndarray):
    """The closed skin's fast winding number tree (libigl's `FastWindingNumberBVH`, the same
    numbers as `igl.fast_winding_number`), built on first use and kept. vertices (V, 3) m,
    triangles (F, 3)."""
    return _skin_tree(vertices, triangles, "FastWindingNumberBVH")


def body_closest(vertices: np.ndarray, triangles: np.ndarray):
    """The closed skin's bounding-box tree (libigl's `AABB`, for closest points), built on
    first use and kept. vertices (V, 3) m, triangles (F, 3); query it with the same arrays."""
    return _skin_tree(vertices, triangles, "AABB")


def vertex_tree(vertices: np.ndarray):
    """A k-d tree of the vertices (V, 3) (scipy's cKDTree, on its own copy of them), built on
    first use and kept."""
    v = np.asarray(vertices, dtype=np.float64)
    kept = _kept(v, None)
    if "tree" not in kept:
        from scipy.spatial import cKDTree

        kept["tree"] = cKDTree(v, copy_data=True)
    return kept["tree"]
