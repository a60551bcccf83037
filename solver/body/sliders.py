"""The body model's shape sliders (MakeHuman's macro modifiers, each in [0, 1]); this module
imports nothing, so that the command line builds its options without loading the model."""

SHAPE_KEYS = ("gender", "age", "muscle", "weight", "height", "proportions")
