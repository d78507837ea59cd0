"""``piezo-ff bench``: throughput of every core stage and of the full chain, next to naive baselines.

Every stage is run the way the nodes run it — streaming blocks with carried state — on a periodic 2-axis signal
(10 s buffer replayed; tones at 0.1, 1 and 13 Hz: creep-, scan- and vibration-range), and timed by wall clock,
best of ``--repeats`` (the machine may be shared; CPU time is reported too).  In the same run, the same maths is
timed done naively on a short slice (``--baseline-duration``) and extrapolated:

* a plain per-sample Python loop (numpy per sample) for every stage, linear parts as dense ``x ← A x + B u`` with
  (A, B, C, D) from ``control.c2d(…, 'zoh')`` of the continuous realisation;
* python-control's ``forced_response`` on those ZOH-discretised linear parts (the nonlinear stages stay as loops).

A *sample* is one time step of both axes; the real-time factor is simulated seconds per wall second at the
config's sample rate (20 kHz).  The first call of each compiled kernel (numba cache load or compile) is timed
separately from the steady-state throughput.

Run as ``piezo-ff bench [--json FILE] [--duration S]`` or ``python bench/bench_core.py``.  The measurement and the
naive baselines live in :mod:`piezo_ff_ros.bench.throughput`; this module is the command line and the report.
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Sequence

import numpy as np

from ..bench.throughput import run_benchmark

__all__ = ["add_parser", "run", "run_benchmark", "main", "format_report"]


# ----------------------------------------------------------------------------------------------------------------
# CLI
# ----------------------------------------------------------------------------------------------------------------

def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "bench", help="throughput of the core stages and the full chain vs naive baselines",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", metavar="FILE", help="also write the figures to FILE (JSON)")
    p.add_argument("--duration", type=float, default=600.0, metavar="S",
                   help="simulated seconds per stage and repeat (default 600, the length of a creep experiment)")
    p.add_argument("--repeats", type=int, default=3, metavar="N", help="timed repeats, best reported (default 3)")
    p.add_argument("--block", type=int, default=20000, metavar="N",
                   help="samples per process() call (default 20000 = 1 s at 20 kHz: offline simulation, where "
                        "per-call overhead is negligible; see --small-block for node-sized blocks)")
    p.add_argument("--small-block", type=int, default=200, metavar="N",
                   help="block size of an extra full-chain run with node-sized blocks, at most 60 s simulated "
                        "(default 200 = 10 ms; 0 = skip)")
    p.add_argument("--baseline-duration", type=float, default=0.5, metavar="S",
                   help="simulated seconds run by the naive baselines, extrapolated (default 0.5)")
    p.add_argument("--config", metavar="YAML", help="piezo config (default: the paper's PT230.94 values)")
    p.add_argument("--variant", help="config variant (e.g. gyx_gain_div10)")
    p.add_argument("--no-hinf", action="store_true",
                   help="skip the H∞ synthesis; the chain then uses a balanced-truncation stand-in controller")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    res = run_benchmark(duration=args.duration, repeats=args.repeats, block=args.block,
                        small_block=args.small_block, baseline_duration=args.baseline_duration,
                        config=args.config, variant=args.variant, hinf=not args.no_hinf, echo=True)
    print(format_report(res))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=2)
            fh.write("\n")
        print(f"\nwritten {args.json}")
    return 0


def _check_args(args: argparse.Namespace) -> None:
    if not np.isfinite(args.duration) or args.duration <= 0:
        raise ValueError("--duration must be a positive number of seconds")
    if args.repeats < 1:
        raise ValueError("--repeats must be at least 1")
    if args.block < 1:
        raise ValueError("--block must be at least 1 sample")
    if args.small_block < 0:
        raise ValueError("--small-block must be 0 (skip) or a number of samples")
    if not np.isfinite(args.baseline_duration) or args.baseline_duration <= 0:
        raise ValueError("--baseline-duration must be a positive number of seconds")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``bench/bench_core.py`` (same options as ``piezo-ff bench``)."""
    parser = argparse.ArgumentParser(prog="bench_core.py")
    sub = parser.add_subparsers(dest="command")
    add_parser(sub)
    args = parser.parse_args(["bench", *(sys.argv[1:] if argv is None else argv)])
    try:
        return run(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"bench: error: {exc}", file=sys.stderr)
        return 2


# ----------------------------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------------------------

