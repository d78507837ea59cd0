"""``piezo-ff check [CONFIG] [--variant NAME] [--json FILE] [--no-synthesis]``: validate a config and report on it.

Prints every transfer function's facts (:mod:`piezo_ff_ros.core.checks`) and then synthesises the H∞ vibration
compensator the config asks for (≈ 2 s; none when its cascade has no vibration stage), so that a config the compensator cannot build — γ_max below what any
controller reaches, a reduction order too low — is refused here, with exit code 2, and not later by ``reproduce``,
``demo`` or the compensator node.
"""
from __future__ import annotations

import argparse
import json

from . import CliError


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("check", help="validate a positioner config and report on its transfer functions",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("config", nargs="?", default=None, help="YAML config (default: config/pt230_94.yaml)")
    p.add_argument("--variant", default=None, help="a named variant of the config (e.g. gyx_gain_div10)")
    p.add_argument("--json", default=None, help="write the report as JSON")
    p.add_argument("--no-synthesis", action="store_true",
                   help="skip the H∞ synthesis (the config is then only checked field by field)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..core.checks import config_report, format_config_report
    from ..core.config import load_config

    cfg = load_config(args.config, variant=args.variant)
    rep = config_report(cfg)
    print(format_config_report(rep))
    failure = None
    if args.no_synthesis:
        rep["hinf"] = {"checked": False}
    elif not cfg.cascade.vibration:   # the compensator builds no vibration stage: nothing to synthesise
        rep["hinf"] = {"checked": False, "vibration": "off"}
        print("  H∞: vibration stage off in the cascade (not synthesised)")
    elif cfg.vibration.controller is not None:
        rep["hinf"] = {"checked": False, "controller": "given in the config"}
        print("  H∞: controller given in the config (not synthesised)")
    else:
        from ..core.synthesis.hinf import HinfSynthesisError, synthesize_hinf

        try:
            d = synthesize_hinf(cfg.dynamics.G_L, cfg.vibration)
        except HinfSynthesisError as exc:
            rep["hinf"] = {"checked": True, "feasible": False, "error": str(exc)}
            failure = exc
        else:
            rep["hinf"] = {"checked": True, "feasible": True, "gamma": d.gamma, "order_full": d.order_full,
                           "order_reduced": d.order_reduced, "gamma_reduced_achieved": d.gamma_reduced_achieved,
                           "synthesis_s": d.synthesis_s}
            print(f"  H∞: γ = {d.gamma:.4f} (≤ vibration.gamma_max = {cfg.vibration.gamma_max:g}), controller order "
                  f"{d.order_full} → {d.order_reduced}, reduced achieves {d.gamma_reduced_achieved:.4f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rep, f, indent=2, default=str)
    if failure is not None:
        where = args.config or "the default config"
        raise CliError(f"{where}: the compensator cannot be built: {failure}")
    return 0
