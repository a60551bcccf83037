"""Files and pictures: mesh files (OBJ, PLY, GLB) and headless renderings.

Depends on `solver.mesh` only; never on `solver.scene` or the CLI.
"""
