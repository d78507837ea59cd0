"""``piezo-ff check [CONFIG] [--variant NAME] [--json FILE]``: validate a config and print its sanity report."""
from __future__ import annotations

import json


def add_parser(sub):
    p = sub.add_parser("check", help="validate a positioner config and report on its transfer functions")
    p.add_argument("config", nargs="?", default=None, help="YAML config (default: config/pt230_94.yaml)")
    p.add_argument("--variant", default=None, help="a named variant of the config (e.g. gyx_gain_div10)")
    p.add_argument("--json", default=None, help="write the report as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core.checks import config_report, format_config_report
    from ..core.config import load_config

    cfg = load_config(args.config, variant=args.variant)
    rep = config_report(cfg)
    print(format_config_report(rep))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rep, f, indent=2, default=str)
    return 0
