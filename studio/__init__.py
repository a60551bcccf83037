"""The interactive layer on top of the solver: a local web studio and an HTTP API."""
