"""Safe ROS 2 environment defaults for every process this project starts (tests, demo launcher, commissioning).

- ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``: without it DDS discovery multicasts out of the machine
  (``ROS_LOCALHOST_ONLY`` is ignored by the Kilted wheels).
- ``ROS_DOMAIN_ID``: a per-run domain so that parallel runs do not cross-talk.
- ``ROS_LOG_DIR``: rcl's log files in a temp dir instead of ``~/.ros/log``.
Imports nothing from ROS.
"""
from __future__ import annotations

import os
import tempfile


def apply_ros_env_defaults(domain_id: int | None = None, env: dict | None = None, force_domain: bool = False) -> dict:
    """Set the defaults in ``env`` (default ``os.environ``) where unset; returns that mapping."""
    env = os.environ if env is None else env
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # mandatory here, never left to the default
    if force_domain or "ROS_DOMAIN_ID" not in env:
        env["ROS_DOMAIN_ID"] = str(domain_id if domain_id is not None else 1 + os.getpid() % 100)
    if "ROS_LOG_DIR" not in env:
        env["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="piezo_ff_roslog_")
    return env
