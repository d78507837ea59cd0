"""``piezo-ff commission``: characterise → identify → synthesise → verify, in one command (paper Fig. 3).

On the simulated actuator (``--sim-only``; the paper's printed models as the truth, optionally with sensor noise
or asymmetric hysteresis): the characterisation experiments run stage by stage, each through the compensators
identified before it (sines on S0 → Bouc-Wen; long steps on S_H → K, Cr(s); steps on S_L → G_L(s)); the H∞
compensator is synthesised from the identified G_L; then the paper's tests (Sections IV–VII) run on the same truth
through the cascade built from the identified parameters, and Tables I/II are printed before/after compensation
(and, unless ``--no-compare``, next to the cascade built from the printed parameters).  Every fit is measured on
held-out data.  Writes ``DIR/config.yaml`` (loadable by the compensator node), ``DIR/commission.json`` and, with
``--json F``, the same JSON to F.

Against the ROS node graph (a running driver, recording to MCAP and pushing the parameters live to the compensator
node) commissioning is not implemented yet: use ``--sim-only``, or record the characterisation runs and use
``piezo-ff identify``.
"""
from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from pathlib import Path


def add_parser(subparsers):
    p = subparsers.add_parser("commission", help="characterise, identify, synthesise and verify in one command",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("--sim-only", action="store_true",
                   help="commission the simulated actuator with the core simulator (no ROS graph)")
    p.add_argument("--out", default="commission_out", metavar="DIR",
                   help="directory for config.yaml and commission.json (default ./commission_out)")
    p.add_argument("--json", default=None, metavar="F", help="also write the JSON result to F")
    p.add_argument("--creep-duration", type=float, default=600.0, metavar="S",
                   help="creep step duration, up and down, in the characterisation and the verification "
                        "(paper: 600 s; 60–120 s for a quick run)")
    p.add_argument("--noise-nm", type=float, default=0.0, metavar="NM", help="sensor noise of the simulated truth")
    p.add_argument("--truth", choices=("nominal", "asymmetric"), default="nominal",
                   help="simulated truth: the printed models, or with generalized (asymmetric) hysteresis")
    p.add_argument("--generalized", action="store_true", help="identify the generalized (asymmetric) Bouc-Wen")
    p.add_argument("--creep-order", default="auto", help="creep order per entry (int) or 'auto'")
    p.add_argument("--dynamics-order", default="auto", help="G_L order per entry (int) or 'auto'")
    p.add_argument("--no-compare", action="store_true",
                   help="skip the verification of the cascade built from the printed parameters")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated truth")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)
    return p


def _order(v):
    return v if v == "auto" else int(v)


def _verify(cfg, design, truth_plant, creep_duration, noise_std, say, label):
    from ..core.experiments import paper_experiments, simulate_experiments
    from ..core.reproduce import evaluate

    exps = paper_experiments(cfg, creep_duration=creep_duration)
    rec = simulate_experiments(cfg, design=design, plant=truth_plant, experiments=exps,
                               progress=lambda name: say(f"verify ({label}): {name}"))
    return evaluate(rec, exps, design=design, robust=noise_std > 0,
                    conditions={"compensator": label, "noise_std_m": noise_std, "creep_duration_s": creep_duration},
                    reference_model_tau=cfg.vibration.t_r / 3.0)


def run(args) -> int:
    from ..core.characterisation import CharacterisationSettings
    from ..core.config import load_config
    from ..core.identification.pipeline import commission_sim
    from ..core.reproduce import format_tables, truth_plant

    if not args.sim_only:
        raise ValueError("commissioning through the ROS node graph is not implemented yet; use --sim-only "
                         "(core simulator), or record the characterisation runs and run 'piezo-ff identify'")
    if not (math.isfinite(args.creep_duration) and args.creep_duration > 1.0):
        raise ValueError(f"--creep-duration must be > 1 s, got {args.creep_duration}")
    if not (math.isfinite(args.noise_nm) and args.noise_nm >= 0):
        raise ValueError(f"--noise-nm must be a non-negative number, got {args.noise_nm}")
    t_start = time.perf_counter()

    def say(msg):
        if not args.quiet:
            print(f"[{time.perf_counter() - t_start:7.1f} s] {msg}", file=sys.stderr, flush=True)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    printed = load_config()
    noise = args.noise_nm * 1e-9
    truth = truth_plant(printed, args.truth, noise, seed=args.seed)
    settings = CharacterisationSettings(creep_duration=args.creep_duration)
    cfg, report, _runs = commission_sim(truth, printed.sample_rate, printed.axes, settings=settings, base=printed,
                                        generalized=args.generalized, creep_order=_order(args.creep_order),
                                        dynamics_order=_order(args.dynamics_order), progress=say)
    t0 = time.perf_counter()
    say("vibration: H∞ synthesis on the identified G_L")
    from ..core.identification.pipeline import synthesize_for

    design, note = synthesize_for(cfg, say)
    report["timing_s"]["hinf"] = time.perf_counter() - t0
    if note:
        cfg = dataclasses.replace(cfg, vibration=dataclasses.replace(cfg.vibration,
                                                                     gamma_max=1.05 * float(design.gamma)))
    cfg = dataclasses.replace(cfg, vibration=dataclasses.replace(
        cfg.vibration, controller=design.controller_matrices())).validate()
    cfg_path = out / "config.yaml"
    cfg.to_yaml(cfg_path)
    load_config(cfg_path)  # what the compensator node will do: fails loudly if the file is not loadable
    say(f"wrote {cfg_path}")

    t0 = time.perf_counter()
    res = _verify(cfg, design, truth, args.creep_duration, noise, say, "identified")
    report["timing_s"]["verify"] = time.perf_counter() - t0
    result = {"fit_percent": report["fit_percent"], "orders": report["orders"],
              "before": res["before"], "after": res["after"], "hinf": res["hinf"], "tracking": res["tracking"],
              "static_error_percent": res["static_error_percent"], "errors": res["errors"],
              "conditions": {"truth": args.truth, "noise_std_m": noise, "creep_duration_s": args.creep_duration,
                             "sample_rate_hz": printed.sample_rate, "generalized": bool(args.generalized)},
              "config": str(cfg_path), "hinf_note": note}
    print(format_tables(res, label="identified cascade", axes=printed.axes))
    if not args.no_compare:
        t0 = time.perf_counter()
        ref = _verify(printed, None, truth, args.creep_duration, noise, say, "printed")
        report["timing_s"]["verify_printed"] = time.perf_counter() - t0
        result["after_printed"] = ref["after"]
        result["hinf_printed"] = ref["hinf"]
        print()
        print("after compensation [%]          identified   printed parameters")
        for key, per_axis in res["after"].items():
            for a, v in per_axis.items():
                w = ref["after"][key][a]
                print(f"  {key:<24} {a}  {_f(v)}   {_f(w)}")
    result["timing_s"] = {k: round(v, 2) for k, v in report["timing_s"].items()}
    print()
    print("held-out fit [%] (MATLAB compare):")
    for stage, d in report["fit_percent"].items():
        print(f"  {stage:10s} " + "  ".join(f"{k}: {_f(v)}" for k, v in d.items()))
    text = json.dumps(result, indent=2, default=_jsonable)
    (out / "commission.json").write_text(text)
    if args.json:
        Path(args.json).write_text(text)
    say(f"done in {time.perf_counter() - t_start:.1f} s")
    return 0


def _f(v):
    return "—" if v is None else f"{v:8.3f}"


def _jsonable(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
