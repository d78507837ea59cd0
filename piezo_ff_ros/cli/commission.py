"""``piezo-ff commission``: characterise → identify → synthesise → verify, in one command (paper Fig. 3).

On the simulated actuator (``--sim-only``; the paper's printed models as the truth, optionally with sensor noise
or asymmetric hysteresis): the characterisation experiments run stage by stage, each through the compensators
identified before it (sines on S0 → Bouc-Wen; long steps on S_H → K, Cr(s); steps on S_L → G_L(s)); the H∞
compensator is synthesised from the identified G_L; then the paper's tests (Sections IV–VII) run on the same truth
through the cascade built from the identified parameters, and Tables I/II are printed before/after compensation
(and, unless ``--no-compare``, next to the cascade built from the printed parameters).  Every fit is measured on
held-out data.  Writes ``DIR/config.yaml`` (loadable by the compensator node), ``DIR/commission.json`` and, with
``--json F``, the same JSON to F.

Both paths run one sequence (:mod:`piezo_ff_ros.core.commissioning`) over a rig: the simulated plant
(:class:`~piezo_ff_ros.core.commissioning.SimRig`) or, without ``--sim-only``, the ROS 2 node graph
(:mod:`piezo_ff_ros.ros.commission`): against a running driver (any backend with a displacement sensor), or — with
none on the domain — a sim graph it starts itself; each identified stage is
pushed live to the compensator node before the next is characterised, everything is recorded to
``DIR/commission.mcap``, then the paper's tests are played through the graph with the identified cascade.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

if TYPE_CHECKING:
    from ..core.config import PiezoConfig
    from ..core.reproduce import ReproduceResult
    from ..core.stage import Processor


#: exit code of a refused identification (a held-out fit below the floor, no --accept-poor-fit)
EXIT_POOR_FIT = 3
#: the options of the ROS graph path and their defaults (given otherwise with --sim-only: one warning line)
GRAPH_ONLY: dict[str, Any] = {"domain_id": None, "probe_timeout": 3.0, "step_um": 15.0, "only": None,
                              "block_size": 2000, "voltage_limit": None}
#: = core.commissioning.FIT_FLOOR_PERCENT (not imported here: the parser is built without loading the core)
FIT_FLOOR = 50.0


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser("commission", help="characterise, identify, synthesise and verify in one command",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("--sim-only", action="store_true",
                   help="commission the simulated actuator with the core simulator (no ROS graph)")
    p.add_argument("--out", default="commission_out", metavar="DIR",
                   help="directory for config.yaml and commission.json (default ./commission_out)")
    p.add_argument("--json", default=None, metavar="F", help="also write the JSON result to F")
    p.add_argument("--creep-duration", type=float, default=None, metavar="S",
                   help="creep step duration, up and down, in the characterisation and the verification "
                        "(paper: 600 s; default 600 with --sim-only, 60 through the ROS graph)")
    p.add_argument("--noise-nm", type=float, default=0.0, metavar="NM", help="sensor noise of the simulated truth")
    p.add_argument("--truth", choices=("nominal", "asymmetric"), default="nominal",
                   help="simulated truth: the printed models, or with generalized (asymmetric) hysteresis")
    p.add_argument("--generalized", action="store_true", help="identify the generalized (asymmetric) Bouc-Wen")
    p.add_argument("--creep-order", default="auto", help="creep order per entry (int) or 'auto'")
    p.add_argument("--dynamics-order", default="auto", help="G_L order per entry (int) or 'auto'")
    p.add_argument("--no-compare", action="store_true",
                   help="skip the verification of the cascade built from the printed parameters")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated truth")
    p.add_argument("--config", metavar="YAML",
                   help="starting config: the stage's axes (1 to 6), name, weights and limits; with --sim-only also "
                        "the simulated truth (default: the paper's printed values, 2 axes)")
    p.add_argument("--variant", metavar="NAME", help="named variant of the starting config")
    p.add_argument("--accept-poor-fit", action="store_true",
                   help="keep an identification whose held-out fit (hysteresis per axis, creep and G_L diagonal, "
                        f"whole plant) is below the floor ({FIT_FLOOR:g} %%) instead of refusing it (exit code "
                        f"{EXIT_POOR_FIT}, nothing written or applied)")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--sine-frequency", type=float, default=0.1, metavar="HZ",
                   help="hysteresis characterisation sine frequency (paper 0.1 Hz)")
    p.add_argument("--sine-periods", type=int, default=2, metavar="N", help="periods per hysteresis sine (2)")
    g = p.add_argument_group("ROS graph (without --sim-only)")
    g.add_argument("--domain-id", type=int, metavar="ID",
                   help="ROS_DOMAIN_ID to look for a driver on and to start the sim graph on (default: look on the "
                        "caller's domain; start the sim graph on a private one)")
    g.add_argument("--probe-timeout", type=float, default=GRAPH_ONLY["probe_timeout"], metavar="S",
                   help="how long to look for a running driver (default 3 s)")
    g.add_argument("--step-um", type=float, default=GRAPH_ONLY["step_um"], metavar="UM",
                   help="creep/dynamics characterisation step, µm (default 15: keeps the step well inside the ±200 V "
                        "amplifier on a stage stiffer than the paper's — its 20 µm asks ≈ 159 V on x — since a "
                        "clamped step biases the creep fit)")
    g.add_argument("--only", metavar="NAMES", help="verification: comma-separated experiment names (default: all)")
    g.add_argument("--block-size", type=int, default=GRAPH_ONLY["block_size"], metavar="N",
                   help="samples per block (default 2000)")
    g.add_argument("--voltage-limit", type=float, default=None, metavar="V",
                   help="driver/compensator voltage limit (default: the config's limits.voltage)")
    p.set_defaults(func=run)
    return p


def _verify(cfg: PiezoConfig, design: object, truth_plant: Processor, creep_duration: float, noise_std: float,
            say: Callable[[str], None], label: str) -> ReproduceResult:
    from ..core.commissioning import SimRig, verify
    from ..core.experiments import paper_experiments

    exps = paper_experiments(cfg, creep_duration=creep_duration)
    rig = SimRig(truth_plant, cfg.sample_rate, cfg.axes)
    return verify(rig, cfg, design, exps, robust=noise_std > 0,
                  conditions={"compensator": label, "noise_std_m": noise_std, "creep_duration_s": creep_duration},
                  progress=lambda m: say(f"{m} ({label})"))


#: "within 10 %" of the printed cascade's figure: the identified cascade's |figure| may exceed the printed one's by
#: at most max(10 % of |printed|, 0.1 percentage point) — the absolute floor because several printed figures are
#: ≈ 0 %, where 10 % of the figure is below the sim's resolution.  Lower is better for every after-figure.
AFTER_REL_TOL = 0.10
AFTER_ABS_TOL_PP = 0.1


def after_vs_printed(after: Mapping[str, Mapping[str, float | None]],
                     after_printed: Mapping[str, Mapping[str, float | None]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per figure and axis: identified, printed, Δ, the allowance and ``pass`` (see :data:`AFTER_REL_TOL`).

    ``pass`` is one-sided (the identified cascade may do better than the printed one by any margin);
    ``within_two_sided`` says whether |Δ| itself is within the allowance.
    """
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for key, per_axis in after.items():
        for a, v in per_axis.items():
            w = (after_printed.get(key) or {}).get(a)
            if v is None or w is None:
                out.setdefault(key, {})[a] = {"identified": v, "printed": w, "pass": None}
                continue
            allow = max(AFTER_REL_TOL * abs(w), AFTER_ABS_TOL_PP)
            out.setdefault(key, {})[a] = {
                "identified": round(float(v), 4), "printed": round(float(w), 4), "delta": round(float(v - w), 4),
                "allowance": round(allow, 4), "pass": bool(abs(v) <= abs(w) + allow),
                "within_two_sided": bool(abs(v - w) <= allow)}
    return out


