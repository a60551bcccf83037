"""Names the command line offers before any work is loaded (this module imports nothing, so
that `sitrelax --help` starts without numpy)."""

FORMATS = ("binary", "binary-old", "string")  # the Perception Neuron stream formats (capture.neuron)
