"""Contact between bodies and surfaces: where a body needs support (the pressure model and its
importance), how a surface carries it (the evaluation, like a pressure mat), and the physical
references that check the model.

Depends on `solver.mesh` and `solver.body`; never on `solver.surface`, `solver.scene`,
`solver.io` or the CLI.
"""
