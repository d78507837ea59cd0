"""Config files: where the packaged default is, a YAML loader that refuses duplicate keys, flat dotted dicts.

Every YAML text the package parses from a file, a parameter or a message goes through :func:`safe_yaml` (or
:func:`load_config`, which uses it): a ``yaml.SafeLoader`` that refuses duplicate keys and, before any work is done on
the document, a text larger than :data:`YAML_MAX_BYTES`, nesting deeper than :data:`YAML_MAX_DEPTH` levels and
more than :data:`YAML_MAX_NODES` nodes once every alias is expanded (an "alias bomb" of a few hundred characters
expands to billions) — each a one-line :class:`~.validation.ConfigError` naming the input, never a crash or a
stall.

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

__all__ = ["load_config", "default_config_path", "DuplicateKeyError", "UniqueKeyLoader", "YamlLimitError",
           "safe_yaml", "YAML_MAX_BYTES", "YAML_MAX_DEPTH", "YAML_MAX_NODES", "flatten", "unflatten"]

#: the largest YAML text parsed [bytes of UTF-8]: a configuration is a few kB, the paper's about 4 kB
YAML_MAX_BYTES = 1 << 20
#: the deepest nesting of mappings/sequences accepted (a configuration nests 5 levels)
YAML_MAX_DEPTH = 64
#: the most nodes a document may have with every alias expanded (the paper's configuration: about 600)
YAML_MAX_NODES = 100_000


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


class YamlLimitError(yaml.YAMLError):
    """A YAML document beyond :data:`YAML_MAX_DEPTH` or :data:`YAML_MAX_NODES` (the text says which)."""


class _LimitedLoader(UniqueKeyLoader):
    """:class:`UniqueKeyLoader` that counts, while composing, the nesting depth and the nodes with every alias
    expanded, and stops at the limits (before anything is constructed: an alias bomb costs nothing)."""

    max_depth = YAML_MAX_DEPTH
    max_nodes = YAML_MAX_NODES

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0
        self._expanded = 0
        self._sizes: dict[int, int] = {}

    def compose_node(self, parent: Any, index: Any) -> Any:  # noqa: D102 - PyYAML's composer hook
        from yaml.events import AliasEvent

        if self.check_event(AliasEvent):
            event = self.peek_event()  # type: ignore[no-untyped-call]  # PyYAML ships no annotations
            target = self.anchors.get(event.anchor)
            self._expanded += self._sizes.get(id(target), 1)
            self._check_nodes(event)
            return super().compose_node(parent, index)
        self._depth += 1
        if self._depth > self.max_depth:
            mark = self.peek_event().start_mark  # type: ignore[no-untyped-call]  # PyYAML ships no annotations
            raise YamlLimitError(f"nested deeper than {self.max_depth} levels (line {mark.line + 1})")
        before = self._expanded
        self._expanded += 1
        self._check_nodes(self.peek_event())  # type: ignore[no-untyped-call]  # PyYAML ships no annotations
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        self._sizes[id(node)] = self._expanded - before
        return node

    def _check_nodes(self, event: Any) -> None:
        if self._expanded > self.max_nodes:
            raise YamlLimitError(f"more than {self.max_nodes} nodes with its aliases expanded (line "
                                 f"{event.start_mark.line + 1}): an alias bomb?")


def safe_yaml(text: str | bytes, name: str, max_bytes: int = YAML_MAX_BYTES) -> Any:
    """Parse one YAML document safely: size, depth and alias-expansion limits first, duplicate keys refused.

    Parameters
    ----------
    text : str or bytes
        The YAML text.
    name : str
        What it is (a parameter's or a file's name): every refusal starts with it.
    max_bytes : int
        Largest text accepted [bytes], checked before parsing.

    Returns
    -------
    Any
        The document (None for an empty one).

    Raises
    ------
    ConfigError
        ``<name>: …`` one line: too large, too deep, too many nodes, a duplicate key, not YAML.
    """
    size = len(text.encode("utf-8", "surrogatepass")) if isinstance(text, str) else len(text)
    if size > max_bytes:
        raise ConfigError(name, f"{size} bytes of YAML, more than the {max_bytes} accepted")
    try:
        return yaml.load(text, Loader=_LimitedLoader)  # noqa: S506 - a SafeLoader subclass
    except DuplicateKeyError as exc:
        raise ConfigError(name, f"line {exc.line}: duplicate key {exc.key!r} (YAML would silently keep the "
                                "last value)") from None
    except YamlLimitError as exc:
        raise ConfigError(name, f"YAML {exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(name, f"not a text (YAML) file ({exc.reason} at byte {exc.start})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(name, f"not valid YAML ({' '.join(str(exc).split())[:300]})") from None
    except RecursionError:   # a construct the limits above did not foresee: still one line, never a crash
        raise ConfigError(name, "YAML nested too deeply") from None


def load_config(path: str | Path | None = None, variant: str | None = None) -> PiezoConfig:
    """Load and validate a positioner config (default: the paper's PT230.94 values as printed)."""
    p = Path(path) if path is not None else default_config_path()
    if p.is_dir():
        raise ConfigError(str(p), "is a directory, not a YAML config file")
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such config file")
    size = p.stat().st_size
    if size > YAML_MAX_BYTES:   # before reading it
        raise ConfigError(str(p), f"{size} bytes, more than the {YAML_MAX_BYTES} a config file may have")
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(str(p), f"not a text (YAML) file ({exc.reason} at byte {exc.start})") from None
    data = safe_yaml(text, str(p))
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
