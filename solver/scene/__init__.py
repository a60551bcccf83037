"""Scenes: scenario files and their schema, people placed in a scene, and the pipelines that run
a fit or a relaxation from a scenario to its files (`sitrelax fit`, `relax`, `batch`, `demo`).

The orchestration layer: it may use every other layer of the solver.
"""
