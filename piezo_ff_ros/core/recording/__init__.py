"""Recorded runs: the in-memory :class:`RunData`, and readers/writers (MCAP of our topic contract, CSV, .mat).

The front door: :func:`load_run` reads any of them by its suffix.  The modules: :mod:`.run` (:class:`RunData`,
:func:`canonical_axes`), :mod:`.blocks` (the block message codec, stamps), :mod:`.schemas`, :mod:`.qos`,
:mod:`.mcap_writer`, :mod:`.mcap_scan`, :mod:`.mcap_reader`, :mod:`.recover` (MCAP in the rosbag2 format),
:mod:`.importers` (CSV, .mat).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .run import RunData

__all__ = ["RunData", "load_run"]


def load_run(path: str | Path, **kwargs: Any) -> RunData:
    """Load a run from ``.mcap`` (our topic contract), ``.csv`` (``t,u_x,u_y,x,y``) or ``.mat`` (``t``, ``u``, ``y``).

    Raises ``ValueError`` with a message that says what is wrong and where for malformed files.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    suffix = p.suffix.lower()
    if suffix == ".mcap" or p.is_dir():
        from .mcap_reader import read_run

        return read_run(p, **kwargs)
    if suffix == ".csv":
        from .importers import load_csv

        return load_csv(p, **kwargs)
    if suffix == ".mat":
        from .importers import load_mat

        return load_mat(p, **kwargs)
    raise ValueError(f"{p}: unknown format {suffix!r} (expected .mcap, .csv or .mat)")
