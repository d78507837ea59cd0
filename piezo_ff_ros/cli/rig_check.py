"""``piezo-ff rig-check --backend NAME [--param K=V …] [--loopback] [--json OUT] [--md OUT]``: what to run first on
a new rig.

The checks (link, sample clock, write-ahead margin, measured command→sensor latency, slew limit, safe ramp) are
:mod:`piezo_ff_ros.core.hardware.rig_check`; this module maps the options to it and writes the report.  The test
voltages stay within ``--test-voltage`` (default 10 % of the limit).  ``--backend sim`` runs the clocked simulator
(``--param mode=lockstep`` for the other one).  ``--loopback``: the sensor inputs are wired to the command outputs
(NI: AO → AI), the latency must then match the backend's ``latency_samples`` exactly, and the report's
``latency_samples`` is the value to set.  The report (JSON/Markdown) has at least ``ok``, ``sample_rate_hz``,
``latency_samples``, ``underruns``, ``safe_ramp_max_step_v``; a check that does not apply to the device is
``skipped`` with the reason; exit code 0 when ok, 1 otherwise.
"""
from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Sequence


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("rig-check", help="first checks on a rig: link, sample clock, write-ahead, measured latency, "
                                          "slew limit, safe ramp (Markdown/JSON report)")
    p.add_argument("--backend", default="sim", help="backend plug-in (sim, nidaqmx, pi_gcs, or an entry point)")
    p.add_argument("--param", action="append", default=[], metavar="K=V",
                   help="a backend parameter (repeatable), e.g. --param device=Dev1 (values parsed as YAML)")
    p.add_argument("--config", default=None, help="positioner config YAML (limits, axes, sample rate)")
    p.add_argument("--variant", default=None, help="config variant")
    p.add_argument("--duration", type=float, default=60.0, help="seconds of paced streaming (default 60)")
    p.add_argument("--block-size", type=int, default=200, help="samples per block (default 200 = 10 ms)")
    p.add_argument("--write-ahead", type=float, default=None,
                   help="FIFO margin ahead of the clock [s] (default: the driver's default write_ahead)")
    p.add_argument("--test-voltage", type=float, default=None, help="largest test voltage [V] (default 10 %% "
                                                                     "of limits.voltage)")
    p.add_argument("--ramp-duration", type=float, default=0.05, help="safe ramp: minimum duration [s]")
    p.add_argument("--ramp-slew", type=float, default=1.0e4, help="safe ramp: maximum slew [V/s]")
    p.add_argument("--loopback", action="store_true", help="the sensor inputs are wired to the command outputs: "
                                                            "the measured latency must equal latency_samples")
    p.add_argument("--json", default=None, help="write the report as JSON")
    p.add_argument("--md", default=None, help="write the report as Markdown")
    p.set_defaults(func=run)


def _parse_params(items: Sequence[str]) -> dict[str, Any]:
    import yaml

    out: dict[str, Any] = {}
    for it in items:
        k, sep, v = it.partition("=")
        if not sep or not k.strip():
            raise ValueError(f"--param: expected K=V, got {it!r}")
        try:
            out[k.strip()] = yaml.safe_load(v)
        except yaml.YAMLError:
            out[k.strip()] = v
    return out


def backend_opener(cfg: Any, backend_name: str, params: dict[str, Any]) -> Callable[[], tuple[Any, dict[str, Any]]]:
    """``open_backend()`` for the rig-check engine: the plug-in ``backend_name`` with ``params`` validated (``sim``
    defaults to its clocked mode), created for ``cfg``."""
    def open_backend() -> tuple[Any, dict[str, Any]]:
        from ..backends import get_spec

        spec = get_spec(backend_name)
        p = {"mode": "clocked", **params} if backend_name == "sim" else params
        bparams = spec.validate(p)
        return spec.create(cfg, bparams), bparams

    return open_backend


def rig_check(cfg: Any, backend_name: str, params: dict[str, Any], **kw: Any) -> dict[str, Any]:
    """The checks on the plug-in ``backend_name`` with ``params`` (keyword options: those of
    :func:`piezo_ff_ros.core.hardware.rig_check.rig_check`); returns the report."""
    from ..core.hardware.rig_check import rig_check as engine

    return engine(cfg, backend_name, backend_opener(cfg, backend_name, params), **kw)


def run(args: argparse.Namespace) -> int:
    from ..core.config import load_config
    from ..core.hardware.rig_check import DEFAULT_WRITE_AHEAD, markdown
    from ..core.safety import SafeRampConfig

    cfg = load_config(args.config, variant=args.variant)
    if args.write_ahead is None:
        args.write_ahead = DEFAULT_WRITE_AHEAD
    for name in ("duration", "write_ahead", "ramp_duration", "ramp_slew"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"--{name.replace('_', '-')}: must be a finite number ≥ 0, got {v}")
    if not 1 <= args.block_size <= 10 * cfg.sample_rate:
        raise ValueError(f"--block-size: must be in [1, {int(10 * cfg.sample_rate)}], got {args.block_size}")
    tv = 0.1 * cfg.limits.voltage if args.test_voltage is None else args.test_voltage
    if not (math.isfinite(tv) and 0 < tv <= cfg.limits.voltage):
        raise ValueError(f"--test-voltage: must be in (0, {cfg.limits.voltage}] V, got {tv}")
    for out in (args.json, args.md):
        if out and (Path(out).is_dir() or not Path(out).resolve().parent.is_dir()):
            raise ValueError(f"{out}: not a writable file path")
    ramp = SafeRampConfig(duration=args.ramp_duration, slew=args.ramp_slew).validate()
    cfg = replace(cfg, limits=cfg.limits.validate())
    rep = rig_check(cfg, args.backend, _parse_params(args.param), duration=args.duration, block_size=args.block_size, write_ahead=args.write_ahead,
                    test_voltage=tv, ramp=ramp, loopback=args.loopback)
    if args.json:
        Path(args.json).write_text(json.dumps(rep, indent=2, default=str))
    if args.md:
        Path(args.md).write_text(markdown(rep))
    print(f"rig-check: {'OK' if rep['ok'] else 'FAILED'}")
    return 0 if rep["ok"] else 1
