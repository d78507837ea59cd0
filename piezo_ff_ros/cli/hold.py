"""``piezo-ff hold X [Y [Z]]``: hold the stage at a point (metres), like ``ros2 topic pub --once reference_point
geometry_msgs/msg/PointStamped …`` — for environments without the ``ros2`` CLI.

The compensator plays a held point as blocks while no ``reference`` block arrives; the point is published once
the compensator's subscription has matched.  Uses the graph's ``ROS_DOMAIN_ID`` (0 when unset, like ``ros2``).
"""
from __future__ import annotations

import argparse


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser("hold", help="hold the stage at a point [m] (reference_point; no ros2 CLI needed)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("point", nargs="+", type=float, metavar="X", help="coordinates [m], one per axis (x y …)")
    p.add_argument("--topic", default="reference_point", help="topic (default reference_point)")
    p.add_argument("--timeout", type=float, default=10.0, help="wait this long for the compensator [s]")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..ros.helpers import Session, hold_point

    with Session("piezo_ff_hold", timeout=args.timeout) as s:
        hold_point(s, args.point, topic=args.topic)
    print(f"holding {args.point} m (published on {args.topic}, ROS_DOMAIN_ID={s.domain})")
    return 0