def _fmt_x(x: float, width: int = 8) -> str:
    """A factor: whole numbers when large, two decimals when small."""
    return f"{x:{width}.0f}" if x >= 10 else f"{x:{width}.2f}"


def _fmt_rate(r: float) -> str:
    return f"{r / 1e6:8.2f} M" if r >= 1e5 else f"{r / 1e3:8.1f} k"


def format_report(res: dict[str, Any]) -> str:
    fs = res["sample_rate"]
    m = res["machine"]
    lines = [
        f"core chain throughput at {fs:g} Hz, 2 axes — {res['duration_s']:g} s simulated per stage, "
        f"blocks of {res['block']}, best of {next(iter(res['stages'].values()))['repeats']} (wall clock)",
        f"machine: {m['cpu']}, {m['cpu_count']} CPUs, load {m['loadavg_1_5_15']} → {m['loadavg_end']}; "
        f"python {m['python']}, numpy {m['numpy']}, numba {m['numba']}, control {m['control']}"
        + ("" if res["numba"] else "  [numba MISSING: pure-Python fallback]"),
        f"controller: {res['controller']['controller']} (order {res['controller']['controller_order']})",
        "",
        f"{'stage':38s} {'compiled':>11s} {'RT×':>8s} {'cpu RT×':>8s} | {'Python loop':>11s} {'RT×':>6s}"
        f" {'speed-up':>8s} | {'forced_resp.':>11s} {'RT×':>6s} | {'max rel diff':>12s}",
    ]
    for name, r in res["stages"].items():
        row = (f"{r['label'][:38]:38s} {_fmt_rate(r['samples_per_s'])}/s {_fmt_x(r['rt_factor'])} "
               f"{_fmt_x(r['cpu_rt_factor'])} |")
        nv = r.get("naive")
        fr = r.get("forced_response")
        row += (f" {_fmt_rate(nv['samples_per_s'])}/s {nv['rt_factor']:6.2f} "
                f"{_fmt_x(r['samples_per_s'] / nv['samples_per_s'], 7)}× |"
                if nv else f" {'':11s} {'':6s} {'':8s} |")
        row += f" {_fmt_rate(fr['samples_per_s'])}/s {fr['rt_factor']:6.2f} |" if fr else f" {'':11s} {'':6s} |"
        diffs = [x["max_rel_diff"] for x in (nv, fr) if x]
        row += f" {max(diffs):12.1e}" if diffs else ""
        lines.append(row)
    fc = res["stages"]["full_chain"]
    lines += [
        "",
        f"full chain: {_fmt_x(res['full_chain_rt_factor'], 0)}× real time → a 600 s experiment in "
        f"{res['full_chain_s_per_600s']:.2f} s (target ≥ 500×, ≤ 1.2 s); per core of CPU time "
        f"{_fmt_x(res['full_chain_cpu_rt_factor'], 0)}× ({600.0 / res['full_chain_cpu_rt_factor']:.2f} s); "
        f"naive per-sample Python loop "
        f"{res['baseline_rt_factor']:.2f}×, with forced_response for the linear parts "
        f"{res['baseline_forced_response_rt_factor']:.2f}× "
        f"(baselines on {res['baseline_duration_s']:g} s, extrapolated)",
        *([f"full chain, {res['stages']['full_chain_small_blocks']['block']}-sample blocks: "
           f"{_fmt_x(res['stages']['full_chain_small_blocks']['rt_factor'], 0)}× real time (target ≥ 400×)"]
          if "full_chain_small_blocks" in res["stages"] else []),
        f"H∞ synthesis + reduction: "
        + (f"{res['hinf_synthesis_s']:.2f} s (target ≤ 10 s; wall {res['controller']['hinf_wall_s']:.2f} s "
           f"including the design's own frequency-grid verification; "
           f"CPU {res['controller']['hinf_cpu_s']:.2f} s)"
           if res["hinf_synthesis_s"] is not None else f"not measured — {res['controller']['note']}"),
        f"warm-up (not in the throughput): imports {res['import_s']:.2f} s; first call per stage "
        + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in res["jit"]["first_call_s"].items()),
        "numba cache: " + ", ".join(f"{k.split('.')[-1]} {v['cache_hits']} hit/{v['cache_misses']} miss"
                                    for k, v in res["jit"]["cache_after"].items()
                                    if v["cache_hits"] or v["cache_misses"]),
    ]
    return "\n".join(lines)
