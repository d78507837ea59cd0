"""``piezo-ff track``: tracking of known trajectories — open loop, the paper's cascade, + preview, + learning.

Circles 20/30 µm at 1, 10, 50 Hz, rasters 20 µm at 10 and 50 Hz lines and a spiral, on the nominal truth (model =
plant) and on mismatched truths (asymmetric hysteresis, 100 nm sensor noise, a config identified on the simulated
printed plant); RMS and max error, peak voltage and slew in one table (and ``--json``), one plot (``--plots``).
See docs/tracking.md and :mod:`piezo_ff_ros.core.tracking.benchmark`.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

from ..core.tracking.benchmark import METHODS, TRUTHS

if TYPE_CHECKING:
    from ..core.config import PiezoConfig

TARGETS = "targets (model = plant): circle 20 µm 1 Hz ≤ 0.05 µm RMS, 10 Hz ≤ 0.2 µm; raster 20 µm 10 Hz ≤ 1 % of range"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("track", help="tracking benchmark: open / cascade / preview / learning on known trajectories",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", metavar="OUT", help="write the results (contract: {'cases': [...]}) to OUT")
    p.add_argument("--plots", metavar="DIR", help="write tracking.png (and limits.png) to DIR")
    p.add_argument("--quick", action="store_true",
                   help="a few cases (20 µm circles at 1/10 Hz, 10 Hz raster, spiral), nominal+asymmetric, 4 trials")
    p.add_argument("--config", metavar="YAML", help="the printed model = the truth (default: the paper's values)")
    p.add_argument("--variant", metavar="NAME", help="named variant of the config")
    p.add_argument("--identified", metavar="YAML",
                   help="identified config for the 'identified' truth (default: identify now on the simulated "
                        "printed plant, `commission --sim-only` with 60 s creep records, ~30 s)")
    p.add_argument("--truths", default=None, metavar="LIST",
                   help=f"comma-separated subset of {','.join(TRUTHS)} (default: all; --quick: nominal,asymmetric)")
    p.add_argument("--iterations", type=int, default=None, metavar="N", help="learning trials (default 10; quick 4)")
    p.add_argument("--constrained", action="store_true",
                   help="also run the constrained-least-squares preview on the cases where the limits bind "
                        "(nominal truth; ≈ 6 min more)")
    p.add_argument("--corrections", metavar="DIR", help="store each learned correction (.npz per trajectory/truth)")
    p.add_argument("--graph", metavar="DIR", help="also play the 20 µm circle at 10 Hz (the stage of --config: its "
                   "20 µm, 10 Hz case, a sine on one axis) through the ROS node graph, "
                   "recorded to DIR/.../run.mcap and replayed: cascade and + preview on the nominal truth; cascade, "
                   "+ preview and + learning (learned through the graph from the measured displacement, stored to "
                   "DIR/learning_asymmetric/correction.npz, played by the compensator's learning.file) on the "
                   "asymmetric truth (≈ 6 graph runs, 2–4 min)")
    p.add_argument("--graph-iterations", type=int, default=2, metavar="N",
                   help="learning updates through the graph (default 2; each is one more graph run)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def _check_out(path: str | None, what: str) -> None:
    if path and Path(path).is_dir():
        raise ValueError(f"{what} {path}: is a directory, expected a file path")


def _identified_config(printed: PiezoConfig, say: Callable[[str], None]) -> PiezoConfig:
    from ..core.characterisation import CharacterisationSettings
    from ..core.commissioning import commission_sim
    from ..core.reproduce import truth_plant

    say("identify a config on the simulated printed plant (commission --sim-only, 60 s creep records)")
    cfg, _, _ = commission_sim(truth_plant(printed, "nominal"), printed.sample_rate, printed.axes,
                               CharacterisationSettings(creep_duration=60.0), base=printed)
    return cfg


def run(args: argparse.Namespace) -> int:
    from ..core.config import load_config
    from ..core.tracking.ilc import ILCConfig

    _check_out(args.json, "--json")
    if args.plots and Path(args.plots).exists() and not Path(args.plots).is_dir():
        raise ValueError(f"--plots {args.plots}: exists and is not a directory")
    truths = tuple(t.strip() for t in args.truths.split(",")) if args.truths else (
        ("nominal", "asymmetric") if args.quick else TRUTHS)
    bad = [t for t in truths if t not in TRUTHS]
    if bad or not truths:
        raise ValueError(f"--truths: unknown truth {bad[0] if bad else ''!r}; use some of {','.join(TRUTHS)}")
    if not 1 <= args.graph_iterations <= 20:
        raise ValueError(f"--graph-iterations must be in 1…20, got {args.graph_iterations}")
    if args.graph and Path(args.graph).exists() and not Path(args.graph).is_dir():
        raise ValueError(f"--graph {args.graph}: exists and is not a directory")
    if args.iterations is not None and not 0 <= args.iterations <= 100:
        raise ValueError(f"--iterations must be in 0…100, got {args.iterations}")
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    printed = load_config(args.config, args.variant)
    identified = None
    if "identified" in truths:
        identified = load_config(args.identified) if args.identified else _identified_config(printed, say)
    ilc = ILCConfig(iterations=args.iterations if args.iterations is not None else (4 if args.quick else 10))
    from ..core.tracking.benchmark import run_benchmark

    result = run_benchmark(printed, identified, quick=args.quick, truths=truths, ilc=ilc,
                           constrained=args.constrained, progress=say, corrections_dir=args.corrections)
    if args.graph:
        from .track_graph import run_graph_case, run_graph_learning

        g = Path(args.graph)
        # the stage --config describes ('' = the packaged paper's); a variant is written out as the file the nodes load
        stage_file = str(Path(args.config).resolve()) if args.config else ""
        if args.variant:
            g.mkdir(parents=True, exist_ok=True)
            stage_file = str((g / "printed.yaml").resolve())
            Path(stage_file).write_text(printed.to_yaml())
        for preview in (False, True):
            result["cases"].append(run_graph_case(g / ("preview" if preview else "cascade"), preview, say,
                                                  config_file=stage_file))
        result["cases"].append(run_graph_case(g / "cascade_asymmetric", False, say, truth="asymmetric",
                                              config_file=stage_file))
        result["cases"].extend(run_graph_learning(g / "learning_asymmetric", "asymmetric", args.graph_iterations,
                                                  say=say, config_file=stage_file))
    result["targets"] = check_targets(result)
    print(format_table(result))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=1, default=float))
        say(f"wrote {args.json}")
    if args.plots:
        from .track_plots import plot_all

        for p in plot_all(result, Path(args.plots)):
            say(f"wrote {p}")
    return 0


def _row(result: Mapping[str, Any], **key: Any) -> dict[str, Any] | None:
    for c in result["cases"]:
        if all(c.get(k) == v for k, v in key.items()) and not c.get("variant") and not c.get("graph"):
            return c
    return None


def check_targets(result: dict) -> dict:
    """The issue's targets, each ``{value, limit, pass}`` (None when the case was not run)."""
    out = {}
    for f, lim in ((1, 0.05), (10, 0.2)):
        c = _row(result, trajectory="circle", size_um=20, frequency_hz=f, method="preview", truth="nominal")
        out[f"circle_20um_{f}hz_preview_rms_um"] = None if c is None else {
            "value": c["rms_error_um"], "limit": lim, "pass": c["rms_error_um"] <= lim and c["peak_voltage_v"] <= 200.0}
    c = _row(result, trajectory="raster", size_um=20, frequency_hz=10, method="preview", truth="nominal")
    pct = None if c is None else 100 * c["max_error_um"] / c["size_um"]
    out["raster_20um_10hz_preview_max_percent_of_range"] = None if pct is None else {
        "value": pct, "limit": 1.0, "pass": pct <= 1.0}
    vlim = result["conditions"]["voltage_limit_v"]
    ratios = []
    for c in result["cases"]:
        if c["method"] == "learning" and c["truth"] != "nominal":
            key = dict(trajectory=c["trajectory"], size_um=c["size_um"], frequency_hz=c["frequency_hz"])
            k = _row(result, method="cascade", truth=c["truth"], **key)
            p = _row(result, method="preview", truth=c["truth"], **key)
            if k is None:
                raise RuntimeError(f"no cascade case for {key} / {c['truth']} (the learning case is compared with it)")
            ratios.append({"case": f"{c['trajectory']} {c['size_um']:g} µm {c['frequency_hz']:g} Hz / {c['truth']}",
                           "cascade_over_learning": k["rms_error_um"] / max(c["rms_error_um"], 1e-12),
                           # the exact shaped reference would ask more than the amplifier gives: no feedforward
                           # can follow it, the error floor is the clipping's
                           "voltage_bound": bool(p and p.get("asked_peak_voltage_v", 0.0) > vlim)})
    feasible = [r for r in ratios if not r["voltage_bound"]]
    out["learning_5x_below_cascade_mismatched"] = {
        "min_ratio": min((r["cascade_over_learning"] for r in feasible), default=None), "limit": 5.0,
        "pass": all(r["cascade_over_learning"] >= 5 for r in feasible) if feasible else None,
        "failing": [r for r in feasible if r["cascade_over_learning"] < 5],
        "voltage_bound": [r for r in ratios if r["voltage_bound"]]}
    return out


