"""MCAP in the rosbag2 format, without ROS: the recorder's writer and the replay reader (one import for both).

The code lives in focused modules, re-exported here so ``from piezo_ff_ros.core.recording.mcap_io import …`` keeps
working:

- :mod:`.schemas`: message definitions (``ros2msg``) and RIHS01 type hashes as rosbag2 builds them, topic names;
- :mod:`.qos`: offered QoS profiles in rosbag2's v9 YAML form;
- :mod:`.mcap_writer`: :class:`McapRecorder` (rosbag2-profile MCAP from raw CDR, crash-tolerant chunks);
- :mod:`.mcap_scan`: :func:`scan_mcap` / :func:`iter_mcap_records` (every readable record, damage accounted);
- :mod:`.mcap_reader`: :func:`read_run` (block topics → sample-aligned :class:`~.run.RunData`).
"""
from __future__ import annotations

from .mcap_reader import read_run
from .mcap_scan import McapContents, iter_mcap_records, scan_mcap
from .mcap_writer import McapRecorder, RecordingStopped
from .qos import block_qos_profile, qos_profiles_yaml
from .schemas import BLOCK_ROLES, METADATA_NAME, ros2msg_definition, type_hash

__all__ = [
    "METADATA_NAME", "BLOCK_ROLES", "ros2msg_definition", "type_hash", "qos_profiles_yaml", "block_qos_profile",
    "McapRecorder", "RecordingStopped", "McapContents", "scan_mcap", "iter_mcap_records", "read_run",
]
