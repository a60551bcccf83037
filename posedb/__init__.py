"""The HDF5 pose database (takes, poses, tags, bodies, scenarios). Depends on `capture`."""
