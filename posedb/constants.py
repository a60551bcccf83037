"""The pose library's names and defaults that the command line shows before any work is loaded
(this module imports nothing, so that `sitrelax --help` starts without numpy and h5py)."""

# bit k of a pose's `supports` names SUPPORT_PARTS[k]; "legs" is thighs and calves together
# (thighs and calves took the two spare bits of the uint8 within schema 1: older files never set
# them, so they read the same)
SUPPORT_PARTS = ("head", "torso", "arms", "hands", "legs", "feet", "thighs", "calves")

# held-posture detection (posedb.suggest)
DEFAULT_MAX_SPEED = 0.2  # m/s: settling and fidgeting while seated stay under it; walking ~1 m/s
DEFAULT_MIN_DURATION = 0.5  # s
