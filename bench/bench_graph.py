"""Benchmark of the node graph over real DDS (a script, not a test).

1. realtime: the 4 nodes at 20 kHz, blocks of ``--block`` samples, for ``--duration`` s (default 60): lost samples
   (from the recording), latency reference→displacement (receive times of the same stamp in this process: the
   trajectory→compensator→driver path), CPU per node (/proc utime+stime over the window), recorder bytes/s;
2. lockstep: ``--lockstep-seconds`` of signal as fast as the graph answers, real-time factor per block size.

    PYTHONPATH=. .venv/bin/python bench/bench_graph.py [--duration 60] [--json out.json]

Vibration compensation is off unless the H∞ synthesis module is installed (``--vibration`` forces it on).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from piezo_ff_ros.ros.env import apply_ros_env_defaults  # noqa: E402

apply_ros_env_defaults(force_domain=True)


sys.path.insert(0, str(Path(__file__).resolve().parent))
from _graph_common import cpu_seconds, have_hinf, percentiles_ms  # noqa: E402


def run_realtime(args, out: Path, vib: bool) -> dict:
    import rclpy
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.ros.launcher import GraphLauncher
    from piezo_ff_ros.nodes.common import RECORD_QOS, stamp_to_ns

    spec = json.dumps({"type": "circle", "radius": 2e-5, "frequency": 1.0, "revolutions": 100000})
    mcap = out / "bench_realtime.mcap"
    g = GraphLauncher({
        "recorder": ["-p", f"output:={mcap}"], "driver": [],
        "compensator": ["-p", f"cascade.vibration:={'true' if vib else 'false'}"],
        "trajectory": ["-p", "mode:=realtime", "-p", f"block_size:={args.block}", "-p", "min_subscribers:=2",
                       "-p", f"trajectory:='{spec}'"]}, log_dir=out / "logs_realtime", env=os.environ)
    g.start(timeout=300)
    rclpy.init()
    node = rclpy.create_node("bench")
    t_ref, t_disp = {}, {}
    node.create_subscription(PointCloud2, "reference", lambda m: t_ref.setdefault(stamp_to_ns(m.header.stamp),
                                                                                  time.monotonic()), RECORD_QOS)
    node.create_subscription(PointCloud2, "displacement", lambda m: t_disp.setdefault(stamp_to_ns(m.header.stamp),
                                                                                      time.monotonic()), RECORD_QOS)
    from std_srvs.srv import Trigger

    cli = node.create_client(Trigger, "/trajectory/start")
    cli.wait_for_service(timeout_sec=30)
    fut = cli.call_async(Trigger.Request())
    while not fut.done():
        rclpy.spin_once(node, timeout_sec=0.05)
    warm_end = time.monotonic() + 3.0
    while time.monotonic() < warm_end:
        rclpy.spin_once(node, timeout_sec=0.01)
    pids = {n: p.proc.pid for n, p in g.procs.items()}
    cpu0 = {n: cpu_seconds(pid) for n, pid in pids.items()}
    size0, w0 = mcap.stat().st_size, time.monotonic()
    t_ref.clear()
    t_disp.clear()
    end = w0 + args.duration
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.01)
    w1 = time.monotonic()
    cpu1 = {n: cpu_seconds(pid) for n, pid in pids.items()}
    size1 = mcap.stat().st_size
    node.destroy_node()
    rclpy.try_shutdown()
    codes = g.stop()
    lat = [t_disp[s] - t_ref[s] for s in t_ref if s in t_disp]
    from piezo_ff_ros.core.recording.mcap_io import read_run

    run = read_run(mcap)
    blocks = run.meta["blocks"]
    wall = w1 - w0
    res = {
        "duration_s": round(wall, 2), "block_size": args.block, "vibration": vib,
        "blocks_seen_by_probe": len(t_ref),
        "recorded_samples": int(len(run)),
        "lost_samples": {r: int(b["missing_samples"]) for r, b in blocks.items()},
        "gaps": {r: len(b["gaps"]) for r, b in blocks.items()},
        "latency_ms": percentiles_ms(lat),
        "cpu_fraction_of_one_core": {n: round((cpu1[n] - cpu0[n]) / wall, 3) for n in pids},
        "recorder_bytes_per_s": round((size1 - size0) / wall),
        "exit_codes": codes,
    }
    res["cpu_total"] = round(sum(res["cpu_fraction_of_one_core"].values()), 3)
    return res


def run_lockstep(args, out: Path, vib: bool, block: int) -> dict:
    import rclpy
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from piezo_ff_ros.ros.launcher import GraphLauncher
    from piezo_ff_ros.nodes.common import LATCHED_QOS

    spec = json.dumps({"type": "circle", "radius": 2e-5, "frequency": 1.0, "revolutions": args.lockstep_seconds})
    g = GraphLauncher({
        "recorder": ["-p", f"output:={out / f'bench_lockstep_{block}.mcap'}"], "driver": [],
        "compensator": ["-p", f"cascade.vibration:={'true' if vib else 'false'}"],
        "trajectory": ["-p", "mode:=lockstep", "-p", f"block_size:={block}", "-p", "min_subscribers:=2",
                       "-p", f"window:={args.window}", "-p", f"trajectory:='{spec}'"]},
        log_dir=out / f"logs_lockstep_{block}", env=os.environ)
    g.start(timeout=300)
    rclpy.init()
    node = rclpy.create_node("bench")
    states = []
    node.create_subscription(String, "/trajectory/state", lambda m: states.append((time.monotonic(),
                                                                                   json.loads(m.data))), LATCHED_QOS)
    cli = node.create_client(Trigger, "/trajectory/start")
    cli.wait_for_service(timeout_sec=30)
    fut = cli.call_async(Trigger.Request())
    while not any(s["state"] in ("finished", "failed") for _, s in states):
        rclpy.spin_once(node, timeout_sec=0.01)
    t_play = next(t for t, s in states if s["state"] == "playing")
    t_end, end = next((t, s) for t, s in states if s["state"] in ("finished", "failed"))
    node.destroy_node()
    rclpy.try_shutdown()
    g.stop()
    wall = t_end - t_play
    return {"block_size": block, "window": args.window, "signal_s": args.lockstep_seconds, "wall_s": round(wall, 2),
            "real_time_factor": round(args.lockstep_seconds / wall, 1), "state": end["state"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--block", type=int, default=200)
    ap.add_argument("--lockstep-seconds", type=float, default=20.0)
    ap.add_argument("--lockstep-blocks", default="200,2000")
    ap.add_argument("--window", type=int, default=4)
    ap.add_argument("--vibration", action="store_true")
    ap.add_argument("--out", default="/tmp/piezo_ff_bench_graph")
    ap.add_argument("--json")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vib = args.vibration or have_hinf()
    result = {"realtime": run_realtime(args, out, vib)}
    print(json.dumps(result["realtime"], indent=1), flush=True)
    result["lockstep"] = [run_lockstep(args, out, vib, int(b)) for b in args.lockstep_blocks.split(",")]
    print(json.dumps(result["lockstep"], indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
