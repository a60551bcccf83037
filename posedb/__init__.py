"""The HDF5 pose library: takes, poses, tags, live recording. Depends on `capture`.

One file holds the library (schema in `posedb.schema`); recordings in progress keep a journal in
`<library>.recordings/` until they become takes.

This module is the facade: the names a user calls, each loaded when first used (so that the
`sitrelax` command starts without numpy and h5py).
"""

from __future__ import annotations

import importlib
import sys
import types

_EXPORTS = {
    "posedb.library": ("DuplicateNameError", "Editor", "LockedError", "PoseInfo", "PoseLibrary",
                       "TakeData", "TakeInfo"),
    "posedb.record": ("record", "recordings", "recover"),
    "posedb.schema": ("SCHEMA_VERSION", "SUPPORT_PARTS", "LibraryError", "NotFoundError",
                      "SchemaError"),
    "posedb.suggest": ("HeldPosture", "held_postures"),
    "posedb.tags": ("TagError", "compile_expression"),
}
_HOME = {name: module for module, names in _EXPORTS.items() for name in names}
__all__ = sorted(_HOME)


def __getattr__(name: str):
    module = _HOME.get(name)
    if module is None:
        raise AttributeError(f"module 'posedb' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _Facade(types.ModuleType):
    """`posedb.record` is the function: importing the submodule of that name must not bind it
    over the function (as the eager `from .record import record` used to ensure)."""

    def __setattr__(self, name: str, value) -> None:
        if name in _HOME and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Facade
