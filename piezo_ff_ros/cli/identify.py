"""``piezo-ff identify``: recorded characterisation runs → a complete config the compensator loads.

Runs come from MCAP (recorded by the node graph), CSV, MATLAB .mat, or a ``u_<tag>.npy``/``y_<tag>.npy`` pair of
periodic records (one run per realization; ``--sample-rate``).  Each file (or each run inside it) must be
tagged with its stage (hysteresis / creep / dynamics) — from the recording's metadata, or from the file name
(``*hyst*``, ``*creep*``, ``*dyn*``; ``*val*`` or ``*held*`` marks a held-out run), or with ``--stage``.
Any number of axes; hysteresis is required, creep and dynamics are optional (a hysteresis-only record; voltage
records of a stage without creep, whose dynamics runs need no reference): a stage without runs is switched off
(creep none, G_L the ``--base`` config's, whose axes must be the runs').
For creep and dynamics runs the input of the characterised system (Y_H / Y_L) must be recorded as the reference
(CSV columns ``r_<axis>``, .mat variable ``r``).
Linear dynamics alone: periodic voltage records (the .npy layout) all tagged ``--stage dynamics`` (held out:
``dynamics:validation``) give ``Y = G_L(s)·Dp·U`` with no hysteresis or creep stage, and held-out test figures
(RMSE in µm and NRMSE over the last period of each realization) next to a published BLA's when known.  Broadband
records (multisines up to near the Nyquist frequency) cannot be fitted with the Bouc-Wen: refused in one line.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser("identify", help="identify hysteresis, creep, G_L (+ H∞) from recorded runs",
                              description=__doc__)
    p.add_argument("--data", nargs="+", required=True, metavar="FILE", help=".mcap, .csv or .mat files")
    p.add_argument("--out", required=True, help="config YAML to write")
    p.add_argument("--json", default=None, metavar="F", help="write held-out fits and timings as JSON")
    p.add_argument("--stage", nargs="*", default=None,
                   help="stage of each --data file (hysteresis|creep|dynamics[:validation]), same order")
    p.add_argument("--base", default=None, help="config whose H∞ weights, cascade and limits are kept "
                                                "(default: the paper's)")
    p.add_argument("--generalized", action="store_true", help="generalized (asymmetric) Bouc-Wen")
    p.add_argument("--creep-order", default="auto", help="creep order per entry (int) or 'auto'")
    p.add_argument("--dynamics-order", default="auto", help="G_L order per entry (int) or 'auto'")
    p.add_argument("--no-hinf", action="store_true", help="skip the H∞ synthesis")
    p.add_argument("--fit-offset", action="store_true",
                   help="hysteresis: identify a constant sensor offset (measured records)")
    p.add_argument("--delay", type=int, default=0, metavar="N",
                   help="hysteresis: samples by which the measured output lags the voltage (default 0)")
    p.add_argument("--input-gain", type=float, default=1.0, metavar="G",
                   help="volts at the actuator per recorded volt (records of an amplifier's input; default 1): the "
                        "fits do not depend on it, the identified parameters are per actuator volt")
    p.add_argument("--sample-rate", type=float, default=None, metavar="HZ",
                   help="sample rate of .npy records (the u_<tag>.npy / y_<tag>.npy layout holds none)")
    p.add_argument("--skip", type=float, default=0.0, metavar="S",
                   help="hysteresis: seconds at the start of each run left out (initial transient; default 0)")
    p.add_argument("--name", default=None, help="name of the written config (default <base name>_identified)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)
    return p


#: what ``--stage`` accepts (``plant``: a held-out voltage record the identified whole plant is scored on)
STAGE_NAMES = ("hysteresis", "creep", "dynamics", "plant")


def _tag_from_name(path: Path) -> tuple[str | None, str]:
    name = path.name.lower()
    stage = "hysteresis" if "hyst" in name else "creep" if "creep" in name else "dynamics" if "dyn" in name else None
    role = "validation" if ("val" in name or "held" in name) else "fit"
    return stage, role


def run(args: argparse.Namespace) -> int:
    from ..core.config import load_config
    from ..core.identification.pipeline import identify_all
    from ..core.jsonable import parse_order
    from ..core.recording import load_run
    from ..core.recording.run import RunData

    from . import output_file

    output_file(args.out, "--out")  # before the identification, not after
    t_start = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t_start:7.1f} s] {msg}", file=sys.stderr, flush=True)

    if args.stage is not None and len(args.stage) != len(args.data):
        raise ValueError(f"--stage: {len(args.stage)} value(s) for {len(args.data)} file(s)")
    for spec in args.stage or ():
        st, _, role = spec.partition(":")
        if st not in STAGE_NAMES or (role and role not in ("fit", "validation")):
            raise ValueError(f"--stage {spec!r}: expected STAGE[:ROLE] with STAGE one of {list(STAGE_NAMES)} and "
                             "ROLE fit or validation")
    if not (0 < args.input_gain < float("inf")):
        raise ValueError(f"--input-gain must be a positive number, got {args.input_gain}")
    if args.delay < 0 or not (args.skip >= 0 and args.skip < float("inf")):
        raise ValueError(f"--delay and --skip must be >= 0, got {args.delay} and {args.skip}")
    runs = []
    for i, f in enumerate(args.data):
        p = Path(f)
        say(f"loading {p}")
        if p.suffix.lower() == ".npy":   # a u_/y_ pair of periodic records: one run per realization
            from ..core.recording.importers import load_npy_realizations

            loaded: RunData | list[RunData] = load_npy_realizations(p, sample_rate=args.sample_rate)
        else:
            loaded = load_run(p)
        items = loaded if isinstance(loaded, list) else [loaded]
        for r in items:
            if args.stage is not None:
                st, _, role = args.stage[i].partition(":")
                r.meta["stage"], r.meta["role"] = st, (role or "fit")
            elif "stage" not in r.meta:
                st, role = _tag_from_name(p)
                if st is None:
                    raise ValueError(f"{p}: cannot tell its stage (name it *hyst*/*creep*/*dyn* or use --stage)")
                r.meta["stage"] = st
                r.meta.setdefault("role", role)
            if args.input_gain != 1.0:
                r.u = r.u * args.input_gain
            runs.append(r)
    base = load_config(args.base) if args.base else load_config()
    cfg, report = identify_all(runs, base=base, generalized=args.generalized, creep_order=parse_order(args.creep_order),
                               dynamics_order=parse_order(args.dynamics_order), synthesize=not args.no_hinf,
                               progress=say, fit_offset=args.fit_offset, delay=args.delay, skip=args.skip)
    if args.name:
        from dataclasses import replace

        cfg = replace(cfg, name=str(args.name)).validate()
    cfg.to_yaml(args.out)
    say(f"wrote {args.out}")
    fits = report.fit_percent
    print("held-out fit [%] (MATLAB compare):")
    for stage, d in fits.items():
        print(f"  {stage:10s} " + "  ".join(f"{k}: {v:.2f}" if v is not None else f"{k}: n/a" for k, v in d.items()))
    for stage, what in (report.not_identified or {}).items():
        why = "" if report.heldout_test else " (no runs)"   # linear dynamics alone: not identified by design
        print(f"  {stage:10s} not identified{why}: {what}")
    for tag, fig in (report.heldout_test or {}).items():
        line = (f"held-out test {tag} ({fig['realizations']} realizations, last period, all channels): "
                f"RMSE {fig['rmse_um']:.4f} µm, NRMSE {fig['nrmse_percent']:.2f} %")
        pub = fig.get("published_bla")
        if pub:
            line += f"; published BLA: {pub['rmse_um']:.3f} µm ({pub['nrmse_percent']:.2f} %)"
        print(line)
    if args.json:
        Path(args.json).write_text(json.dumps(report.to_json(), indent=2))
    return 0
