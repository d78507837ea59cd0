"""The compensator node with ``reference_limit`` emptied by a peer through its parameter service, then fed huge
references through real DDS (1 m, ±1e6 m, a 2e6 m step): every block is answered with finite voltages within
±limits.voltage, and the node keeps answering ordinary blocks; a reference beyond the hard bound is still refused.

Before the bounded-work Bouc-Wen path the node took ~55 ms a sample of a 1 m reference and ~240 ms of 1e6 m: the
8000 samples below would have taken minutes, far beyond the conditions' timeouts.
"""
from __future__ import annotations

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_live_node import Graph, held  # noqa: E402
from test_nodes_integration import Probe, start_node, stop_node  # noqa: E402

N = 400


@pytest.fixture()
def probe():
    p = Probe("cliff6_probe")
    yield p
    p.close()


def test_node_answers_huge_references_with_the_limit_emptied(tmp_path, probe):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    g = Graph(probe)
    comp = start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)
    try:
        g.wait_ready()
        g.k = 10**6 * N
        g.send(held(N))
        req = SetParameters.Request(parameters=[
            Parameter("reference_limit", Parameter.Type.DOUBLE_ARRAY, []).to_parameter_msg()])
        res = probe.call(g.setp, req).results[0]
        assert res.successful, res.reason
        stamps = []
        for x, y in [(1.0, 0.0), (1e6, -1e6), (-1e6, 1e6), (1.0, 0.0)] * 5:
            stamps.append(g.send(held(N, x, y), wait=False))
        probe.spin_until(lambda: all(s in g.volts for s in stamps), 120, "voltages for 8000 samples of huge references")
        u = np.vstack([g.volts[s] for s in stamps])
        assert np.all(np.isfinite(u)) and np.max(np.abs(u)) <= 200.0
        assert np.all(u[N:2 * N, 0] == 200.0) and np.all(u[2 * N:3 * N, 0] == -200.0)
        # beyond the hard bound (1e12 × the reach): refused whole even with the limit empty
        s_bad = g.send(held(N, 1e300, 0.0), wait=False)
        d = g.diag_after(lambda d: int(d.get("rejected_blocks", 0)) >= 1, "the refused 1e300 m block")
        assert "hard reference bound" in d["_message"], d["_message"]
        g.send(held(N))
        assert s_bad not in g.volts and comp.poll() is None
    finally:
        assert stop_node(comp) == 0
    log = (tmp_path / "compensator.log").read_text()
    assert "hard reference bound" in log
