"""``piezo-ff lifecycle | param | hold | echo``: what the README's rig block does with ``ros2``, without it.

A managed driver (started unconfigured), a compensator and the plotter run as separate processes; every helper is
run as a user runs it (``python -m piezo_ff_ros …``, a process of its own, the graph's ROS_DOMAIN_ID)."""
from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

pytest.importorskip("rclpy")

from test_nodes_integration import child_env, start_node, stop_node  # noqa: E402


def cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "piezo_ff_ros", *args], env=child_env(), capture_output=True,
                          text=True, timeout=timeout)


def ok(*args):
    r = cli(*args)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_helpers_step_the_driver_set_parameters_hold_a_point_and_echo(tmp_path):
    procs = [start_node("driver", "-p", "autostart:=false", log_dir=tmp_path),
             start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path),
             start_node("plotter", log_dir=tmp_path)]
    try:
        # lifecycle, as `ros2 lifecycle get/set /driver …`
        assert ok("lifecycle", "driver", "get", "--timeout", "60").strip() == "unconfigured"
        assert ok("lifecycle", "driver", "configure").strip() == "inactive"
        assert ok("lifecycle", "driver", "activate").strip() == "active"
        r = cli("lifecycle", "driver", "activate")             # not a transition of `active`
        assert r.returncode == 2 and "active" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr

        # parameters, with "did you mean" for the typo the issue met (`vibration.tr`)
        assert float(ok("param", "get", "compensator", "vibration.t_r", "--timeout", "60")) > 0
        r = cli("param", "set", "compensator", "vibration.tr", "0.02")
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "did you mean" in r.stderr and "vibration.t_r" in r.stderr, r.stderr
        assert "crossfade: 0.01 -> 0.02" in ok("param", "set", "compensator", "crossfade", "0.02")
        r = cli("param", "set", "compensator", "crossfade", "-1")     # rejected by the node: old value kept
        assert r.returncode == 2 and "rejected" in r.stderr, r.stderr
        assert float(ok("param", "get", "compensator", "crossfade")) == 0.02
        # the atomic change: a YAML document sent as the string it is (ros2 param set parses it into a dict)
        change = tmp_path / "change.yaml"
        change.write_text("creep.Cr.xx.den: [1.0, 0.12809, 0.001443844]\ncreep.Cr.xx.den_deg: [2]\n")
        ok("param", "set", "compensator", "config_yaml", change.read_text())
        assert yaml.safe_load(ok("param", "get", "compensator", "creep.Cr.xx.den")) == [1.0, 0.12809, 0.001443844]
        assert ok("param", "get", "compensator", "config_yaml").strip() == ""

        # hold a point; the driver applies it: plot_voltage shows it, /diagnostics reports the driver active
        assert "holding [5e-06, 0.0]" in ok("hold", "5e-6", "0")
        msg = yaml.safe_load(ok("echo", "plot_voltage", "--count", "1", "--timeout", "30").split("---")[0])
        assert set(msg) == {"header", "point"} and msg["header"]["frame_id"] == "piezo"
        out = ok("echo", "/diagnostics", "--count", "3", "--timeout", "30")
        assert out.count("---") == 3 and "lifecycle" in out
        r = cli("echo", "plot_eror", "--timeout", "3")
        assert r.returncode == 2 and "did you mean /plot_error" in r.stderr, r.stderr
    finally:
        assert [stop_node(p) for p in procs] == [0, 0, 0]


def test_the_documented_ros2_param_set_form_of_config_yaml_is_a_string(tmp_path):
    """What ``ros2 param set`` does with its VALUE (rclpy's own ``get_parameter_value``): the raw mapping fails with
    the issue's TypeError; the block literal docs/nodes.md shows — built by the shell exactly as written there —
    arrives as a string holding the file's contents."""
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import get_parameter_value

    change = tmp_path / "change.yaml"
    change.write_text("creep.Cr.xx.den: [1.0, 0.12809, 0.001443844]\ncreep.Cr.xx.den_deg: [2]\n")
    from rclpy.serialization import serialize_message

    with pytest.raises(TypeError):   # what `ros2 param set … "$(cat change.yaml)"` sends: a dict where a string goes
        serialize_message(get_parameter_value(change.read_text()))
    docs = (__import__("pathlib").Path(__file__).resolve().parents[1] / "docs" / "nodes.md").read_text()
    assert 'ros2 param set /compensator config_yaml "|\n$(sed \'s/^/  /\' change.yaml)"' in docs
    arg = subprocess.run(["bash", "-c", 'printf %s "|\n$(sed \'s/^/  /\' change.yaml)"'], cwd=tmp_path,
                         capture_output=True, text=True, check=True).stdout
    value = get_parameter_value(arg)
    serialize_message(value)
    assert value.type == ParameterType.PARAMETER_STRING
    assert value.string_value == change.read_text().rstrip("\n")      # the file, less its last newline
