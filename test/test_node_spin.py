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
