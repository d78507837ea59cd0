"""``piezo-ff analyze RUN.mcap [--json FILE] [--plots DIR]``: replay analysis of a recorded run.

Reads any ROS 2 MCAP (or rosbag2 directory) of the topic contract, segments it by the ``experiment`` markers,
computes the paper's tables with the shared evaluation (same JSON keys as ``reproduce --json``), tracking errors,
gap/duplicate/saturation counts, and optional PNG plots.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser("analyze", help="replay analysis of a recorded run (.mcap or rosbag2 directory)",
                              description=__doc__)
    p.add_argument("run_path", metavar="RUN.mcap", help="MCAP file or rosbag2 directory")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON ('-' = stdout)")
    p.add_argument("--plots", metavar="DIR", help="write PNG plots into DIR")
    p.add_argument("--namespace", help="pick /<namespace>/reference … when the file holds several")
    p.add_argument("--sample-rate", type=float, help="override the sample rate [Hz] (default: from the file)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..core.analysis import analyze_run, format_report, plot_run
    from ..core.recording.mcap_io import read_run

    path = Path(args.run_path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    data = read_run(path, namespace=args.namespace, sample_rate=args.sample_rate)
    result = analyze_run(data).to_json()
    if args.json != "-":
        print(format_report(result))
        tables = _format_tables(result)
        if tables:
            print(tables)
    if args.plots:
        written = plot_run(data, args.plots)
        print(f"plots: {len(written)} PNG in {args.plots}", file=sys.stderr if args.json == "-" else sys.stdout)
    if args.json:
        text = json.dumps(result, indent=2, allow_nan=False)
        if args.json == "-":
            print(text)
        else:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(text + "\n")
            print(f"results: {args.json}")
    return 0


def _format_tables(result: dict) -> str | None:
    """The paper's Tables I/II as ``reproduce`` prints them, when the shared formatter exists."""
    paper = {k: v for k, v in result.items() if k != "replay"}
    if not paper:
        return None
    import importlib

    for mod_name in ("piezo_ff_ros.core.experiments", "piezo_ff_ros.core.reproduce"):
        try:
            mod = importlib.import_module(mod_name)
        except ImportError:
            continue
        for fn_name in ("format_tables", "format_report"):
            fn = getattr(mod, fn_name, None)
            if callable(fn):
                try:
                    return fn(paper, axes=result["replay"]["axes"])
                except (KeyError, TypeError, ValueError):
                    return None
    return None
