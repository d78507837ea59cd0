"""Config files: where the packaged default is, a YAML loader that refuses duplicate keys, flat dotted dicts.

:func:`load_config` reads a YAML file (default: :func:`default_config_path`, the paper's PT230.94 values, found in
the source tree or in an installed ``share/piezo_ff_ros/config``) with :class:`UniqueKeyLoader` and hands it to
:meth:`~.piezo.PiezoConfig.from_dict`; every failure is a :class:`~.validation.ConfigError` naming the file.
:func:`flatten` / :func:`unflatten` convert between nested and dotted-key dicts.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import yaml

from .piezo import PiezoConfig
from .validation import ConfigError

__all__ = ["load_config", "default_config_path", "DuplicateKeyError", "UniqueKeyLoader", "flatten", "unflatten"]


def default_config_path() -> Path:
    """``config/pt230_94.yaml``: in the source tree, or installed under ``share/piezo_ff_ros/config``."""
    here = Path(__file__).resolve()
    candidates = [here.parents[3] / "config" / "pt230_94.yaml"]  # source tree (<root>/piezo_ff_ros/core/config/)
    import sys

    candidates.append(Path(sys.prefix) / "share" / "piezo_ff_ros" / "config" / "pt230_94.yaml")
    try:  # a colcon/ROS install
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory("piezo_ff_ros")) / "config" / "pt230_94.yaml")
    except Exception:  # noqa: BLE001 - ament index absent or package not registered
        pass
    for c in candidates:
        if c.is_file():
            return c
    raise FileNotFoundError("config/pt230_94.yaml not found (looked in: " + ", ".join(map(str, candidates)) + ")")


class DuplicateKeyError(ValueError):
    """A YAML mapping holds the same key twice (``line`` is 1-based)."""

    def __init__(self, key: Any, line: int) -> None:
        super().__init__(f"line {line}: duplicate key {key!r}")
        self.key, self.line = key, line


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate keys (the plain loader keeps the last value, silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        """The mapping of ``node``; :class:`DuplicateKeyError` on a repeated key."""
        self.flatten_mapping(node)
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                dup = key in seen
            except TypeError:  # an unhashable key: let the base class report it
                break
            if dup:
                raise DuplicateKeyError(key, key_node.start_mark.line + 1)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def load_config(path: str | Path | None = None, variant: str | None = None) -> PiezoConfig:
    """Load and validate a positioner config (default: the paper's PT230.94 values as printed)."""
    p = Path(path) if path is not None else default_config_path()
    if p.is_dir():
        raise ConfigError(str(p), "is a directory, not a YAML config file")
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such config file")
    try:
        data = yaml.load(p.read_text(), Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except DuplicateKeyError as exc:
        raise ConfigError(str(p), f"line {exc.line}: duplicate key {exc.key!r} (YAML would silently keep the "
                                  "last value)") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(str(p), f"not a text (YAML) file ({exc.reason} at byte {exc.start})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(str(p), f"not valid YAML ({exc})") from None
    if not isinstance(data, Mapping):
        raise ConfigError(str(p), "top level must be a mapping")
    return PiezoConfig.from_dict(data, variant=variant)


def flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{'a': {'b': 1}}`` → ``{'a.b': 1}`` (lists are leaves)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, Mapping):
            out.update(flatten(v, key))
        else:
            out[key] = v
    return out


def unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    """``{'a.b': 1}`` → ``{'a': {'b': 1}}`` (the inverse of :func:`flatten`)."""
    out: dict[str, Any] = {}
    for key, v in flat.items():
        cur = out
        parts = key.split(".")
        for p in parts[:-1]:
            cur = cur.setdefault(p, {})
        cur[parts[-1]] = v
    return out
