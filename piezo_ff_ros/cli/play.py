"""``piezo-ff play VOLTAGES --backend NAME [--param K=V …] --out RUN.csv|RUN.mcap``: play a voltage table once on a
device and record what it applied and what the sensor measured, on the same sample grid.

``VOLTAGES`` is ``piezo-ff feedforward``'s output or any ``[N, axes]`` CSV/.npy/.mat in volts at the config's sample
rate.  A backend with a wave generator (``pi_gcs``: its table player, hardware-timed, with the data recorder) plays
it itself; any other backend (``sim``, ``nidaqmx``) streams it through the driver core.  Either way the output is
ramped from the safe voltage to the table's first value and from its last value back to safe at the safe ramp's pace,
and the run (``t,u_<axis>…,<axis>…`` in seconds, volts and metres, or the recorder's MCAP topics) is what
``piezo-ff analyze``/``identify``/``diagnose`` read.  The engine is :mod:`piezo_ff_ros.core.hardware.play`.
"""
from __future__ import annotations

import argparse
import json
import sys
from importlib import import_module
from pathlib import Path

FORMATS = (".csv", ".mcap")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("play", help="play a voltage table on a device and record the run (CSV/MCAP)")
    p.add_argument("voltages", help="voltage table [N, axes] V: .csv (u_<axis> columns, e.g. from feedforward), "
                                    ".npy or .mat")
    p.add_argument("--backend", required=True, help="backend plug-in: pi_gcs (wave generator), sim, nidaqmx, …")
    p.add_argument("--param", action="append", default=[], metavar="K=V",
                   help="a backend parameter (repeatable), e.g. --param address=192.168.0.10 (values parsed as YAML)")
    p.add_argument("--config", default=None, help="positioner config YAML (axes, sample rate, limits)")
    p.add_argument("--variant", default=None, help="config variant")
    p.add_argument("--out", required=True, help="the run: .csv (t,u_<axis>…,<axis>…) or .mcap")
    p.add_argument("--ramp-duration", type=float, default=0.05, help="safe ramp: minimum duration [s]")
    p.add_argument("--ramp-slew", type=float, default=1.0e4, help="safe ramp: maximum slew [V/s]")
    p.add_argument("--write-ahead", type=float, default=None,
                   help="streaming backends: seconds queued ahead of the device's clock (default: 0.5 s or 80 %% "
                        "of the device FIFO)")
    p.add_argument("--timeout", type=float, default=30.0, help="seconds to wait beyond the table's length (default 30)")
    p.add_argument("--json", default=None, help="also write a summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..backends import BackendError, available, get_spec
    from ..core.config import load_config
    from ..core.hardware.contract import DeviceFault
    from ..core.hardware.driver_core import DriverSettings
    from ..core.hardware.play import PlayError, load_voltage_table, play_on_table, play_streaming, write_run
    from ..core.safety import SafeRampConfig
    from . import CliError, output_file
    from .rig_check import _parse_params

    out = output_file(args.out, "--out")
    if out.suffix.lower() not in FORMATS:
        raise CliError(f"--out {out}: use one of {', '.join(FORMATS)}")
    cfg = load_config(args.config, variant=args.variant)
    u, fs = load_voltage_table(args.voltages, cfg.axes)
    if fs is not None and abs(fs - cfg.sample_rate) > 1e-6 * cfg.sample_rate:
        raise CliError(f"{args.voltages}: sampled at {fs:g} Hz but the config runs at {cfg.sample_rate:g} Hz "
                       "(sample_rate); recompute it with the same config")
    ramp = SafeRampConfig(args.ramp_duration, args.ramp_slew).validate("--ramp")
    spec = get_spec(args.backend)
    params = spec.validate(_parse_params(args.param))
    meta = {"backend": args.backend, "source": str(args.voltages), "sample_rate": cfg.sample_rate}
    module = import_module(available()[args.backend].partition(":")[0])
    try:
        if hasattr(module, "open_table_player"):
            player = module.open_table_player(cfg, params, ramp)
            player.timeout = args.timeout
            try:
                run_data = play_on_table(player, u, cfg.sample_rate, cfg.axes, meta)
            finally:
                player.close()
        else:
            backend = spec.create(cfg, params)
            # the whole table is known ahead: a deep write-ahead costs nothing and rides out a loaded host
            ahead = args.write_ahead if args.write_ahead is not None else \
                min(0.5, 0.8 * backend.info.fifo_depth / cfg.sample_rate)
            settings = DriverSettings(sample_rate=cfg.sample_rate, n_axes=cfg.n_axes, limits=cfg.limits, ramp=ramp,
                                      max_block=max(1000, int(cfg.sample_rate)), write_ahead=ahead,
                                      low_water=ahead / 5)
            run_data = play_streaming(backend, settings, u, cfg.axes, meta, timeout=args.timeout)
    except ValueError as exc:      # the table does not fit the device (range, slew, capacity): bad input
        raise CliError(str(exc)) from None
    except (BackendError, PlayError, DeviceFault, TimeoutError) as exc:
        print(f"piezo-ff play: failed: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}",
              file=sys.stderr)
        return 1
    out.parent.mkdir(parents=True, exist_ok=True)
    write_run(run_data, out)
    summary = {"samples": len(run_data), "sample_rate_hz": cfg.sample_rate, "axes": list(cfg.axes),
               "backend": args.backend, "mode": run_data.meta.get("mode"), "out": str(out),
               "max_abs_voltage_v": float(abs(run_data.u).max()),
               **{k: v for k, v in run_data.meta.items() if k in ("ramp_in_samples", "ramp_out_samples",
                                                                   "max_step_v")}}
    print(f"play: {len(run_data)} samples ({len(run_data) / cfg.sample_rate:g} s) on {args.backend} "
          f"({summary['mode']}), |U| ≤ {summary['max_abs_voltage_v']:.3f} V, ended at the safe voltage → {out}")
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2))
    return 0
