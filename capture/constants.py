"""Names the command line offers before any work is loaded (this module imports nothing, so
that `sitrelax --help` starts without numpy)."""

# the Perception Neuron stream formats (capture.neuron)
FORMATS = ("binary", "binary-old", "string")
