"""The named camera views of the pictures (solver.io.render); this module imports nothing, so
that the command line offers them without loading matplotlib or numpy."""

VIEWS = {
    # direction from the scene towards the camera (Y up, bodies face +Z)
    "front": (0.0, 0.15, 1.0),
    "side": (1.0, 0.15, 0.0),
    "three-quarter": (0.8, 0.45, 1.0),
    "top": (0.0, 1.0, 0.05),
    "back": (0.3, 0.2, -1.0),
    "below": (0.0, -1.0, -0.45),
}
