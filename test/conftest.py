"""Test-session defaults: ROS isolation env vars are set before anything can import rclpy.

Every test session gets its own ``ROS_DOMAIN_ID`` (from the PID, or ``PIEZO_FF_TEST_DOMAIN``), discovery restricted
to this machine, and rcl logs in a temp dir.  Data tests skip cleanly where ../shared/data is absent.
"""
from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ["ROS_DOMAIN_ID"] = os.environ.get("PIEZO_FF_TEST_DOMAIN", str(1 + os.getpid() % 100))
os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="piezo_ff_test_roslog_")

SHARED_DATA = Path(os.environ.get("PIEZO_FF_SHARED_DATA", ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA} (set PIEZO_FF_SHARED_DATA)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def paper_config():
    from piezo_ff_ros.core.config import load_config

    return load_config(ROOT / "config" / "pt230_94.yaml")


@pytest.fixture(scope="session")
def paper_design(paper_config):
    """The H∞ design on the printed G_L (synthesised once per session)."""
    from piezo_ff_ros.core.synthesis.hinf import synthesize_hinf

    return synthesize_hinf(paper_config.dynamics.G_L, paper_config.vibration)