def physical_limit_lines(result: dict) -> list[str]:
    """The voltage and slew limits found: what the exact shaped references ask (model = plant) vs the amplifier."""
    cond = result["conditions"]
    vlim, slim = cond["voltage_limit_v"], cond["slew_limit_v_per_s"]
    nominal = [c for c in result["cases"] if c["method"] == "preview" and c["truth"] == "nominal"
               and not c.get("variant") and not c.get("graph") and "asked_peak_voltage_v" in c]
    lines = []
    if nominal:
        bound = [c for c in nominal if c["asked_peak_voltage_v"] > vlim]
        free = [c for c in nominal if c["asked_peak_voltage_v"] <= vlim]
        lines.append(f"physical limits (model = plant): voltage ±{vlim:g} V — " + (
            "voltage-bound: the exact shaped reference asks " + ", ".join(
                f"{_label(c)} {c['asked_peak_voltage_v']:.0f} V (clipped to {c['peak_voltage_v']:.0f} V → "
                f"{c['rms_error_um']:.3g} µm RMS floor)" for c in bound) if bound else "never binds"))
        if free:
            top = max(free, key=lambda c: c["asked_peak_voltage_v"])
            lines.append(f"  within the limit: at most {top['asked_peak_voltage_v']:.0f} V asked ({_label(top)})")
    peak = max(result["cases"], key=lambda c: c["peak_slew_v_per_s"], default=None)
    if peak is not None:
        lines.append(f"  slew limit {slim / 1e3:g} V/ms: at most {peak['peak_slew_v_per_s'] / 1e3:.3g} V/ms used "
                     f"({_label(peak)}, {peak['method']}: {100 * peak['peak_slew_v_per_s'] / slim:.2g} % of it)")
    return lines


