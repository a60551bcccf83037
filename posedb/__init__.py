"""The HDF5 pose library: takes, poses, tags, live recording. Depends on `capture`.

One file holds the library (schema in `posedb.schema`); recordings in progress keep a journal in
`<library>.recordings/` until they become takes.
"""

from .library import (
    DuplicateNameError,
    Editor,
    LockedError,
    PoseInfo,
    PoseLibrary,
    TakeData,
    TakeInfo,
)
from .record import record, recordings, recover
from .schema import (
    SCHEMA_VERSION,
    SUPPORT_PARTS,
    LibraryError,
    NotFoundError,
    SchemaError,
)
from .suggest import HeldPosture, held_postures
from .tags import TagError, compile_expression

__all__ = [
    "DuplicateNameError",
    "Editor",
    "HeldPosture",
    "LibraryError",
    "LockedError",
    "NotFoundError",
    "PoseInfo",
    "PoseLibrary",
    "SCHEMA_VERSION",
    "SUPPORT_PARTS",
    "SchemaError",
    "TagError",
    "TakeData",
    "TakeInfo",
    "compile_expression",
    "held_postures",
    "record",
    "recordings",
    "recover",
]
