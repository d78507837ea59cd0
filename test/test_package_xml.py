"""package.xml declares, with a rosdep key, every third-party package the installed code imports at run time.

``rosdep install --from-paths src`` installs only what package.xml names: an import without a key there is an
ImportError at the first ``ros2 run`` of a workspace built that way.  The imports are read from the code (``import``
statements anywhere, ``importlib.import_module("literal")``), not from a list kept by hand.
"""
from __future__ import annotations

import ast
import functools
import sys
from pathlib import Path

import pytest
from catkin_pkg.package import parse_package

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "piezo_ff_ros"
#: never installed for a user's run: the benchmarks (``setup.py`` packages exclude them; ``bench`` in the tree)
EXCLUDED_DIRS = ("bench",)

#: import name → the rosdep key that installs it, and where the key comes from.  ROS packages are their own keys
#: (resolved by rosdep from the rosdistro's distribution.yaml); the others are keys of rosdistro's
#: ``rosdep/base.yaml`` or ``rosdep/python.yaml`` (``*-pip`` keys install the PyPI package with pip).
ROSDEP_KEYS = {
    # ROS 2 packages (distribution.yaml; pip wheels ros-<name> in requirements.txt)
    "rclpy": ("rclpy", "ROS package"),
    "std_msgs": ("std_msgs", "ROS package (common_interfaces)"),
    "geometry_msgs": ("geometry_msgs", "ROS package (common_interfaces)"),
    "sensor_msgs": ("sensor_msgs", "ROS package (common_interfaces)"),
    "std_srvs": ("std_srvs", "ROS package (common_interfaces)"),
    "diagnostic_msgs": ("diagnostic_msgs", "ROS package (common_interfaces)"),
    "rcl_interfaces": ("rcl_interfaces", "ROS package (rcl_interfaces)"),
    "lifecycle_msgs": ("lifecycle_msgs", "ROS package (rcl_interfaces)"),
    "builtin_interfaces": ("builtin_interfaces", "ROS package (rcl_interfaces)"),
    "ament_index_python": ("ament_index_python", "ROS package (ament_index)"),
    # system / pip keys
    "numpy": ("python3-numpy", "rosdep/python.yaml"),
    "scipy": ("python3-scipy", "rosdep/python.yaml"),
    "yaml": ("python3-yaml", "rosdep/python.yaml"),
    "matplotlib": ("python3-matplotlib", "rosdep/python.yaml"),
    "numba": ("python3-numba", "rosdep/python.yaml"),
    "control": ("python-control-pip", "rosdep/python.yaml (pip: control)"),
    "slycot": ("python-slycot-pip", "rosdep/python.yaml (pip: slycot)"),
    # the key of the ROS 2 MCAP decoder (pip: mcap-ros2-support), which brings `mcap` itself
    "mcap": ("mcap-ros2-support", "rosdep/python.yaml (pip: mcap-ros2-support → mcap)"),
    "mcap_ros2": ("mcap-ros2-support", "rosdep/python.yaml (pip: mcap-ros2-support)"),
    "rosbags": ("python3-rosbags-pip", "rosdep/python.yaml (pip: rosbags)"),
    # optional hardware library: declared with a condition (PIEZO_FF_WITH_PI=1), see docs/nodes.md
    "pipython": ("python3-pipython-pip", "rosdep/python.yaml (pip: pipython)"),
}
#: optional hardware libraries with no rosdep key: imported only when their backend is chosen, installed with the
#: pip extra named here (the backend's error says so when it is missing)
OPTIONAL_WITHOUT_KEY = {"nidaqmx": "pip install 'piezo_ff_ros[nidaqmx]' (and NI-DAQmx's runtime from NI)"}
#: optional libraries that package.xml declares only under a condition, so that plain `rosdep install` skips them
OPTIONAL_CONDITIONED = {"pipython": "$PIEZO_FF_WITH_PI == 1"}


@functools.lru_cache(maxsize=None)
def _third_party_imports() -> dict[str, set[str]]:
    """Top-level names of every non-stdlib module imported by the installed package → the files importing it
    (scanned once for the two tests that read it: the walk over every module's syntax tree is their whole cost)."""
    found: dict[str, set[str]] = {}
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG)
        if rel.parts[0] in EXCLUDED_DIRS:
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in
                  ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant)
                  and isinstance(node.args[0].value, str)):
                names = [node.args[0].value]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top and top not in sys.stdlib_module_names and top != "piezo_ff_ros":
                    found.setdefault(top, set()).add(str(rel))
    return found


def _exec_depends() -> dict[str, str | None]:
    pkg = parse_package(str(ROOT / "package.xml"))   # validates format 3 too
    return {d.name: d.condition for d in pkg.exec_depends}


def test_the_import_scan_sees_the_known_run_time_imports():
    found = _third_party_imports()
    for name in ("rclpy", "numpy", "numba", "control", "mcap", "rosbags", "nidaqmx", "pipython"):
        assert name in found, f"the scan missed {name!r}: it would pass with nothing checked"


def test_every_run_time_import_has_a_rosdep_key_in_package_xml():
    deps = _exec_depends()
    missing = []
    for name, files in sorted(_third_party_imports().items()):
        if name in OPTIONAL_WITHOUT_KEY:
            continue
        if name not in ROSDEP_KEYS:
            missing.append(f"{name} (imported by {sorted(files)[0]}): no known rosdep key — add it to ROSDEP_KEYS "
                           "with where the key comes from, or drop the import")
            continue
        key = ROSDEP_KEYS[name][0]
        if key not in deps:
            missing.append(f"{name} (imported by {sorted(files)[0]}): <exec_depend>{key}</exec_depend> missing")
    assert not missing, "package.xml:\n" + "\n".join(missing)


@pytest.mark.parametrize("name", sorted(OPTIONAL_CONDITIONED))
def test_optional_hardware_libraries_are_conditioned(name):
    """An optional vendor library is not installed by a plain `rosdep install` (the condition is false unless the
    user sets the variable), and is installed with it."""
    deps = _exec_depends()
    key = ROSDEP_KEYS[name][0]
    assert deps.get(key) == OPTIONAL_CONDITIONED[name]
    pkg = parse_package(str(ROOT / "package.xml"))
    pkg.evaluate_conditions({})
    assert key not in {d.name for d in pkg.exec_depends if d.evaluated_condition}
    pkg.evaluate_conditions({"PIEZO_FF_WITH_PI": "1"})
    assert key in {d.name for d in pkg.exec_depends if d.evaluated_condition}


@pytest.mark.parametrize("name", sorted(OPTIONAL_WITHOUT_KEY))
def test_optional_libraries_without_a_key_are_imported_only_by_their_backend(name):
    """A library rosdep cannot install must never be imported at module level: the package starts without it."""
    for path in sorted((PKG).rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in tree.body:   # module level only
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                mods = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                assert not any(m.split(".")[0] == name for m in mods), f"{path}: imports {name} at module level"


def test_optional_libraries_are_documented():
    text = (ROOT / "docs" / "nodes.md").read_text()
    for name in (*OPTIONAL_WITHOUT_KEY, *OPTIONAL_CONDITIONED):
        assert name in text, f"docs/nodes.md does not say how to install the optional {name}"
    assert "PIEZO_FF_WITH_PI" in text
