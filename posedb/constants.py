"""The pose library's names and defaults that the command line shows before any work is loaded
(this module imports nothing, so that `sitrelax --help` starts without numpy and h5py)."""

# the body regions a support names, and the defaults per use, are `posedb.regions`'s

# held-posture detection (posedb.suggest)
DEFAULT_MAX_SPEED = 0.2  # m/s: settling and fidgeting while seated stay under it; walking ~1 m/s
DEFAULT_MIN_DURATION = 0.5  # s
MAX_HOLD_DURATION = 86_400.0  # s: the longest min_duration asked for (a day: no take is longer)
