"""A hostile peer against a live driver + compensator (real DDS, own ROS domain): each case sends what a buggy
client or a hostile node could, then good 10 µm reference blocks, and reports whether the input was refused, whether
the graph recovered (a good block's voltage finite and off the limit, and applied by the driver) and how long after
the hostile input that first good output came.

    PYTHONPATH=$PWD python bench/bench_hostile.py [--vibration] [--json out.json]

Prints one table row per case: ``case | refused | recovered | time to recover [s] | what the graph said``.  Timings
are wall-clock on whatever the machine is doing (noisy on a shared machine).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from piezo_ff_ros.ros.env import apply_ros_env_defaults, claim_ros_domain  # noqa: E402

AXES = ["x", "y"]
DT_NS = 50_000
N = 200


def start(name: str, *args: str, log_dir: Path) -> subprocess.Popen:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    log = open(log_dir / f"{name}.log", "wb")
    return subprocess.Popen([sys.executable, "-m", f"piezo_ff_ros.nodes.{name}", "--ros-args", *args], env=env,
                            stdout=log, stderr=subprocess.STDOUT)


def stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


class Peer:
    """The hostile node: publishers on every input topic, the compensator's parameter service, and what the graph
    publishes back (voltages, applied voltages, both nodes' /diagnostics)."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PointStamped
        from rcl_interfaces.srv import SetParameters
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import PointCloud2

        from piezo_ff_ros.nodes.common import BLOCK_QOS, stamp_to_ns, unpack_block

        rclpy.init()
        self.node = rclpy.create_node("hostile_peer")
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)
        self.volts: dict[int, np.ndarray] = {}
        self.applied: dict[int, float] = {}
        self.diag: dict[str, dict[str, str]] = {"compensator": {}, "driver": {}}
        self.max_level = {"compensator": 0, "driver": 0}   # highest /diagnostics level since the last reset
        n = self.node
        self.vsub = n.create_subscription(PointCloud2, "voltage", lambda m: self.volts.__setitem__(
            stamp_to_ns(m.header.stamp), unpack_block(m, AXES)), BLOCK_QOS)
        self.asub = n.create_subscription(PointCloud2, "voltage_applied", lambda m: self.applied.__setitem__(
            stamp_to_ns(m.header.stamp), time.monotonic()), BLOCK_QOS)
        n.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.ref = n.create_publisher(PointCloud2, "reference", BLOCK_QOS)
        self.volt = n.create_publisher(PointCloud2, "voltage", BLOCK_QOS)
        self.fake_applied = n.create_publisher(PointCloud2, "voltage_applied", BLOCK_QOS)
        self.point = n.create_publisher(PointStamped, "reference_point", 10)
        self.setp = n.create_client(SetParameters, "/compensator/set_parameters")
        self.k = 10**6 * N
        self._wall0 = (time.monotonic(), self.k)   # a realtime client: its stamps follow the wall clock

    def _on_diag(self, m: Any) -> None:
        for s in m.status:
            for who in self.diag:
                if s.name.endswith("/" + who):
                    level = ord(s.level) if isinstance(s.level, bytes) else int(s.level)
                    self.diag[who] = {kv.key: kv.value for kv in s.values} | {"_level": str(level),
                                                                              "_message": s.message}
                    self.max_level[who] = max(self.max_level[who], level)

    def spin_until(self, cond: Callable[[], bool], timeout: float) -> bool:
        end = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > end:
                return False
            self.ex.spin_once(timeout_sec=0.01)
        return True

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def counter(self, who: str, key: str) -> int:
        try:
            return int(self.diag[who].get(key, 0))
        except ValueError:
            return 0

    def pack(self, block: np.ndarray, stamp: int) -> Any:
        from piezo_ff_ros.nodes.common import pack_block

        return pack_block(block, AXES, stamp)

    def good(self) -> int:
        """A good 10 µm block; after a pause the stream resumes at the wall clock's sample (as the trajectory
        node's realtime mode does), not behind it."""
        t0, k0 = self._wall0
        self.k = max(self.k, k0 + int((time.monotonic() - t0) * 1e9) // DT_NS // N * N)
        stamp = self.k * DT_NS
        self.ref.publish(self.pack(np.tile([10e-6, 0.0], (N, 1)), stamp))
        self.k += N
        return stamp

    def set_param(self, **values: Any) -> Any:
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        req = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        fut = self.setp.call_async(req)
        self.spin_until(fut.done, 60)
        return fut.result().results[0] if fut.done() else None

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.try_shutdown()


def recover(peer: Peer, t_sent: float, limit: float, timeout: float = 20.0) -> float | None:
    """Good blocks every 10 ms until one's voltage is finite and off the limit and the driver applied it; the time
    from ``t_sent`` to that voltage [s] (None: not within ``timeout``)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        s = peer.good()
        if peer.spin_until(lambda: s in peer.volts and s in peer.applied, 0.5):
            u = peer.volts[s]
            if np.all(np.isfinite(u)) and np.max(np.abs(u)) < limit * 0.999:
                return time.monotonic() - t_sent
        peer.spin_for(0.01)
    return None


def refused_by(peer: Peer, who: str, key: str, before: int, timeout: float = 5.0) -> bool:
    return peer.spin_until(lambda: peer.counter(who, key) > before, timeout)


def run(args: argparse.Namespace) -> list[dict[str, Any]]:
    from piezo_ff_ros.core.recording.blocks import MAX_BLOCK_SAMPLES

    log_dir = Path(tempfile.mkdtemp(prefix="bench_hostile_"))
    comp_args = ["-p", f"cascade.vibration:={'true' if args.vibration else 'false'}"]
    drv = start("driver", "-p", "limits.stale_timeout:=1.0", log_dir=log_dir)
    comp = start("compensator", *comp_args, log_dir=log_dir)
    peer = Peer()
    rows: list[dict[str, Any]] = []
    limit = 200.0
    try:
        assert peer.spin_until(lambda: peer.ref.get_subscription_count() > 0 and peer.vsub.get_publisher_count() > 0
                               and peer.asub.get_publisher_count() > 0, 120), "graph did not come up"
        peer.spin_for(1.0)
        assert recover(peer, time.monotonic(), limit, 60) is not None, "the graph does not answer good blocks"
        peer.spin_until(lambda: bool(peer.diag["compensator"]) and bool(peer.diag["driver"]), 5)

        def case(name: str, send: Callable[[], Any], who: str, key: str, note: str = "") -> None:
            before = peer.counter(who, key)
            peer.max_level[who] = 0
            t0 = time.monotonic()
            extra = send()
            t_rec = recover(peer, t0, limit)          # good blocks right after the hostile input
            refused = refused_by(peer, who, key, before) if key else bool(extra)
            peer.spin_for(1.1)                         # one more /diagnostics period: the level while it lasted
            rows.append({"case": name, "refused": refused, "recovered": t_rec is not None,
                         "time_to_recover_s": None if t_rec is None else round(t_rec, 3),
                         "said": note or f"{who} {key} {peer.counter(who, key)}, /diagnostics level "
                                         f"{['OK', 'WARN', 'ERROR', 'STALE'][peer.max_level[who]]}"})

        def ref_block(block: np.ndarray, stamp_offset: int = 0) -> Callable[[], None]:
            def send() -> None:
                peer.ref.publish(peer.pack(block, peer.k * DT_NS + stamp_offset))
                peer.k += block.shape[0]
            return send

        bad = np.tile([10e-6, 0.0], (N, 1))
        bad[7, 0] = 1e308
        case("reference: one sample of 1e308 m", ref_block(bad), "compensator", "rejected_blocks")
        case("reference: a 1e10 m block", ref_block(np.full((N, 2), 1e10)), "compensator", "rejected_blocks")
        nan = np.tile([10e-6, 0.0], (N, 1))
        nan[3, 1] = np.nan
        case("reference: NaN", ref_block(nan), "compensator", "rejected_blocks")
        case("reference: 1 ns off the grid", ref_block(np.tile([10e-6, 0.0], (N, 1)), 1), "compensator",
             "rejected_blocks")

        def empty() -> None:
            m = peer.pack(np.zeros((1, 2)), peer.k * DT_NS)
            m.width, m.row_step, m.data = 0, 0, b""
            peer.ref.publish(m)
        case("reference: width 0", empty, "compensator", "rejected_blocks")

        def count0() -> None:
            m = peer.pack(np.tile([10e-6, 0.0], (N, 1)), peer.k * DT_NS)
            m.fields[1].count = 0
            peer.ref.publish(m)
        case("reference: field count 0", count0, "compensator", "rejected_blocks")
        case(f"reference: 2 000 000 samples (> {MAX_BLOCK_SAMPLES})", ref_block(np.zeros((2_000_000, 2))),
             "compensator", "rejected_blocks")

        def stray() -> None:
            peer.ref.publish(peer.pack(np.tile([10e-6, 0.0], (N, 1)), (peer.k + 10**12) * DT_NS))
        gap0 = peer.counter("compensator", "input_gap_samples")
        case("reference: one stray stamp 1e12 samples ahead", stray, "compensator", "input_jumps")
        rows[-1]["said"] += f"; input_gap_samples +{peer.counter('compensator', 'input_gap_samples') - gap0}"

        def point() -> None:
            from geometry_msgs.msg import PointStamped

            msg = PointStamped()
            msg.point.x = 1.0
            peer.point.publish(msg)
        case("reference_point: 1 m", point, "compensator", "rejected_blocks")

        def applied(value: float) -> Callable[[], None]:
            def send() -> None:
                last = max(peer.volts) if peer.volts else peer.k * DT_NS
                peer.fake_applied.publish(peer.pack(np.full((N, 2), value), last))
            return send
        case("voltage_applied (foreign): NaN", applied(np.nan), "compensator", "applied_rejected")
        case("voltage_applied (foreign): 1e10 V", applied(1e10), "compensator", "applied_rejected")

        def to_driver_off_grid() -> None:
            peer.volt.publish(peer.pack(np.zeros((N, 2)), peer.k * DT_NS + 1))
        case("voltage (direct): 1 ns off the grid", to_driver_off_grid, "driver", "rejected_blocks")

        deep = "{a: " * 1000 + "1" + "}" * 1000     # 5 kB, 1000 levels (it crashed the node: RecursionError)
        bomb = 'a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n' + "".join(
            f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]\n" for i in range(1, 10))
        for name, text in (("1000 levels deep", deep), ("alias bomb (624 chars)", bomb),
                           ("8 MB string", "x: '" + "a" * (8 << 20) + "'")):
            said: list[str] = []

            def send(text: str = text, said: list[str] = said) -> bool:
                t = time.monotonic()
                r = peer.set_param(config_yaml=text)
                said.append(f"answered in {time.monotonic() - t:.2f} s: {r.reason[:70] if r else 'no answer'}")
                return r is not None and not r.successful
            case(f"config_yaml: {name}", send, "compensator", "", note="")
            rows[-1]["said"] = said[0]

        # a burst far beyond the queue depth: counted as lost, nothing unsafe
        gaps0 = peer.counter("compensator", "input_gap_samples")
        sent = 5000

        def burst() -> bool:
            for _ in range(sent):
                peer.good()
            return False
        t0 = time.monotonic()
        burst()
        t_rec = recover(peer, t0, limit)
        peer.spin_for(1.5)
        lost = (peer.counter("compensator", "input_gap_samples") - gaps0) // N
        rows.append({"case": f"reference: burst of {sent} blocks at once", "refused": False,
                     "recovered": t_rec is not None, "time_to_recover_s": None if t_rec is None else round(t_rec, 3),
                     "said": f"≈ {lost} of {sent} blocks lost at the QoS depth (counted: input_gap_samples)"})
    finally:
        peer.close()
        stop(comp)
        stop(drv)
    for name, argv in (("driver: safe_ramp.duration 0, slew 1e12", ["piezo_ff_ros.nodes.driver", "--ros-args", "-p",
                        "safe_ramp.duration:=0.0", "-p", "safe_ramp.slew:=1.0e12"]),
                       ("trajectory: sample_rate 30 kHz", ["piezo_ff_ros.nodes.trajectory", "--ros-args", "-p",
                        "sample_rate:=30000.0"])):
        r = subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, timeout=120,
                           env=dict(os.environ, PYTHONPATH=str(ROOT)))
        line = r.stderr.strip().splitlines()
        rows.append({"case": name, "refused": r.returncode == 2, "recovered": True, "time_to_recover_s": None,
                     "said": f"exit {r.returncode}: {line[-1][:90] if line else ''}"})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vibration", action="store_true", help="run the compensator with C(s) (H∞ synthesis)")
    ap.add_argument("--json", type=Path, help="write the rows as JSON")
    args = ap.parse_args()
    domain, _lock = claim_ros_domain()
    apply_ros_env_defaults(domain, force_domain=True)
    rows = run(args)
    w = max(len(r["case"]) for r in rows)
    print(f"{'case':<{w}} | refused | recovered | recover [s] | what the graph said")
    print("-" * (w + 60))
    for r in rows:
        t = "-" if r["time_to_recover_s"] is None else f"{r['time_to_recover_s']:.3f}"
        print(f"{r['case']:<{w}} | {'yes' if r['refused'] else 'no':<7} | {'yes' if r['recovered'] else 'NO':<9} | "
              f"{t:>11} | {r['said']}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    bad = [r["case"] for r in rows if not r["recovered"] or (not r["refused"] and "burst" not in r["case"])]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
