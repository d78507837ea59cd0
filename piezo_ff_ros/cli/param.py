"""``piezo-ff param get|set|list NODE [NAME [VALUE]]``: a node's parameters, like ``ros2 param`` — for
environments without the ``ros2`` CLI.

``set`` reads the parameter first and parses VALUE for its type (a string parameter takes VALUE as it is, so
``piezo-ff param set compensator config_yaml "$(cat change.yaml)"`` sends the YAML document); a name the node does
not have is answered with the close ones ("did you mean …?"); a value the node rejects keeps the old one running
and prints the node's reason.  Uses the graph's ``ROS_DOMAIN_ID`` (0 when unset, like ``ros2``).
"""
from __future__ import annotations

import argparse

import yaml


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser("param", help="get/set/list a node's parameters (no ros2 CLI needed)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("action", choices=("get", "set", "list"))
    p.add_argument("node", help="node name, e.g. compensator or /tube1/driver")
    p.add_argument("name", nargs="?", help="parameter name (get, set)")
    p.add_argument("value", nargs="?", help="new value (set): YAML for numbers/lists/booleans, as is for strings")
    p.add_argument("--timeout", type=float, default=10.0, help="wait this long for the node [s]")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from . import CliError
    from ..ros.helpers import Session, get_parameter, list_parameters, set_parameter

    if args.action in ("get", "set") and not args.name:
        raise CliError(f"param {args.action}: give the parameter NAME")
    if args.action == "set" and args.value is None:
        raise CliError("param set: give the VALUE")
    with Session("piezo_ff_param", timeout=args.timeout) as s:
        if args.action == "list":
            print("\n".join(list_parameters(s, args.node)))
        elif args.action == "get":
            print(_show(get_parameter(s, args.node, args.name)))
        else:
            old, new = set_parameter(s, args.node, args.name, args.value)
            print(f"{args.name}: {_show(old)} -> {_show(new)}")
    return 0


def _show(value: object) -> str:
    if isinstance(value, str):
        return value if "\n" not in value else "|\n" + "".join("  " + ln + "\n" for ln in value.splitlines())
    return yaml.safe_dump(value, default_flow_style=True, width=1_000_000).strip().removesuffix("...").strip()
