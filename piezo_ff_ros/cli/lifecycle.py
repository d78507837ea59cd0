"""``piezo-ff lifecycle NODE get|configure|activate|deactivate|cleanup|shutdown``: step a managed node (the
driver), like ``ros2 lifecycle get/set`` — for environments without the ``ros2`` CLI.  Prints the state it is in
afterwards; a refused transition is one line naming the state it stays in.  Uses the graph's ``ROS_DOMAIN_ID``.
"""
from __future__ import annotations

import argparse

TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser("lifecycle", help="get or change a managed node's state (no ros2 CLI needed)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("node", help="node name, e.g. driver")
    p.add_argument("transition", choices=("get", *TRANSITIONS))
    p.add_argument("--timeout", type=float, default=10.0, help="wait this long for the node [s]")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..ros.helpers import Session, lifecycle

    with Session("piezo_ff_lifecycle", timeout=args.timeout) as s:
        print(lifecycle(s, args.node, None if args.transition == "get" else args.transition))
    return 0
