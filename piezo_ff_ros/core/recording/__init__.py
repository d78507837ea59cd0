"""Recorded runs: the in-memory :class:`RunData`, and readers/writers (MCAP of our topic contract, CSV, .mat)."""
from .run import RunData, load_run  # noqa: F401
