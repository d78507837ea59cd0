"""Safe ROS 2 environment defaults for every process this project starts (tests, demo launcher, commissioning).

- ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``: without it DDS discovery multicasts out of the machine
  (``ROS_LOCALHOST_ONLY`` is ignored by the Kilted wheels).
- ``ROS_DOMAIN_ID``: a per-run domain so that parallel runs do not cross-talk.
- ``ROS_LOG_DIR``: rcl's log files in a temp dir instead of ``~/.ros/log``.
Imports nothing from ROS.
"""
from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path
from typing import IO, MutableMapping

#: the domains this process claimed (their lock files stay open, i.e. held, until it exits)
_HELD: list[IO[str]] = []


def claim_ros_domain(first: int = 1, last: int = 100) -> tuple[int, IO[str]]:
    """A ROS domain no other test session, benchmark or demo of this project holds: the first in ``first…last``
    whose lock file (``$TMPDIR/piezo_ff_test_domain_<id>.lock``) can be ``flock``-ed; held while the returned file
    stays open.

    Returns
    -------
    domain : int
        The domain id.
    lock : file
        Keep it open for as long as the domain is used.
    """
    start = os.getpid() % (last - first + 1)
    for i in range(last - first + 1):
        domain = first + (start + i) % (last - first + 1)
        f = open(Path(tempfile.gettempdir()) / f"piezo_ff_test_domain_{domain}.lock", "a")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        return domain, f
    raise RuntimeError(f"no free ROS domain in {first}…{last} (all held by other test sessions, benchmarks or "
                       "demos)")


def apply_ros_env_defaults(domain_id: int | None = None, env: MutableMapping[str, str] | None = None,
                           force_domain: bool = False) -> MutableMapping[str, str]:
    """Set the defaults in ``env`` (default ``os.environ``) where unset; returns that mapping."""
    if env is None:
        env = os.environ
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # mandatory here, never left to the default
    if force_domain or "ROS_DOMAIN_ID" not in env:
        if domain_id is None:   # a free one, held for this process's lifetime (no other run of ours lands on it)
            domain_id, lock = claim_ros_domain()
            _HELD.append(lock)
        env["ROS_DOMAIN_ID"] = str(domain_id)
    if "ROS_LOG_DIR" not in env:
        env["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="piezo_ff_roslog_")
    return env
