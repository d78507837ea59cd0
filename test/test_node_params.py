"""Node parameters through real node processes: an override no node declares stops the node with one line naming it
and the closest declared name (command line or parameter file, before any device or file is opened); the trajectory
and compensator nodes' parameters keep their declared types (lossless integer → double taken, anything else refused
naming the parameter)."""
from __future__ import annotations

import subprocess
import sys

import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import Probe, child_env, start_node, stop_node  # noqa: E402

from piezo_ff_ros.nodes.params import override_names  # noqa: E402


def _run(name: str, *ros_args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", f"piezo_ff_ros.nodes.{name}", "--ros-args", *ros_args],
                          env=child_env(), capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("node,typo,close", [("driver", "limits.voltag", "limits.voltage"),
                                             ("compensator", "crossfad", "crossfade"),
                                             ("trajectory", "windw", "window"),
                                             ("recorder", "flush_intervall", "flush_interval")])
def test_an_unknown_override_stops_the_node_in_one_line(tmp_path, node, typo, close):
    out = tmp_path / "run.mcap"
    extra = ["-p", f"output:={out}"] if node == "recorder" else []
    r = _run(node, *extra, "-p", f"{typo}:=1.0")
    lines = (r.stdout + r.stderr).strip().splitlines()
    assert r.returncode == 2, r.stdout + r.stderr
    assert lines[-1] == f"{node}: error: unknown parameter {typo!r} (did you mean {close!r}?)"
    assert sum("unknown parameter" in ln for ln in lines) == 1 and not any("Traceback" in ln for ln in lines)
    assert not out.exists()                       # the recorder refused before creating its file


def test_a_params_file_entry_for_this_node_or_every_node_is_checked_another_nodes_is_not(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    mode: lockstep\n    blok_size: 100\n"
                 "driver:\n  ros__parameters:\n    limits.voltage: 100.0\n"
                 "trajectory:\n  ros__parameters:\n    wndow: 2\n")
    r = _run("trajectory", "--params-file", str(f), "-p", "driver:bogus:=1")
    assert r.returncode == 2, r.stdout + r.stderr
    assert (r.stdout + r.stderr).strip().splitlines()[-1] == \
        "trajectory: error: unknown parameter 'blok_size' (did you mean 'block_size'?); " \
        "unknown parameter 'wndow' (did you mean 'window'?)"


def test_a_trajectory_node_at_a_rate_off_the_nanosecond_grid_does_not_start():
    """30 kHz: 33 333.3 ns per sample, the stamps would drift from k / fs."""
    r = _run("trajectory", "-p", "sample_rate:=30000.0")
    assert r.returncode == 2, r.stdout + r.stderr
    last = (r.stdout + r.stderr).strip().splitlines()[-1]
    assert last.startswith("trajectory: error: sample_rate: 30000.0 Hz has no whole-nanosecond period"), last
    r = _run("trajectory", "-p", "block_size:=2.5")
    assert r.returncode == 2 and (r.stdout + r.stderr).strip().splitlines()[-1] == \
        "trajectory: error: block_size: expected an integer, got a double 2.5"


def test_override_names_reads_ros_args_sections_and_node_prefixes(tmp_path):
    argv = ["prog", "-p", "outside:=1", "--ros-args", "-r", "a:=b", "-p", "x:=1", "--param", "trajectory:y:=2",
            "-p", "/trajectory:z:=3", "-p", "driver:no:=4", "--", "-p", "after:=5", "--ros-args", "-p", "w:=6"]
    assert override_names("trajectory", "/trajectory", argv) == ["x", "y", "z", "w"]


@pytest.fixture()
def probe():
    p = Probe("params_probe")
    yield p
    p.close()


def test_trajectory_parameters_keep_their_types(tmp_path, probe):
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters

    proc = start_node("trajectory", "-p", "sample_rate:=25000", "-p", "ack_timeout:=5", log_dir=tmp_path)
    try:
        getp = probe.node.create_client(GetParameters, "/trajectory/get_parameters")
        setp = probe.node.create_client(SetParameters, "/trajectory/set_parameters")
        got = probe.call(getp, GetParameters.Request(names=["sample_rate", "ack_timeout", "block_size"]), 60).values
        assert [(v.type, v.double_value) for v in got[:2]] == [(ParameterType.PARAMETER_DOUBLE, 25000.0),
                                                               (ParameterType.PARAMETER_DOUBLE, 5.0)]
        assert (got[2].type, got[2].integer_value) == (ParameterType.PARAMETER_INTEGER, 200)

        def set_(name, **value):
            msg = ParameterMsg(name=name, value=ParameterValue(**value))
            return probe.call(setp, SetParameters.Request(parameters=[msg])).results[0]
        r = set_("lockstep_timeout", type=ParameterType.PARAMETER_INTEGER, integer_value=7)
        assert r.successful, r.reason
        v = probe.call(getp, GetParameters.Request(names=["lockstep_timeout"])).values[0]
        assert (v.type, v.double_value) == (ParameterType.PARAMETER_DOUBLE, 7.0)
        r = set_("block_size", type=ParameterType.PARAMETER_DOUBLE, double_value=2.5)
        assert not r.successful and r.reason == "block_size: expected an integer, got a double 2.5 (kept: 200)"
        r = set_("mode", type=ParameterType.PARAMETER_INTEGER, integer_value=3)
        assert not r.successful and r.reason == "mode: expected a string, got an integer 3 (kept: 'realtime')"
        r = set_("window", type=ParameterType.PARAMETER_INTEGER, integer_value=0)
        assert not r.successful and r.reason.startswith("window: must be an integer ≥ 1")
        v = probe.call(getp, GetParameters.Request(names=["block_size", "mode", "window"])).values
        assert (v[0].integer_value, v[1].string_value, v[2].integer_value) == (200, "realtime", 4)  # kept
    finally:
        assert stop_node(proc) == 0


def test_compensator_refuses_a_wrongly_typed_parameter_in_one_line_and_keeps_the_old_value(tmp_path, probe):
    """A running compensator: a string for a double, a double for an integer and a bool for a double array are
    refused in one line naming the parameter with the value kept, which `param get` still reads and `param describe`
    still types as declared; an integer for a double is taken as that double.  At start-up a wrongly typed override
    stops the node in one line."""
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters

    proc = start_node("compensator", "-p", "cascade.vibration:=false", "-p", "crossfade:=0", log_dir=tmp_path)
    try:
        getp = probe.node.create_client(GetParameters, "/compensator/get_parameters")
        setp = probe.node.create_client(SetParameters, "/compensator/set_parameters")
        got = probe.call(getp, GetParameters.Request(names=["crossfade", "block_size"]), 60).values
        assert (got[0].type, got[0].double_value) == (ParameterType.PARAMETER_DOUBLE, 0.0)   # -p crossfade:=0

        def set_(name, **value):
            msg = ParameterMsg(name=name, value=ParameterValue(**value))
            return probe.call(setp, SetParameters.Request(parameters=[msg])).results[0]
        r = set_("hold_timeout", type=ParameterType.PARAMETER_STRING, string_value="long")
        assert not r.successful and r.reason == "hold_timeout: expected a double, got a string 'long' (kept: 0.2)"
        r = set_("block_size", type=ParameterType.PARAMETER_DOUBLE, double_value=2.5)
        assert not r.successful and r.reason == "block_size: expected an integer, got a double 2.5 (kept: 1000)"
        r = set_("workspace", type=ParameterType.PARAMETER_BOOL, bool_value=True)
        assert not r.successful and r.reason.startswith("workspace: expected a double array, got a bool True")
        assert "\n" not in r.reason
        r = set_("crossfade", type=ParameterType.PARAMETER_INTEGER, integer_value=1)
        assert r.successful, r.reason
        got = probe.call(getp, GetParameters.Request(names=["hold_timeout", "block_size", "crossfade"])).values
        assert (got[0].type, got[0].double_value) == (ParameterType.PARAMETER_DOUBLE, 0.2)       # kept
        assert (got[1].type, got[1].integer_value) == (ParameterType.PARAMETER_INTEGER, 1000)    # kept
        assert (got[2].type, got[2].double_value) == (ParameterType.PARAMETER_DOUBLE, 1.0)       # taken as 1.0
        from rcl_interfaces.srv import DescribeParameters

        desc = probe.node.create_client(DescribeParameters, "/compensator/describe_parameters")
        d = probe.call(desc, DescribeParameters.Request(names=["hold_timeout", "block_size", "workspace"])).descriptors
        # the refused values did not retype the parameters either (rclpy retypes a dynamically typed descriptor)
        assert [x.type for x in d] == [ParameterType.PARAMETER_DOUBLE, ParameterType.PARAMETER_INTEGER,
                                       ParameterType.PARAMETER_DOUBLE_ARRAY]
        assert d[0].floating_point_range and d[0].description
    finally:
        assert stop_node(proc) == 0
    r = _run("compensator", "-p", "block_size:=2.5")
    assert r.returncode == 2, r.stdout + r.stderr
    assert (r.stdout + r.stderr).strip().splitlines()[-1] == \
        "compensator: error: block_size: expected an integer, got a double 2.5"
