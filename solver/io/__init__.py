"""Files and pictures: mesh files (OBJ, PLY, GLB) in a stated unit and up axis, Rhino
documents (.3dm, through rhino3dm) and headless renderings.

Depends on `solver.mesh` only; never on `solver.scene` or the CLI.
"""
