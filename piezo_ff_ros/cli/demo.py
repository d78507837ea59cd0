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

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from . import CliError, output_dir

DEFAULT_CREEP_DURATION = 60.0


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
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
                        "paper's amplifier; the 20 µm x step asks ≈ 159 V, so nothing is clamped)")
    p.add_argument("--slew-limit", type=float, default=None, metavar="V/S",
                   help="driver (and compensator) slew limit (default: the config's limits.slew)")
    p.add_argument("--clocked", type=float, default=None, metavar="SPEED",
                   help="drive the clocked simulator (paced by the wall clock like a DAQ: FIFO, write-ahead, sensor "
                        "latency, underruns) with its clock SPEED times real time (1 = a real rig's pace); default: "
                        "the lockstep simulator")
    p.add_argument("--domain-id", type=int, metavar="ID",
                   help="ROS_DOMAIN_ID of the demo's graph (default: a free one, held while the demo runs, that no "
                        "test session or benchmark of this project uses)")
    p.add_argument("--only", metavar="NAMES", help="comma-separated experiment names (default: all)")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(func=run)
    return p


def _check(args: argparse.Namespace) -> None:
    if not (math.isfinite(args.creep_duration) and args.creep_duration > 1.0):
        raise ValueError(f"--creep-duration must be > 1 s, got {args.creep_duration}")
    if not 1 <= args.block_size <= 20000:
        raise ValueError(f"--block-size must be in 1..20000, got {args.block_size}")
    if args.clocked is not None and not (math.isfinite(args.clocked) and 1e-3 <= args.clocked <= 1e3):
        raise ValueError(f"--clocked must be a speed in [0.001, 1000], got {args.clocked}")
    for name in ("voltage_limit", "slew_limit"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ValueError(f"--{name.replace('_', '-')} must be a positive number, got {v}")
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        raise ValueError(f"--domain-id must be in 0..232, got {args.domain_id}")
    if not 1 <= args.window <= 50:
        raise ValueError(f"--window must be in 1..50, got {args.window}")
    output_dir(args.out, "--out")


def _preflight(args: argparse.Namespace) -> None:
    """Fail before starting four processes when the config cannot work: it loads, and its H∞ design exists."""
    from ..core.config import load_config

    cfg = load_config(args.config, variant=args.variant)
    if cfg.vibration.controller is None:
        from ..core.synthesis.cache import cached_synthesis

        # HinfSynthesisError: one line from the CLI entry; the design is kept for the compensator node's start-up
        cached_synthesis(cfg.dynamics.G_L, cfg.vibration)


def run(args: argparse.Namespace) -> int:
    _check(args)
    _preflight(args)
    try:
        return _run(args)
    except (RuntimeError, TimeoutError) as exc:  # a node died, a service timed out…: one clear message
        print(f"piezo-ff demo: error: {exc}", file=sys.stderr)
        return 1


def _run(args: argparse.Namespace) -> int:
    from ..ros.env import apply_ros_env_defaults

    # before rclpy is imported: a private domain, localhost discovery only
    apply_ros_env_defaults(domain_id=args.domain_id, force_domain=True)
    from ..core.analysis import analyze_run, format_report
    from ..core.config import load_config
    from ..core.experiments import paper_experiments, select_experiments
    from ..core.recording.mcap_io import read_run
    from ..core.reproduce import evaluate, format_tables
    from ..ros.graph_session import GraphClient
    from ..ros.sim_graph import sim_graph

    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    cfg = load_config(args.config, variant=args.variant)
    # the driver enforces the config's limits unless told otherwise; the compensator clamps to the same ones
    if args.voltage_limit is None:
        args.voltage_limit = cfg.limits.voltage
    if args.slew_limit is None:
        args.slew_limit = cfg.limits.slew
    exps = paper_experiments(cfg, creep_duration=args.creep_duration)
    exps = select_experiments(exps, args.only)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mcap_path = out / "run.mcap"
    fs = cfg.sample_rate
    total_s = sum(e.trajectory.n_samples(fs) for e in exps) / fs
    print(f"piezo-ff demo: {len(exps)} experiments ({total_s:.1f} s of signal at {fs:g} Hz) through the ROS 2 graph "
          + (f"on the clocked simulator at {args.clocked:g}× real time" if args.clocked else "in lockstep")
          + f"; creep runs {args.creep_duration:g} s after the step"
          + (" (the paper's 600 s: --creep-duration 600)" if args.creep_duration != 600 else "")
          + f"; driver limits ±{args.voltage_limit:g} V, {args.slew_limit:g} V/s", flush=True)

    graph = sim_graph(out, mcap_path, fs=fs, voltage_limit=args.voltage_limit, slew_limit=args.slew_limit,
                      block_size=args.block_size, window=args.window, config=args.config, variant=args.variant,
                      metadata={"demo": {"creep_duration": args.creep_duration,
                                         "experiments": [e.name for e in exps], "block_size": args.block_size,
                                         "mode": "lockstep", "driver_clock": args.clocked or "lockstep"}},
                      clocked=args.clocked)
    t_start = time.perf_counter()
    log(f"starting the nodes (ROS_DOMAIN_ID={graph.env['ROS_DOMAIN_ID']}, logs in {graph.log_dir}) …")
    graph.start()
    client = None
    skipped = []
    hinf = None
    try:
        client = GraphClient("piezo_ff_demo")
        client.wait_recorder_connected(check=graph.check_alive)
        for i, exp in enumerate(exps):
            graph.check_alive()
            bypass = exp.input == "voltage"
            if not client.configure(exp.stages, bypass=bypass, say=log):
                log(f"  {exp.name}: skipped: {client.comp_diag.get('last_error', 'configuration not built')}")
                skipped.append(exp.name)
                continue
            dt = client.play(exp.name, exp.trajectory, exp.meta())
            n = exp.trajectory.n_samples(fs)
            log(f"  [{i + 1}/{len(exps)}] {exp.name:<16} {n / fs:7.2f} s of signal in {dt:6.2f} s "
                f"(real-time factor {n / fs / max(dt, 1e-9):.1f})")
        if exps and len(skipped) == len(exps):
            raise CliError("no experiment could run: the compensator could not build its configuration ("
                           f"{client.comp_diag.get('last_error', 'no reason given')})")
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
    driver = f"clocked sim driver at {args.clocked:g}× real time" if args.clocked else "lockstep sim driver"
    conditions = {"source": f"piezo-ff demo (ROS 2 graph, {driver})",
                  "creep_duration_s": args.creep_duration, "config": cfg.name, "variant": args.variant}
    result = analyze_run(data, evaluate=lambda rec: evaluate(rec, experiments=exps, design=hinf,
                                                                  conditions=conditions)).to_json()
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
