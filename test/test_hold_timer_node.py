"""The compensator plays a held reference_point from one executor timer (core HoldPacer), not a thread of its own:
paced at the sample rate (never faster), contiguous stamps, block_size changes re-time it."""
from __future__ import annotations

import threading
import time

import pytest

rclpy = pytest.importorskip("rclpy")

FS = 20000.0
DT_NS = 50_000


def _run(node, executor, seconds):
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        executor.spin_once(timeout_sec=0.005)


def test_held_point_is_paced_by_an_executor_timer():
    from geometry_msgs.msg import PointStamped
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from piezo_ff_ros.nodes.common import stamp_to_ns
    from piezo_ff_ros.nodes.compensator import CompensatorNode

    ctx = Context()
    rclpy.init(context=ctx, args=["--ros-args", "-p", "cascade.vibration:=false", "-p", "hold_timeout:=0.0",
                                   "-p", "block_size:=200"])
    threads_before = threading.active_count()
    node = CompensatorNode(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    sent = []
    node.pub_u.publish = lambda msg: sent.append((time.monotonic(), stamp_to_ns(msg.header.stamp), msg.width))
    try:
        assert threading.active_count() == threads_before      # no hold thread
        assert node._hold_timer.is_canceled()                   # nothing held: no wake-ups
        _run(node, ex, 0.3)
        assert sent == []                                       # nothing held: nothing played
        msg = PointStamped()
        msg.point.x, msg.point.y = 2e-6, -1e-6
        node.on_point(msg)
        t0 = time.monotonic()
        _run(node, ex, 1.0)
        t1 = time.monotonic()
        n200 = len(sent)
        due = (t1 - t0) * FS / 200 + 1
        assert 0.5 * due <= n200 <= due + 1                      # paced: never faster than the samples
        assert all(w == 200 for _, _, w in sent)
        node.set_parameters([Parameter("block_size", Parameter.Type.INTEGER, 400)])
        _run(node, ex, 0.5)
        assert {w for _, _, w in sent[n200:]} == {400}
        from std_srvs.srv import Trigger

        node.on_reset(Trigger.Request(), Trigger.Response())    # reset: the held point is forgotten, timer off
        assert node._hold_timer.is_canceled()
        n_reset = len(sent)
        _run(node, ex, 0.2)
        assert len(sent) == n_reset
        sent = sent[:n_reset]
        ks = [s for _, s, _ in sent]
        widths = [w for _, _, w in sent]
        assert all(b - a == w * DT_NS for a, b, w in zip(ks, ks[1:], widths))  # one contiguous stream
    finally:
        node.stop()
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