def run(args: argparse.Namespace) -> int:
    from ..core.characterisation import CharacterisationSettings
    from ..core.config import load_config
    from ..core.commissioning import PoorFitError, SimRig, commission, save_config, save_report
    from ..core.jsonable import parse_order
    from ..core.reproduce import format_tables, truth_plant
    from . import output_dir

    output_dir(args.out, "--out")  # before minutes of work, not after
    if args.creep_duration is None:
        args.creep_duration = 600.0 if args.sim_only else 60.0
    if not (math.isfinite(args.creep_duration) and args.creep_duration > 1.0):
        raise ValueError(f"--creep-duration must be > 1 s, got {args.creep_duration}")
    if not (math.isfinite(args.noise_nm) and args.noise_nm >= 0):
        raise ValueError(f"--noise-nm must be a non-negative number, got {args.noise_nm}")
    t_start = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t_start:7.1f} s] {msg}", file=sys.stderr, flush=True)

    _check_sine_args(args)
    if not args.sim_only:
        _check_graph_args(args)
        from ..core.commissioning import PoorFitError
        from ..ros.commission import run_graph

        try:
            return run_graph(args, say)
        except PoorFitError as exc:
            return _refused(exc)
        except (RuntimeError, TimeoutError) as exc:   # a node died, a service timed out…: one clear message
            print(f"piezo-ff commission: error: {exc}", file=sys.stderr)
            return 1

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    printed = load_config(args.config, variant=args.variant)   # the stage to commission: truth and starting point
    noise = args.noise_nm * 1e-9
    truth = truth_plant(printed, args.truth, noise, seed=args.seed)
    ignored = [name for name, default in GRAPH_ONLY.items() if getattr(args, name) != default]
    if ignored:
        print("piezo-ff commission: warning: ROS graph options ignored with --sim-only: "
              + ", ".join("--" + n.replace("_", "-") for n in ignored), file=sys.stderr)
    settings = CharacterisationSettings(creep_duration=args.creep_duration, sine_frequency=args.sine_frequency,
                                        sine_periods=args.sine_periods)
    try:
        result = commission(SimRig(truth, printed.sample_rate, printed.axes), base=printed, settings=settings,
                            generalized=args.generalized, creep_order=parse_order(args.creep_order),
                            dynamics_order=parse_order(args.dynamics_order), progress=say,
                            accept_poor_fit=args.accept_poor_fit)
    except PoorFitError as exc:
        return _refused(exc)
    cfg, design, note, report = result.config, result.design, result.hinf_note, result.report
    cfg_path = out / "config.yaml"
    save_config(cfg, cfg_path)
    say(f"wrote {cfg_path}")

    t0 = time.perf_counter()
    res = _verify(cfg, design, truth, args.creep_duration, noise, say, "identified")
    timing = {**report.timing_s, "verify": time.perf_counter() - t0}
    out_json: dict[str, Any] = {"fit_percent": report.fit_percent, "orders": report.orders,
              "before": res.before, "after": res.after, "hinf": res.hinf, "tracking": res.tracking,
              "static_error_percent": res.static_error_percent, "errors": res.errors,
              "conditions": {"truth": args.truth, "noise_std_m": noise, "creep_duration_s": args.creep_duration,
                             "sine_frequency_hz": settings.sine_frequency, "sine_periods": settings.sine_periods,
                             "sample_rate_hz": printed.sample_rate, "generalized": bool(args.generalized)},
              "config": str(cfg_path), "hinf_note": note,
              "plant_fit_basis": report.plant_fit_basis}
    if report.plant_fit_noise_free is not None:
        out_json["plant_fit_noise_free"] = report.plant_fit_noise_free
    out_json["plant_fit_parts"] = report.plant_fit_parts
    if report.accepted_poor_fits:
        out_json["accepted_poor_fits"] = report.accepted_poor_fits
    if res.cross_coupling_pairs_percent is not None:   # three axes or more: Table II per ordered pair
        out_json["cross_coupling_pairs_percent"] = res.cross_coupling_pairs_percent
    print(format_tables(res, label="identified cascade", axes=printed.axes))
    if not args.no_compare:
        t0 = time.perf_counter()
        ref = _verify(printed, None, truth, args.creep_duration, noise, say, "printed")
        timing["verify_printed"] = time.perf_counter() - t0
        out_json["after_printed"] = ref.after
        out_json["hinf_printed"] = ref.hinf
        cmp = after_vs_printed(res.after, ref.after)
        out_json["after_vs_printed"] = cmp
        out_json["after_vs_printed_rule"] = (f"pass if |identified| <= |printed| + max({AFTER_REL_TOL:g}*|printed|, "
                                             f"{AFTER_ABS_TOL_PP:g} pp)")
        print()
        print(f"{'after compensation [%]':<32}{'identified':>12}{'printed parameters':>20}   within 10 % / 0.1 pp")
        for key, per_axis in cmp.items():
            for a, c in per_axis.items():
                verdict = "—" if c["pass"] is None else ("pass" if c["pass"] else "FAIL")
                print(f"  {key:<24} {a:<4}{_f(c['identified']):>12}{_f(c['printed']):>20}   {verdict}")
    out_json["timing_s"] = {k: round(v, 2) for k, v in timing.items()}
    print()
    print(report.format_fits())
    save_report(out_json, out, args.json)
    say(f"done in {time.perf_counter() - t_start:.1f} s")
    return 0


