"""``piezo-ff commission`` through the ROS 2 node graph: the sequence of :mod:`piezo_ff_ros.core.commissioning` on a
:class:`~piezo_ff_ros.ros.graph_rig.GraphRig`.

1. Finds a driver on the domain (a node named ``driver`` or a subscriber of ``voltage``): any backend, simulated or
   hardware; without one it starts the sim graph (driver, compensator, trajectory, recorder) on a private domain (or
   ``--domain-id``); with one it starts only the nodes that are missing (never a second recorder: the recording
   must be ours).  A driver without a displacement sensor is refused, and so is one whose axes (its
   ``joint_states`` names) differ from the starting config's.
2. Characterises S0 (compensator bypassed), S_H and S_L stage by stage with live parameter pushes, identifies each
   stage from the recording, scores the identified whole plant on a held-out voltage record, synthesises H∞ and
   pushes the complete identified config (all in :func:`~piezo_ff_ros.core.commissioning.commission`).
3. Verifies by playing the paper's tests (:mod:`piezo_ff_ros.core.experiments`) through the graph; Tables I/II.

Everything goes through the topics into ``DIR/commission.mcap``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable


def driver_axes(client: Any, timeout: float = 2.0) -> tuple[str, ...] | None:
    """The axes a running driver drives: those of the config it loaded (its ``config_file`` and ``variant``
    parameters), else the joint names of its ``/joint_states``; None when neither answers within ``timeout`` s."""
    from rclpy.parameter import parameter_value_to_python
    from sensor_msgs.msg import JointState

    from ..core.config import load_config

    get = client.node.create_client(client.GetParameters, "/driver/get_parameters")
    try:
        if get.wait_for_service(timeout_sec=timeout):
            res = client.call(get, client.GetParameters.Request(names=["config_file", "variant"]), timeout=timeout)
            values = [parameter_value_to_python(v) for v in res.values]
            if len(values) == 2 and isinstance(values[0], str) and isinstance(values[1], str):
                return tuple(load_config(values[0] or None, variant=values[1] or None).axes)
    finally:
        client.node.destroy_client(get)
    names: list[tuple[str, ...]] = []
    sub = client.node.create_subscription(JointState, "/joint_states", lambda m: names.append(tuple(m.name)), 10)
    try:
        deadline = time.monotonic() + timeout
        while not names and time.monotonic() < deadline:
            client.spin_for(0.1)
    finally:
        client.node.destroy_subscription(sub)
    return names[0] if names else None


def run_graph(args: argparse.Namespace, say: Callable[[str], None]) -> int:
    """The ROS path of ``piezo-ff commission`` (``args`` from :mod:`piezo_ff_ros.cli.commission`)."""
    from .env import apply_ros_env_defaults

    # before rclpy is imported: localhost discovery; probe the given (or the caller's) domain for a driver
    apply_ros_env_defaults(domain_id=args.domain_id, force_domain=args.domain_id is not None)
    from ..core.characterisation import CharacterisationSettings
    from ..core.commissioning import commission, save_config, save_report, verify
    from ..core.config import load_config
    from ..core.experiments import paper_experiments, select_experiments
    from ..core.jsonable import parse_order
    from ..core.reproduce import format_tables
    from .graph_rig import GraphRig
    from .graph_session import GraphClient, displacement_present, driver_present
    from .sim_graph import sim_graph

    t_start = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mcap_path = out / "commission.mcap"
    if mcap_path.exists():
        mcap_path.unlink()
    printed = load_config(args.config, variant=args.variant)
    fs, axes = printed.sample_rate, printed.axes
    vlim = printed.limits.voltage if args.voltage_limit is None else args.voltage_limit
    slim = printed.limits.slew
    settings = CharacterisationSettings(sine_frequency=args.sine_frequency, sine_periods=args.sine_periods,
                                        creep_step=args.step_um * 1e-6, dynamics_step=args.step_um * 1e-6,
                                        creep_duration=args.creep_duration)
    exps = paper_experiments(printed, creep_duration=args.creep_duration)
    exps = select_experiments(exps, args.only)

    client: GraphClient | None
    client = GraphClient("piezo_ff_commission", domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    found = driver_present(client, timeout=args.probe_timeout)
    if found:
        present = {n.rsplit("/", 1)[-1] for n in client.node_names()}
        if "recorder" in present:
            client.close()
            raise ValueError("a recorder node is already running on this domain; stop it (commissioning records "
                             "to its own DIR/commission.mcap)")
        if not displacement_present(client, timeout=max(args.probe_timeout, 5.0)):
            client.close()
            raise ValueError(f"the driver on ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} publishes no /displacement: "
                             "its device has no sensor, and commissioning identifies from measured displacement "
                             "(use a backend with a sensor, e.g. nidaqmx with ai_channels)")
        found_axes = driver_axes(client, timeout=max(args.probe_timeout, 2.0))
        if found_axes is not None and found_axes != tuple(axes):
            client.close()
            raise ValueError(f"the starting config {printed.name!r} has axes {list(axes)} but the driver on "
                             f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} drives {list(found_axes)}: start from a "
                             "config of the driver's axes (--config)")
        if found_axes is None:
            say("the driver published no joint_states: its axes could not be checked against the config's")
        nodes = ("recorder",) + tuple(n for n in ("compensator", "trajectory") if n not in present)
        say(f"driver found on ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}; starting {', '.join(nodes)}")
    else:
        client.close()
        client = None
        if args.domain_id is None:   # a private domain for our own sim graph
            apply_ros_env_defaults(force_domain=True)
        nodes = ("driver", "compensator", "trajectory", "recorder")
        say(f"no driver on the domain: starting the sim graph on ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}")
    graph = sim_graph(out, mcap_path, fs=fs, voltage_limit=vlim, slew_limit=slim, block_size=args.block_size,
                      config=args.config, variant=args.variant, nodes=nodes,
                      metadata={"commission": {"creep_duration": args.creep_duration, "step_m": settings.creep_step,
                                               "sine_frequency": settings.sine_frequency, "mode": "lockstep"}})
    graph.start()
    timing = {}
    try:
        if client is None:
            client = GraphClient("piezo_ff_commission", domain_id=int(os.environ["ROS_DOMAIN_ID"]))
        client.wait_recorder_connected(check=graph.check_alive)
        rig = GraphRig(client, graph, mcap_path, fs, axes, vlim, slim, say=say)
        result = commission(rig, base=printed, settings=settings, generalized=args.generalized,
                            creep_order=parse_order(args.creep_order),
                            dynamics_order=parse_order(args.dynamics_order),
                            progress=say, accept_poor_fit=args.accept_poor_fit)
        cfg, design, note = result.config, result.design, result.hinf_note
        cfg_path = out / "config.yaml"
        save_config(cfg, cfg_path)
        say(f"wrote {cfg_path}; pushing the complete identified configuration live")
        rig.configure(cfg, frozenset({"hysteresis", "creep", "vibration"}))
        say(f"verify: {len(exps)} paper experiments through the graph with the identified cascade")
        t0 = time.perf_counter()
        res = verify(rig, cfg, design, exps,
                     conditions={"source": "piezo-ff commission (ROS 2 graph, lockstep)", "compensator": "identified",
                                 "creep_duration_s": args.creep_duration}, progress=say)
        timing["verify"] = time.perf_counter() - t0
    finally:
        if client is not None:
            client.close()
        codes = graph.stop()
    bad = {k: v for k, v in codes.items() if v != 0}
    if bad:
        print(f"warning: node exit codes {bad} (logs in {graph.log_dir})", file=sys.stderr)

    report = result.report
    timing = {**report.timing_s, **timing, "total": time.perf_counter() - t_start}
    out_json = {"fit_percent": report.fit_percent,
                "plant_fit_basis": "measured output (recorded through the graph)",
                "plant_fit_parts": report.plant_fit_parts,
                **({"accepted_poor_fits": report.accepted_poor_fits} if report.accepted_poor_fits else {}),
                "orders": report.orders,
                "before": res.before, "after": res.after, "hinf": res.hinf,
                "tracking": res.tracking, "static_error_percent": res.static_error_percent,
                **({"cross_coupling_pairs_percent": res.cross_coupling_pairs_percent}
                   if res.cross_coupling_pairs_percent is not None else {}),
                "conditions": {"graph": "started sim graph" if not found else "existing driver",
                               "ros_domain_id": int(os.environ["ROS_DOMAIN_ID"]),
                               "creep_duration_s": args.creep_duration,
                               "characterisation_step_m": settings.creep_step,
                               "sine_frequency_hz": settings.sine_frequency,
                               "sine_periods": settings.sine_periods, "sample_rate_hz": fs,
                               "generalized": bool(args.generalized), "voltage_limit_v": vlim,
                               "experiments": [e.name for e in exps]},
                "config": str(out / "config.yaml"), "recording": str(mcap_path), "hinf_note": note,
                "timing_s": {k: round(v, 2) for k, v in timing.items()}}
    print(format_tables(res, label="identified cascade (ROS graph)", axes=axes))
    print()
    print(report.format_fits())
    save_report(out_json, out, args.json)
    say(f"done in {timing['total']:.1f} s; recording {mcap_path}, config {out / 'config.yaml'}")
    return 0