def _label(c: dict) -> str:
    return f"{c['trajectory']} {c['size_um']:g} µm {c['frequency_hz']:g} Hz"


def format_table(result: dict) -> str:
    vlim = result["conditions"]["voltage_limit_v"]
    lines = [f"{'trajectory':<22}{'truth':<12}{'method':<16}{'RMS µm':>10}{'max µm':>10}{'peak V':>9}{'slew V/ms':>11}"]
    for c in result["cases"]:
        label = f"{c['trajectory']} {c['size_um']:g} µm {c['frequency_hz']:g} Hz"
        meth = c["method"] + ("*" if c.get("variant") else "") + (" (graph)" if c.get("graph") else "")
        clip = "†" if c["peak_voltage_v"] >= vlim - 1e-6 else " "
        lines.append(f"{label:<22}{c['truth']:<12}{meth:<16}{c['rms_error_um']:>10.4g}{c['max_error_um']:>10.4g}"
                     f"{c['peak_voltage_v']:>8.1f}{clip}{c['peak_slew_v_per_s'] / 1e3:>11.2f}")
    lines.append("* preview with the receding-horizon constrained least-squares (the limits bind)")
    lines.append(f"† the voltage reached the amplifier's ±{vlim:g} V limit (clipped)")
    lines.extend(physical_limit_lines(result))
    lim = result["limits"]
    lines.append("")
    lines.append("preview horizon needed (circle 20 µm 10 Hz, model = plant): " + ", ".join(
        f"{s['horizon_s'] * 1e3:g} ms → {s['rms_error_um']:.3g} µm" for s in lim["horizon_sweep_circle20um_10hz"]))
    k = lim["kernel"]
    lines.append(f"inverse kernel: anticausal part above 1e-3 / 1e-6 of its peak over {k['anticausal_lags_1e-3']} / "
                 f"{k['anticausal_lags_1e-6']} samples; causal {k['causal_lags_1e-3']} / {k['causal_lags_1e-6']}")
    rhp = {a: [round(complex(*z).real) for z in zs] for a, zs in lim["g_l_rhp_zeros_rad_s"].items()}
    lines.append(f"G_L right-half-plane zeros, real parts [rad/s]: {rhp}")
    for name, c in lim["learning_condition"].items():
        lines.append(f"learning condition ({name}): ρ = {c['rho']:.3g} (peak at {c['f_peak_hz']:.0f} Hz), "
                     f"without Q {c['rho_without_q']:.3g}")
    v = lim["learning_violation"]
    lines.append(f"condition violated on purpose ({v['truth']}, {v['case']}):")
    for name, run in v["runs"].items():
        h = run["rms_history_um"]
        lines.append(f"  {name:<16} ρ = {run['condition']['rho']:.3g}  RMS per trial µm: "
                     + " ".join(f"{x:.3g}" for x in h) + f"  (guard events {run['guard_events']})")
    lines.append("")
    lines.append(TARGETS)
    for name, t in result.get("targets", {}).items():
        if t is None:
            lines.append(f"  {name}: not run")
        elif "value" in t:
            lines.append(f"  {name}: {t['value']:.4g} (limit {t['limit']:g}) {'PASS' if t['pass'] else 'FAIL'}")
        else:
            fail = ", ".join(f"{r['case']} ×{r['cascade_over_learning']:.2g}" for r in t["failing"])
            lines.append(f"  {name}: min ratio {t['min_ratio'] if t['min_ratio'] is None else round(t['min_ratio'], 1)}"
                         f" over the cases within the voltage limit {'PASS' if t['pass'] else 'FAIL'}"
                         f"{' — ' + fail if fail else ''}")
            if t["voltage_bound"]:
                lines.append("    beyond the voltage limit (the exact shaped reference asks > "
                             f"{result['conditions']['voltage_limit_v']:g} V; not counted): " + ", ".join(
                                 f"{r['case']} ×{r['cascade_over_learning']:.2g}" for r in t["voltage_bound"]))
    return "\n".join(lines)
