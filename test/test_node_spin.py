"""``spin_node``: the exit code of every node's ``main``.

Reproduces the CI failure of ``test_graph_on_the_clocked_simulator`` (compensator exit code 1 on SIGINT): a
callback still running when the context is shut down publishes on a destroyed handle, and the old error path then
called ``node.get_name()`` on the destroyed node, which raised again — a traceback and exit code 1 for a clean stop.
"""
from __future__ import annotations

import pytest

rclpy = pytest.importorskip("rclpy")

from std_msgs.msg import String  # noqa: E402

from piezo_ff_ros.nodes.common import spin_node  # noqa: E402


def _spin_with(callback_body) -> int:
    """A node on the default context, as the nodes' ``main`` makes it (``rclpy.spin`` uses that context)."""
    rclpy.init()
    node = rclpy.create_node("spin_probe")
    pub = node.create_publisher(String, "spin_probe_out", 10)
    node.create_timer(0.01, lambda: callback_body(node.context, pub))
    try:
        return spin_node(node)
    finally:
        rclpy.try_shutdown()


def test_shutdown_under_a_running_callback_is_a_clean_stop(capfd):
    def shut_then_publish(ctx, pub):
        ctx.try_shutdown()                  # what SIGINT does while a block is being processed
        pub.publish(String(data="late"))    # → InvalidHandle

    assert _spin_with(shut_then_publish) == 0
    err = capfd.readouterr().err
    assert "Traceback" not in err and "stopped during a callback" in err


def test_a_callback_fault_while_running_is_fatal_in_one_line(capfd):
    def boom(ctx, pub):
        raise RuntimeError("boom")

    assert _spin_with(boom) == 1
    err = capfd.readouterr().err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == "spin_probe: fatal: boom"


def test_a_stop_while_the_node_is_being_built_is_clean(capfd):
    """SIGINT during a slow start-up (the fault-injection run saw a traceback and exit -2 from the driver)."""
    from piezo_ff_ros.nodes.common import run_node

    def slow_start():
        raise KeyboardInterrupt   # what SIGINT raises in the main thread while the node is being constructed

    assert run_node("slow", slow_start, argv=[]) == 0
    err = capfd.readouterr().err
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "slow: stopped while starting"


def test_a_bad_config_while_building_is_exit_2_in_one_line(capfd):
    from piezo_ff_ros.nodes.common import run_node

    def bad():
        raise ValueError("limits.voltage: must be > 0, got -1")

    assert run_node("drv", bad, argv=[]) == 2
    assert capfd.readouterr().err.strip().splitlines()[-1] == "drv: error: limits.voltage: must be > 0, got -1"


def test_a_handle_error_just_before_the_context_shuts_down_is_a_clean_stop(capfd):
    """The full-suite flake of ``test_lockstep_run_survives_a_compensator_kill9_and_restart`` (trajectory exit code 1
    on SIGINT, "fatal: Unable to convert call argument '0' to Python object"): the executor met a handle already
    destroyed by the shutdown *before* the context said it was no longer ok.  A shutdown that follows the error
    within moments is the stop it was, not a fatal fault."""
    import threading

    def handle_gone(ctx, pub):
        threading.Timer(0.05, ctx.try_shutdown).start()   # the signal's shutdown, completing a moment later
        raise TypeError("Unable to convert call argument '0' to Python object")

    assert _spin_with(handle_gone) == 0
    err = capfd.readouterr().err
    assert "Traceback" not in err and "stopped during a callback" in err


def test_a_stop_while_the_start_up_heap_is_frozen_is_clean(monkeypatch):
    """SIGINT during the start-up heap's collection (seen in a full-suite run: a driver stopped 0.5 s after start
    exited -2 with a KeyboardInterrupt traceback from ``freeze_startup_heap``) is a clean stop, on_exit included."""
    from piezo_ff_ros.nodes import common

    def interrupted() -> int:
        raise KeyboardInterrupt   # what SIGINT raises in the main thread during gc.collect()

    monkeypatch.setattr(common, "freeze_startup_heap", interrupted)
    finished = []
    rclpy.init()
    node = rclpy.create_node("freeze_probe")
    try:
        assert spin_node(node, on_exit=lambda: finished.append(True)) == 0
    finally:
        rclpy.try_shutdown()
    assert finished == [True]     # the driver's on_exit is its safe ramp: it must run


def test_a_node_prints_its_stacks_on_sigusr1_and_says_when_it_stops(tmp_path):
    """``kill -USR1`` makes a running node print every thread's Python stack to its log (what a node that stopped
    answering waits for) and it keeps running; SIGINT then stops it cleanly, and its log says so."""
    import signal
    import time

    from test_nodes_integration import start_node, stop_node

    proc = start_node("trajectory", log_dir=tmp_path)
    log = proc.log_path
    try:
        deadline = time.monotonic() + 60
        while "heap frozen" not in log.read_text(errors="replace"):
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text(errors="replace")[-2000:]
            time.sleep(0.05)
        proc.send_signal(signal.SIGUSR1)
        while "Current thread" not in log.read_text(errors="replace"):
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text(errors="replace")[-2000:]
            time.sleep(0.05)
        assert "spin_node" in log.read_text(errors="replace")
    finally:
        assert stop_node(proc) == 0
    assert log.read_text(errors="replace").rstrip().endswith("trajectory: stopping")


_DEAF_NODE = r"""
import sys
import rclpy
from piezo_ff_ros.nodes.common import run_node


def make():
    node = rclpy.create_node("deaf")
    # what the full-suite stacks showed: SIGINT arrived, yet the idle executor never woke (its only thread stayed in
    # rclpy's wait).  Here that wake-up is taken away: rclpy's signal handling can no longer reach the executor
    # rclpy.spin would use.
    executor = rclpy.get_global_executor()
    if executor._sigint_gc is not None:
        executor._sigint_gc.destroy()
        executor._sigint_gc = None

    def spinning():   # once, from inside the spin: then the node is idle in the executor's wait
        timer.cancel()
        print("ready", flush=True)

    timer = node.create_timer(0.05, spinning)
    return node


sys.exit(run_node("deaf", make, lambda n: print("finished", flush=True), argv=[]))
"""


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_a_stop_signal_stops_an_idle_node_whose_executor_wake_up_is_lost(tmp_path, signame):
    """A node with nothing to do (no timer, no traffic) stops on SIGINT/SIGTERM even when rclpy's signal handling
    never wakes its executor — seen in full-suite runs: a trajectory node that had finished its run ignored SIGINT
    for 15 s, idle in rclpy's executor wait, until it was killed (and its on-exit never ran)."""
    import signal
    import subprocess
    import sys

    from test_nodes_integration import child_env

    proc = subprocess.Popen([sys.executable, "-c", _DEAF_NODE], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=child_env(), cwd=tmp_path)
    try:
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
        proc.send_signal(getattr(signal, signame))
        out, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"the idle node ignored {signame} for 10 s")
    assert proc.returncode == 0, err
    assert "finished" in out and "Traceback" not in err
