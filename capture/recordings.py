"""Recordings bundled with the package (see `data/SOURCES.md` for origins and licences).

A bundled recording is named `bundled:FILE` wherever a BVH path is accepted, for example
`sitrelax bvh info bundled:cmu_75_18_high_sit.bvh`.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

BUNDLED_PREFIX = "bundled:"


def bundled_dir() -> Path:
    """The folder holding the bundled recordings."""
    return Path(str(resources.files("capture") / "data"))


def bundled_recordings() -> list[str]:
    """File names of the bundled BVH recordings."""
    return sorted(p.name for p in bundled_dir().glob("*.bvh"))


def resolve_path(spec: str) -> Path:
    """A filesystem path for a path or a `bundled:NAME` reference."""
    if spec.startswith(BUNDLED_PREFIX):
        name = spec[len(BUNDLED_PREFIX):]
        if name not in bundled_recordings():
            raise FileNotFoundError(
                f"No bundled recording {name!r}; bundled are {bundled_recordings()}"
            )
        return bundled_dir() / name
    return Path(spec)
