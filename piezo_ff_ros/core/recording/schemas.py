"""Message definitions and type hashes as rosbag2 builds them, and the names of the recorded topic contract.

``ros2msg_definition`` builds the full schema text like rosbag2's ``LocalMessageDefinitionSource`` from the ``.msg``
files shipped with the ROS wheels (dependencies appended, sorted, depth-first, each once); ``type_hash`` is the
RIHS01 hash rosbag2 stores per channel.
"""
from __future__ import annotations

import json
import os
import re
import sys
from functools import lru_cache
from pathlib import Path

__all__ = ["METADATA_NAME", "BLOCK_ROLES", "EXPERIMENT_TYPE", "DIAGNOSTICS_TYPE", "ros2msg_definition", "type_hash"]


METADATA_NAME = "piezo_ff_ros"  #: name of the MCAP Metadata record holding the run configuration
BLOCK_ROLES = ("reference", "voltage", "displacement")  #: block topics by their last name component
EXPERIMENT_TYPE = "std_msgs/msg/String"
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
               "int64", "uint64", "string", "wstring"}
# rosbag2's MSG_FIELD_TYPE_REGEX (rosbag2_storage_mcap/message_definition_encoding): the type of each field line
_FIELD_TYPE_RE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:<=[0-9]+)?(?:\[[^\]]*\])?\s+")
_DELIMITER = "=" * 80


# ----------------------------------------------------------------------------------------------------------------
# schema text and type hash, as rosbag2 builds them

def _share_dirs() -> list[Path]:
    dirs = [Path(sys.prefix) / "share"]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / "share")
    return dirs


def _split_type(type_name: str) -> tuple[str, str]:
    parts = type_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError(f"{type_name!r}: not a message type name (expected 'pkg/msg/Type')")


def _interface_file(type_name: str, suffix: str) -> Path | None:
    pkg, name = _split_type(type_name)
    for share in _share_dirs():
        p = share / pkg / "msg" / f"{name}{suffix}"
        if p.is_file():
            return p
    return None


@lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    p = _interface_file(type_name, ".msg")
    if p is not None:
        return p.read_text()
    # not installed as a ROS package here: fall back to rosbags' canonical text for the standard types
    from .blocks import typestore

    ts = typestore()
    full = f"{_split_type(type_name)[0]}/msg/{_split_type(type_name)[1]}"
    if full not in ts.types:
        raise ValueError(f"{type_name}: no .msg file under {[str(d) for d in _share_dirs()]} and not a known type")
    return str(ts.generate_msgdef(full, ros_version=2)[0].split("\n" + _DELIMITER)[0])


def _msg_dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for match in _FIELD_TYPE_RE.finditer(text):
        t = match.group(1)
        if t in _PRIMITIVES:
            continue
        deps.add(t if "/" in t else f"{package}/{t}")
    return sorted(deps)


@lru_cache(maxsize=None)
def ros2msg_definition(type_name: str) -> str:
    """Full ``ros2msg`` schema text of ``type_name``, as rosbag2's ``LocalMessageDefinitionSource`` builds it.

    The type's ``.msg`` text, then for each dependency (sorted, depth-first, each once)
    ``"\\n" + "="*80 + "\\nMSG: pkg/Type\\n" + <its .msg text>``.
    """
    pkg, name = _split_type(type_name)
    seen: set[str] = set()

    def append(dep_pkg: str, dep_name: str) -> str:
        text = _msg_text(f"{dep_pkg}/msg/{dep_name}")
        out = text
        for dep in _msg_dependencies(text, dep_pkg):
            if dep not in seen:
                seen.add(dep)
                dpkg, dname = _split_type(dep)
                out += f"\n{_DELIMITER}\nMSG: {dpkg}/{dname}\n" + append(dpkg, dname)
        return out

    return append(pkg, name)


@lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """The type's RIHS01 hash (``RIHS01_…``) from the wheel's ``<Type>.json`` (else computed by rosbags)."""
    p = _interface_file(type_name, ".json")
    if p is not None:
        return str(json.loads(p.read_text())["type_hashes"][0]["hash_string"])
    from .blocks import typestore

    pkg, name = _split_type(type_name)
    return str(typestore().hash_rihs01(f"{pkg}/msg/{name}"))
