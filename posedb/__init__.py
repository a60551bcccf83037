"""The HDF5 pose library: takes, poses, tags, live recording. Depends on `capture`.

One file holds the library (schema in `posedb.schema`); recordings in progress keep a journal in
`<library>.recordings/` until they become takes.

This module is the facade: the names a user calls, each loaded when first used (so that the
`sitrelax` command starts without numpy and h5py).
"""

from __future__ import annotations

from capture.lazy import lazy_exports
import sys
import types

_EXPORTS = {
    "posedb.library": ("DuplicateNameError", "Editor", "LockedError", "PoseInfo", "PoseLibrary",
                       "PosePlacement", "TakeData", "TakeInfo"),
    "posedb.record": ("TakeRecorder", "record", "recordings", "recover"),
    "posedb.regions": ("BODY_REGIONS", "DEFAULT_SUPPORT", "SUPPORT_USES", "SupportNameError",
                       "support_regions"),
    "posedb.schema": ("SCHEMA_VERSION", "LibraryError", "NotFoundError", "SchemaError"),
    "posedb.suggest": ("HeldPosture", "held_postures"),
    "posedb.tags": ("TagError", "compile_expression"),
}
__all__, _HOME, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())


class _Facade(types.ModuleType):
    """`posedb.record` is the function: importing the submodule of that name must not bind it
    over the function (as the eager `from .record import record` used to ensure)."""

    def __setattr__(self, name: str, value) -> None:
        if name in _HOME and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Facade
