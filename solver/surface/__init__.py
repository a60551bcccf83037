"""Surfaces: Catmull-Clark subdivision as sparse operators, its limit surface (limit masks, and a
regular grid's limit as a bicubic B-spline), and the constrained fit of a control mesh to the
bodies it supports (the fit's quadratic programme and its loop).

Depends on `solver.mesh`, `solver.body` and `solver.contact`; never on `solver.scene`,
`solver.io` or the CLI.
"""
