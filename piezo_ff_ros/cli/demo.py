"""``piezo-ff demo [--out DIR]``: the paper's experiments through the ROS 2 node graph, recorded, then analysed.

Starts driver (simulated PT230.94), compensator, trajectory (lockstep: as fast as the graph answers, lossless) and
recorder as separate processes on a private ROS domain; for each experiment of :mod:`piezo_ff_ros.core.experiments`
it switches the compensator's stages through its parameter service (``set_parameters_atomically``; the H∞ design is
synthesised by the compensator in the background when the vibration stage is first switched on), resets the
simulator and the compensator to rest, and plays the experiment's trajectory.  Everything goes through the topics and
is recorded to ``DIR/run.mcap``; the replay analysis of that file then prints Tables I/II and writes
``DIR/analysis.json`` (same keys as ``piezo-ff reproduce --json``).

The creep experiments last ``--creep-duration`` seconds after the step (default 60 s so that the demo takes about a
minute on a small machine; the paper's figures are for 600 s — pass ``--creep-duration 600``).
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

DEFAULT_CREEP_DURATION = 60.0


def add_parser(subparsers):
    p = subparsers.add_parser("demo", help="the paper's experiments through the ROS 2 node graph, recorded and "
                                           "analysed", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="piezo_ff_demo", metavar="DIR",
                   help="output directory: run.mcap, analysis.json, logs/ (default ./piezo_ff_demo)")
    p.add_argument("--creep-duration", type=float, default=DEFAULT_CREEP_DURATION, metavar="S",
                   help=f"creep observation after the steps, s (default {DEFAULT_CREEP_DURATION:g}; paper: 600)")
    p.add_argument("--config", metavar="YAML", help="actuator config (default: the paper's printed values)")
    p.add_argument("--variant", metavar="NAME", help="named variant of the config (e.g. gyx_gain_div10)")
    p.add_argument("--block-size", type=int, default=2000, metavar="N", help="samples per block (default 2000)")
    p.add_argument("--window", type=int, default=4, metavar="W", help="lockstep blocks in flight (default 4)")
    p.add_argument("--voltage-limit", type=float, default=None, metavar="V",
                   help="driver (and compensator) voltage limit (default: the config's limits.voltage, 200 V — the "
                        "paper's amplifier; the 20 µm x step asks ≈ 202 V at first, so it is clamped)")
    p.add_argument("--slew-limit", type=float, default=None, metavar="V/S",
                   help="driver (and compensator) slew limit (default: the config's limits.slew)")
    p.add_argument("--domain-id", type=int, metavar="ID",
                   help="ROS_DOMAIN_ID of the demo's graph (default: a private one derived from the process id)")
    p.add_argument("--only", metavar="NAMES", help="comma-separated experiment names (default: all)")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(func=run)
    return p


def _check(args):
    if not (math.isfinite(args.creep_duration) and args.creep_duration > 1.0):
        raise ValueError(f"--creep-duration must be > 1 s, got {args.creep_duration}")
    if not 1 <= args.block_size <= 20000:
        raise ValueError(f"--block-size must be in 1..20000, got {args.block_size}")
    for name in ("voltage_limit", "slew_limit"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ValueError(f"--{name.replace('_', '-')} must be a positive number, got {v}")
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        raise ValueError(f"--domain-id must be in 0..232, got {args.domain_id}")
    if not 1 <= args.window <= 50:
        raise ValueError(f"--window must be in 1..50, got {args.window}")


class _GraphClient:
    """The demo's own rclpy node: parameter/Trigger service calls, trajectory state and compensator diagnostics."""

    def __init__(self):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.srv import SetParametersAtomically
        from std_msgs.msg import String
        from std_srvs.srv import Trigger

        from ..nodes.common import LATCHED_QOS

        self.rclpy = rclpy
        rclpy.init()
        self.node = rclpy.create_node("piezo_ff_demo")
        self.states: list[dict] = []
        self.comp_diag: dict = {}
        self.hinf: dict | None = None    # γ/orders of the compensator's H∞ design, from its diagnostics
        self.node.create_subscription(String, "/trajectory/state", lambda m: self.states.append(json.loads(m.data)),
                                      LATCHED_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)
        self.recorder: dict = {}
        self.node.create_subscription(String, "/recorder/status", lambda m: self.recorder.update(json.loads(m.data)),
                                      LATCHED_QOS)
        self.set_comp = self.node.create_client(SetParametersAtomically, "/compensator/set_parameters_atomically")
        self.set_traj = self.node.create_client(SetParametersAtomically, "/trajectory/set_parameters_atomically")
        self.reset_comp = self.node.create_client(Trigger, "/compensator/reset")
        self.reset_drv = self.node.create_client(Trigger, "/driver/reset")
        self.start = self.node.create_client(Trigger, "/trajectory/start")
        self.Trigger = Trigger
        self.SetAtomic = SetParametersAtomically

    def _on_diag(self, msg):
        for st in msg.status:
            if st.name.endswith("compensator"):
                self.comp_diag = {kv.key: kv.value for kv in st.values}
                self.comp_diag["_t"] = time.monotonic()
                if "hinf" in self.comp_diag:
                    self.hinf = json.loads(self.comp_diag["hinf"])

    def spin_until(self, cond, timeout, what):
        deadline = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > deadline:
                raise RuntimeError(f"timed out after {timeout:g} s waiting for {what}")
            self.rclpy.spin_once(self.node, timeout_sec=0.02)

    def call(self, client, request, timeout=30.0):
        if not client.wait_for_service(timeout_sec=timeout):
            raise RuntimeError(f"service {client.srv_name} not available")
        fut = client.call_async(request)
        self.spin_until(fut.done, timeout, f"reply of {client.srv_name}")
        return fut.result()

    def set_params(self, client, values: dict):
        from rclpy.parameter import Parameter

        req = self.SetAtomic.Request(parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        res = self.call(client, req).result
        if not res.successful:
            raise RuntimeError(f"{client.srv_name} rejected {sorted(values)}: {res.reason}")

    def trigger(self, client):
        res = self.call(client, self.Trigger.Request())
        if not res.success:
            raise RuntimeError(f"{client.srv_name}: {res.message}")

    def close(self):
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def run(args) -> int:
    _check(args)
    try:
        return _run(args)
    except (RuntimeError, TimeoutError) as exc:  # a node died, a service timed out…: one clear message
        print(f"piezo-ff demo: error: {exc}", file=sys.stderr)
        return 1


def _run(args) -> int:
    from ..ros_env import apply_ros_env_defaults

    # before rclpy is imported: a private domain, localhost discovery only
    apply_ros_env_defaults(domain_id=args.domain_id, force_domain=True)
    from ..core.analysis import analyze_run, format_report
    from ..core.config import load_config
    from ..core.experiments import paper_experiments
    from ..core.recording.mcap_io import read_run
    from ..core.reproduce import evaluate, format_tables
    from ..core.trajectories import Sequence
    from ..launcher import GraphLauncher

    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    cfg = load_config(args.config, variant=args.variant)
    # the driver enforces the config's limits unless told otherwise; the compensator clamps to the same ones
    if args.voltage_limit is None:
        args.voltage_limit = cfg.limits.voltage
    if args.slew_limit is None:
        args.slew_limit = cfg.limits.slew
    exps = paper_experiments(cfg, creep_duration=args.creep_duration)
    if args.only:
        wanted = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = set(wanted) - {e.name for e in exps}
        if unknown:
            raise ValueError(f"--only: unknown experiment(s) {sorted(unknown)}; have {[e.name for e in exps]}")
        exps = [e for e in exps if e.name in wanted]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mcap_path = out / "run.mcap"
    fs = cfg.sample_rate
    total_s = sum(e.trajectory.n_samples(fs) for e in exps) / fs
    print(f"piezo-ff demo: {len(exps)} experiments ({total_s:.1f} s of signal at {fs:g} Hz) through the ROS 2 graph "
          f"in lockstep; creep runs {args.creep_duration:g} s after the step"
          + (" (the paper's 600 s: --creep-duration 600)" if args.creep_duration != 600 else "")
          + f"; driver limits ±{args.voltage_limit:g} V, {args.slew_limit:g} V/s", flush=True)

    cfg_args = []
    if args.config:
        cfg_args += ["-p", f"config_file:={Path(args.config).resolve()}"]
    if args.variant:
        cfg_args += ["-p", f"variant:={args.variant}"]
    meta = json.dumps({"demo": {"creep_duration": args.creep_duration, "experiments": [e.name for e in exps],
                                "block_size": args.block_size, "mode": "lockstep"}})
    graph = GraphLauncher({
        "recorder": ["-p", f"output:={mcap_path.resolve()}", "-p", f"metadata:='{meta}'", *cfg_args],
        "driver": [*cfg_args, "-p", f"limits.voltage:={float(args.voltage_limit)}",
                   "-p", f"limits.slew:={float(args.slew_limit)}",
                   # lockstep: the simulated time stands still while the graph waits (H∞ synthesis, a busy CPU),
                   # so a wall-clock stale timeout only needs to catch a dead compensator
                   "-p", "limits.stale_timeout:=5.0"],
        "compensator": [*cfg_args, "-p", "cascade.vibration:=false"],
        "trajectory": ["-p", "mode:=lockstep", "-p", f"block_size:={args.block_size}", "-p", f"window:={args.window}",
                       "-p", "min_subscribers:=2", "-p", f"sample_rate:={fs}", "-p", "lockstep_timeout:=30.0"],
    }, log_dir=out / "logs", env=os.environ)
    t_start = time.perf_counter()
    log(f"starting the nodes (ROS_DOMAIN_ID={graph.env['ROS_DOMAIN_ID']}, logs in {graph.log_dir}) …")
    graph.start()
    client = None
    skipped = []
    hinf = None
    try:
        client = _GraphClient()
        # the recorder must be connected to every block publisher before the first sample is sent
        topics = ("/reference", "/voltage", "/displacement")
        client.spin_until(lambda: all(client.recorder.get("publishers", {}).get(t, 0) >= 1 for t in topics), 120,
                          "the recorder to connect to the block topics")
        for i, exp in enumerate(exps):
            graph.check_alive()
            stages = set(exp.stages)
            want = {"cascade.hysteresis": "hysteresis" in stages, "cascade.creep": "creep" in stages,
                    "cascade.vibration": "vibration" in stages}
            bypass = exp.input == "voltage"
            if not bypass:
                stage_str = ",".join(k for k in ("vibration", "creep", "hysteresis") if f"cascade.{k}" in want
                                     and want[f"cascade.{k}"])
                failed_before = client.comp_diag.get("failed_builds", "0")
                client.set_params(client.set_comp, {"bypass": False, **want})
                if "vibration" in stages and client.comp_diag.get("stages") != stage_str:
                    log("  (the compensator synthesises the H∞ vibration compensator in the background …)")
                client.spin_until(lambda: (client.comp_diag.get("stages") == stage_str
                                           and client.comp_diag.get("pending_version") == "None")
                                  or client.comp_diag.get("failed_builds", "0") != failed_before, 900,
                                  f"compensator configuration {stage_str or 'none'}")
                if client.comp_diag.get("stages") != stage_str:
                    log(f"  {exp.name}: skipped: {client.comp_diag.get('last_error', 'configuration not built')}")
                    skipped.append(exp.name)
                    continue
            else:
                client.set_params(client.set_comp, {"bypass": True})
            client.trigger(client.reset_drv)
            client.trigger(client.reset_comp)
            seq = Sequence([(exp.name, exp.trajectory, exp.meta())])
            client.set_params(client.set_traj, {"trajectory": json.dumps(seq.to_dict())})
            n_before = len(client.states)
            t0 = time.perf_counter()
            client.trigger(client.start)
            client.spin_until(lambda: any(s["state"] in ("finished", "failed", "stopped")
                                          for s in client.states[n_before:]), 3600, f"experiment {exp.name}")
            end = [s for s in client.states[n_before:] if s["state"] in ("finished", "failed", "stopped")][0]
            if end["state"] != "finished":
                raise RuntimeError(f"experiment {exp.name}: trajectory {end['state']}: {end.get('error', '')}")
            dt = time.perf_counter() - t0
            n = exp.trajectory.n_samples(fs)
            log(f"  [{i + 1}/{len(exps)}] {exp.name:<16} {n / fs:7.2f} s of signal in {dt:6.2f} s "
                f"(real-time factor {n / fs / max(dt, 1e-9):.1f})")
        if client.comp_diag.get("failed_builds", "0") != "0":
            log(f"  compensator: {client.comp_diag.get('last_error', '')}")
    finally:
        if client is not None:
            hinf = client.hinf
            client.close()
        codes = graph.stop()
    t_graph = time.perf_counter() - t_start
    bad = {k: v for k, v in codes.items() if v != 0}
    if bad:
        print(f"warning: node exit codes {bad} (logs in {graph.log_dir})", file=sys.stderr)
    print(f"graph run: {t_graph:.1f} s wall for {total_s:.1f} s of signal; recording {mcap_path} "
          f"({mcap_path.stat().st_size / 1e6:.1f} MB)", flush=True)

    log("replay analysis of the recording …")
    data = read_run(mcap_path)
    conditions = {"source": "piezo-ff demo (ROS 2 graph, lockstep, sim driver)",
                  "creep_duration_s": args.creep_duration, "config": cfg.name, "variant": args.variant}
    result = analyze_run(data, evaluate=lambda rec: evaluate(rec, experiments=exps, design=hinf,
                                                                  conditions=conditions))
    print(format_report(result))
    if any(k != "replay" for k in result):
        print()
        print(format_tables(result, label="ROS graph", axes=cfg.axes))
    if skipped:
        print(f"\nnot run (their compensator configuration could not be built): {', '.join(skipped)}")
    (out / "analysis.json").write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    print(f"\nanalysis: {out / 'analysis.json'}   (creep figures for {args.creep_duration:g} s"
          + ("; the paper's are for 600 s" if args.creep_duration != 600 else "") + ")")
    print(f"(total {time.perf_counter() - t_start:.1f} s)")
    return 0