def _refused(exc: Exception) -> int:
    """One line for an identification refused for a held-out fit below the floor; its exit code."""
    print(f"piezo-ff commission: refused: {exc}", file=sys.stderr)
    return EXIT_POOR_FIT


def _check_sine_args(args: argparse.Namespace) -> None:
    if not (math.isfinite(args.sine_frequency) and args.sine_frequency > 0):
        raise ValueError(f"--sine-frequency must be a positive number, got {args.sine_frequency}")
    if args.sine_periods < 1:
        raise ValueError(f"--sine-periods must be >= 1, got {args.sine_periods}")


def _check_graph_args(args: argparse.Namespace) -> None:
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        raise ValueError(f"--domain-id must be in 0..232, got {args.domain_id}")
    for name in ("probe_timeout", "step_um"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"--{name.replace('_', '-')} must be a positive number, got {v}")
    if not 1 <= args.block_size <= 20000:
        raise ValueError(f"--block-size must be in 1..20000, got {args.block_size}")
    if args.voltage_limit is not None and not (math.isfinite(args.voltage_limit) and args.voltage_limit > 0):
        raise ValueError(f"--voltage-limit must be a positive number, got {args.voltage_limit}")


def _f(v: float | None) -> str:
    return "—" if v is None else f"{v:8.3f}"
