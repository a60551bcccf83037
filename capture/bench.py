"""Benchmark entries of the capture package, and the record every package uses to declare one.

Timing and reporting live in `solver.bench`; a package only says what to run and, where one
exists, what independent implementation to compare against.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .recordings import resolve_path


@dataclass(frozen=True)
class BenchCase:
    """One benchmark: `run` is timed; `baseline`, when given, is timed in the same session.

    setup : called once before any timing; returns the argument passed to run and baseline.
    """

    name: str
    description: str
    setup: Callable[[], object]
    run: Callable[[object], object]
    baseline: Callable[[object], object] | None = None
    baseline_name: str | None = None
    repeats: int = 15
    baseline_repeats: int = 3


AXIS_RECORDING = "bundled:axis_neuron_standing_yxz.bvh"


def _read_setup() -> str:
    return str(resolve_path(AXIS_RECORDING))


def _read(path: str):
    from .bvh import read_bvh

    return read_bvh(path)


def _bvhio_read(path: str):
    import bvhio

    return bvhio.readAsHierarchy(path)


def _fk_setup():
    from .bvh import read_bvh

    return read_bvh(_read_setup())


def _fk(bvh):
    return bvh.fk()


def cases() -> list[BenchCase]:
    return [
        BenchCase(
            "bvh_read",
            "parse the 17 s, 59-joint Axis Neuron recording (2,156 frames x 180 channels)",
            _read_setup, _read, _bvhio_read, "bvhio.readAsHierarchy",
        ),
        BenchCase(
            "bvh_fk",
            "world positions and rotations of all 59 joints in all 2,156 frames",
            _fk_setup, _fk,
        ),
    ]
