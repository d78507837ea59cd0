"""``piezo-ff``: one command, one module per subcommand (``piezo_ff_ros/cli/<name>.py``).

Each subcommand module defines ``add_parser(subparsers)`` (registering itself, with ``set_defaults(func=run)``) and
``run(args) -> int``.  Modules are imported only when listed here, and a failure to import one (e.g. rclpy absent
for ``demo``) only disables that subcommand.
"""
from __future__ import annotations

import argparse
import importlib
import sys

SUBCOMMANDS = ["reproduce", "demo", "analyze", "identify", "commission", "diagnose", "bench", "check"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="piezo-ff",
        description="Sensorless multivariable feedforward compensation of piezoelectric positioners "
                    "(Habineza et al., IEEE TASE 2018).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            mod = importlib.import_module(f"{__name__}.{name}")
        except ImportError as exc:  # pragma: no cover - optional subcommands
            p = sub.add_parser(name, help=f"(unavailable: {exc})")
            p.set_defaults(func=lambda args, _e=exc, _n=name: _unavailable(_n, _e))
            continue
        mod.add_parser(sub)
    return parser


def _unavailable(name, exc) -> int:
    print(f"piezo-ff {name}: unavailable here ({exc})", file=sys.stderr)
    return 2


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except (FileNotFoundError, ValueError) as exc:
        # bad input (config, data file, option): a clear message, never a traceback
        print(f"piezo-ff {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
