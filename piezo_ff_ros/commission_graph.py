"""``piezo-ff commission`` through the ROS 2 node graph (paper Fig. 3, stage by stage, live parameter pushes).

1. Finds a driver on the domain (a node named ``driver`` or a subscriber of ``voltage``); without one it starts the
   sim graph (driver, compensator, trajectory, recorder) on a private domain (or ``--domain-id``); with one it
   starts only the nodes that are missing (never a second recorder: the recording must be ours).
2. Characterises S0 (compensator ``bypass``: sines in volts, and the held-out whole-plant voltage record),
   identifies the Bouc-Wen model, pushes it live (``set_parameters_atomically``, flat parameters of
   :mod:`piezo_ff_ros.core.param_map`), characterises S_H (creep steps through the identified hysteresis
   compensator), identifies K, Cr(s), refits the Bouc-Wen without creep (as ``commission_sim``), pushes both,
   characterises S_L (steps through both), identifies G_L(s), scores the identified whole plant on the held-out
   record (``fit_percent.plant``), synthesises H∞ and pushes the complete identified config.
3. Verifies by playing the paper's tests (:mod:`piezo_ff_ros.core.experiments`) through the graph; Tables I/II.

Everything goes through the topics into ``DIR/commission.mcap``; identification reads the recording back
(:func:`~piezo_ff_ros.core.recording.mcap_io.read_run`) segment by segment.
"""
from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def _wait_segments(mcap_path, wanted: dict, client, graph, timeout: float = 120.0) -> dict:
    """``{name: RunData}`` for the segments ``wanted`` = ``{name: n_samples}`` once they are fully on disk."""
    from .core.recording.mcap_io import read_run
    from .core.recording.run import RunData

    deadline = time.monotonic() + timeout
    last = "nothing recorded yet"
    while True:
        client.spin_for(0.5)
        if graph is not None:
            graph.check_alive()
        try:
            run = read_run(mcap_path)
        except (ValueError, OSError) as exc:   # the recorder has not flushed a readable chunk yet
            run, last = None, str(exc)
        if run is not None:
            out = {}
            for seg in run.meta.get("segments", []):
                n = wanted.get(seg["name"])
                if n is None or seg["name"] in out:
                    continue
                a = seg["start"]
                if seg["stop"] - a < n or a < 0:
                    continue
                u, y, r = run.u[a:a + n], run.y[a:a + n], run.reference[a:a + n]
                if np.isnan(u).any() or np.isnan(y).any() or np.isnan(r).any():
                    continue
                out[seg["name"]] = RunData(t=np.arange(n) / run.sample_rate, u=u.copy(), y=y.copy(), axes=run.axes,
                                           reference=r.copy(), meta={"experiment": seg["name"]})
            if len(out) == len(wanted):
                return out
            last = f"have {sorted(out)} of {sorted(wanted)}"
        if time.monotonic() > deadline:
            raise RuntimeError(f"the recording {mcap_path} does not hold the runs after {timeout:g} s ({last})")


