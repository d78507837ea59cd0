"""``piezo-ff echo TOPIC [--count N]``: print a topic's messages as YAML, like ``ros2 topic echo`` — for
environments without the ``ros2`` CLI (``/diagnostics``, the plotter's ``plot_*`` topics, ``joint_states`` …).

Block topics (PointCloud2) print their header and layout, their data as a byte count.  Uses the graph's
``ROS_DOMAIN_ID`` (0 when unset, like ``ros2``).
"""
from __future__ import annotations

import argparse
import sys

import yaml


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser("echo", help="print a topic's messages (no ros2 CLI needed)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("topic", help="e.g. /diagnostics, plot_error")
    p.add_argument("--count", type=int, default=1, help="messages to print (default 1)")
    p.add_argument("--timeout", type=float, default=10.0, help="give up after this long [s]")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from . import CliError
    from ..ros.helpers import Session, echo

    if args.count < 1:
        raise CliError(f"--count {args.count}: at least 1")
    with Session("piezo_ff_echo", timeout=args.timeout) as s:
        for msg in echo(s, args.topic, args.count, args.timeout):
            sys.stdout.write(yaml.safe_dump(msg, sort_keys=False, allow_unicode=True) + "---\n")
            sys.stdout.flush()
    return 0
