"""Body model, pressure, Catmull-Clark fitting, relaxation, evaluation and export.

Depends on `capture` and `posedb`. For now it holds the `sitrelax` command and the benchmark
runner; the solving stages arrive with their issues.
"""