def run_graph(args, say) -> int:
    """The ROS path of ``piezo-ff commission`` (``args`` from :mod:`piezo_ff_ros.cli.commission`)."""
    from .ros_env import apply_ros_env_defaults

    # before rclpy is imported: localhost discovery; probe the given (or the caller's) domain for a driver
    apply_ros_env_defaults(domain_id=args.domain_id, force_domain=args.domain_id is not None)
    from .core.characterisation import CharacterisationSettings
    from .core.characterisation_graph import graph_characterisation
    from .core.config import load_config
    from .core.experiments import paper_experiments
    from .core.identification.bouc_wen import identify_bouc_wen
    from .core.identification.creep import identify_creep
    from .core.identification.dynamics import identify_dynamics
    from .core.identification.pipeline import (REFIT_TAG, _fits_report, build_config, plant_fit,
                                               refit_hysteresis_without_creep, synthesize_for)
    from .core.param_map import config_to_params
    from .core.recording.mcap_io import read_run
    from .core.analysis import segment_signals
    from .core.reproduce import evaluate, format_tables
    from .graph_session import GraphClient, driver_present, sim_graph

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
    plan = graph_characterisation(settings, fs, axes)
    exps = paper_experiments(printed, creep_duration=args.creep_duration)
    if args.only:
        wanted = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = set(wanted) - {e.name for e in exps}
        if unknown:
            raise ValueError(f"--only: unknown experiment(s) {sorted(unknown)}; have {[e.name for e in exps]}")
        exps = [e for e in exps if e.name in wanted]

    client = GraphClient("piezo_ff_commission", domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    found = driver_present(client, timeout=args.probe_timeout)
    if found:
        present = {n.rsplit("/", 1)[-1] for n in client.node_names()}
        if "recorder" in present:
            client.close()
            raise ValueError("a recorder node is already running on this domain; stop it (commissioning records "
                             "to its own DIR/commission.mcap)")
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
        client.wait_recorder_connected()

        def characterise(stage, extra_meta=None):
            t0 = time.perf_counter()
            for name, tr, role, _ in plan[stage]:
                dt = client.play(name, tr, {"stage": stage, "role": role, **(extra_meta or {})})
                say(f"  {name}: {tr.n_samples(fs) / fs:.1f} s of signal in {dt:.1f} s")
            recs = _wait_segments(mcap_path, {n: tr.n_samples(fs) for n, tr, _, _ in plan[stage]}, client, graph)
            fit, val = [], []
            for name, _, role, score_t in plan[stage]:
                r = recs[name]
                if role == "split":
                    k = int(round(score_t * fs))
                    f = r.slice(0, k)
                    f.meta.update(stage=stage, role="fit")
                    r.meta.update(stage=stage, role="validation", score_start=k)
                    fit.append(f)
                    val.append(r)
                else:
                    r.meta.update(stage=stage, role=role, **(extra_meta or {}))
                    (val if role == "validation" else fit).append(r)
            timing[f"characterise_{stage}"] = time.perf_counter() - t0
            return fit, val

        def push(stages, cfg, prefixes):
            params = {k: v for k, v in config_to_params(cfg).items() if k.startswith(prefixes)}
            if not client.configure(stages, params=params, say=say):
                raise RuntimeError(f"the compensator rejected the identified {'/'.join(prefixes)} parameters: "
                                   f"{client.comp_diag.get('last_error', '?')}")

        say("characterise hysteresis on S0 (compensator bypass: sines in volts)")
        client.configure(bypass=True)
        fit, val = characterise("hysteresis")
        hyst_runs = fit + val
        say("held-out whole-plant voltage record (multisine + step pair, never fitted on), still in bypass")
        _, plant_runs = characterise("plant")
        t0 = time.perf_counter()
        hf = identify_bouc_wen(fit, val, generalized=args.generalized, progress=say)
        timing["identify_hysteresis"] = time.perf_counter() - t0
        push({"hysteresis"}, dataclasses.replace(printed, hysteresis=hf.config), ("hysteresis.",))
        say("pushed the identified Bouc-Wen model to the compensator; characterise creep on S_H")
        fit, val = characterise("creep")
        t0 = time.perf_counter()
        cf = identify_creep(fit, val, order=_order(args.creep_order), axes=axes, progress=say)
        timing["identify_creep"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        say("hysteresis: refit Bouc-Wen on S0 with the identified creep removed from the output")
        hf = refit_hysteresis_without_creep(hyst_runs, cf.config, generalized=args.generalized, init=hf,
                                            progress=say)
        timing["identify_hysteresis_refit"] = time.perf_counter() - t0
        push({"hysteresis", "creep"}, dataclasses.replace(printed, hysteresis=hf.config, creep=cf.config),
             ("hysteresis.", "creep."))
        say("pushed the refitted Bouc-Wen and K, Cr(s) to the compensator; characterise dynamics on S_L")
        fit, val = characterise("dynamics", {"hysteresis_compensator": REFIT_TAG})
        t0 = time.perf_counter()
        df = identify_dynamics(fit, val, order=_order(args.dynamics_order), axes=axes, progress=say)
        timing["identify_dynamics"] = time.perf_counter() - t0
        cfg = build_config(printed, hf, cf, df, fs, axes)
        t0 = time.perf_counter()
        say("plant: held-out fit of the identified whole-plant model on the recorded voltage record")
        fit_plant = plant_fit(cfg, plant_runs)
        timing["plant_fit"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        say("vibration: H∞ synthesis on the identified G_L")
        design, note = synthesize_for(cfg, say)
        vib = dataclasses.replace(cfg.vibration, controller=design.controller_matrices())
        if note:
            vib = dataclasses.replace(vib, gamma_max=1.05 * float(design.gamma))
        cfg = dataclasses.replace(cfg, vibration=vib).validate()
        timing["hinf"] = time.perf_counter() - t0
        cfg_path = out / "config.yaml"
        cfg.to_yaml(cfg_path)
        load_config(cfg_path)  # what the compensator node will do: fails loudly if the file is not loadable
        say(f"wrote {cfg_path}; pushing the complete identified configuration live")
        push({"hysteresis", "creep", "vibration"}, cfg, ("hysteresis.", "creep.", "dynamics.", "vibration."))

        say(f"verify: {len(exps)} paper experiments through the graph with the identified cascade")
        t0 = time.perf_counter()
        for exp in exps:
            graph.check_alive()
            if not client.configure(exp.stages, bypass=exp.input == "voltage", say=say):
                raise RuntimeError(f"{exp.name}: compensator configuration not built: "
                                   f"{client.comp_diag.get('last_error', '?')}")
            dt = client.play(exp.name, exp.trajectory, exp.meta())
            say(f"  {exp.name:<16} {exp.trajectory.n_samples(fs) / fs:7.2f} s of signal in {dt:5.1f} s")
        timing["verify"] = time.perf_counter() - t0
    finally:
        if client is not None:
            client.close()
        codes = graph.stop()
    bad = {k: v for k, v in codes.items() if v != 0}
    if bad:
        print(f"warning: node exit codes {bad} (logs in {graph.log_dir})", file=sys.stderr)

    run = read_run(mcap_path)
    rec, warnings = segment_signals(run)
    missing = [e.name for e in exps if e.name not in rec]
    if missing:
        raise RuntimeError(f"verification runs missing from {mcap_path}: {missing} ({warnings})")
    res = evaluate({e.name: rec[e.name] for e in exps}, exps, design=design,
                   conditions={"source": "piezo-ff commission (ROS 2 graph, lockstep)", "compensator": "identified",
                               "creep_duration_s": args.creep_duration},
                   reference_model_tau=cfg.vibration.t_r / 3.0)
    report_fits = {**_fits_report(hf, cf, df, axes), "plant": fit_plant}
    timing["total"] = time.perf_counter() - t_start
    result = {"fit_percent": report_fits, "plant_fit_basis": "measured output (recorded through the graph)",
              "orders": {"creep": cf.orders, "dynamics": df.orders},
              "before": res["before"], "after": res["after"], "hinf": res.get("hinf"),
              "tracking": res.get("tracking"), "static_error_percent": res.get("static_error_percent"),
              "conditions": {"graph": "started sim graph" if not found else "existing driver",
                             "ros_domain_id": int(os.environ["ROS_DOMAIN_ID"]), "creep_duration_s": args.creep_duration,
                             "characterisation_step_m": settings.creep_step,
                             "sine_frequency_hz": settings.sine_frequency, "sample_rate_hz": fs,
                             "generalized": bool(args.generalized), "voltage_limit_v": vlim,
                             "experiments": [e.name for e in exps]},
              "config": str(out / "config.yaml"), "recording": str(mcap_path), "hinf_note": note,
              "timing_s": {k: round(v, 2) for k, v in timing.items()}}
    print(format_tables(res, label="identified cascade (ROS graph)", axes=axes))
    print()
    print("held-out fit [%] (MATLAB compare):")
    for stage, d in report_fits.items():
        print(f"  {stage:10s} " + "  ".join(f"{k}: {'—' if v is None else f'{v:8.3f}'}" for k, v in d.items()))
    text = json.dumps(result, indent=2, default=_jsonable)
    (out / "commission.json").write_text(text)
    if args.json:
        Path(args.json).write_text(text)
    say(f"done in {timing['total']:.1f} s; recording {mcap_path}, config {out / 'config.yaml'}")
    return 0


def _order(v):
    return v if v == "auto" else int(v)


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
