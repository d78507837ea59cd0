"""QoS profiles in rosbag2's v9 YAML string form (the ``offered_qos_profiles`` channel metadata)."""
from __future__ import annotations

from typing import Any, Iterable, Mapping

__all__ = ["block_qos_profile", "qos_profiles_yaml"]


_UNSPECIFIED = {"sec": 0, "nsec": 0}


def block_qos_profile(depth: int = 100) -> dict[str, Any]:
    """The contract's QoS for block topics (RELIABLE, KEEP_LAST ``depth``, VOLATILE), as a rosbag2 v9 dict."""
    return {"history": "keep_last", "depth": int(depth), "reliability": "reliable", "durability": "volatile",
            "deadline": dict(_UNSPECIFIED), "lifespan": dict(_UNSPECIFIED), "liveliness": "automatic",
            "liveliness_lease_duration": dict(_UNSPECIFIED), "avoid_ros_namespace_conventions": False}


def _policy_name(value: Any) -> str:
    if isinstance(value, str):
        return value.lower()
    name = getattr(value, "name", None)  # rclpy QoS*Policy enums
    if name is None:
        raise ValueError(f"QoS policy {value!r}: expected a name")
    return str(name).lower()


def _duration(value: Any) -> dict[str, int]:
    if value is None:
        return dict(_UNSPECIFIED)
    if isinstance(value, Mapping):
        return {"sec": int(value["sec"]), "nsec": int(value["nsec"])}
    ns = getattr(value, "nanoseconds", None)  # rclpy.duration.Duration
    if ns is None:
        ns = int(value)
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _qos_dict(profile: Any) -> dict[str, Any]:
    def get(key: str, default: Any = None) -> Any:
        return profile.get(key, default) if isinstance(profile, Mapping) else getattr(profile, key, default)

    return {
        "history": _policy_name(get("history", "keep_last")),
        "depth": int(get("depth", 0)),
        "reliability": _policy_name(get("reliability", "reliable")),
        "durability": _policy_name(get("durability", "volatile")),
        "deadline": _duration(get("deadline")),
        "lifespan": _duration(get("lifespan")),
        "liveliness": _policy_name(get("liveliness", "automatic")),
        "liveliness_lease_duration": _duration(get("liveliness_lease_duration")),
        "avoid_ros_namespace_conventions": bool(get("avoid_ros_namespace_conventions", False)),
    }


def qos_profiles_yaml(profiles: Iterable[Any] | None) -> str:
    """Offered QoS profiles (dicts or rclpy ``QoSProfile``-like objects) → rosbag2's v9 YAML string."""
    import yaml

    items = [_qos_dict(p) for p in (profiles or [])]
    return yaml.safe_dump(items, sort_keys=False, default_flow_style=False) if items else "[]"
