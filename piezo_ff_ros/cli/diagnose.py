"""``piezo-ff diagnose``: where the sim-to-real gap lies, which unmodelled effect causes it, how far it shrinks.

Examples::

    piezo-ff diagnose --train run1.mcap --test run2.mcap --json gap.json --report gap/
    piezo-ff diagnose --model config/my_stage.yaml --data run.csv --apply corrected.yaml --report gap/
    piezo-ff diagnose --train A --test B --discriminate C     # C: the experiment a first diagnosis proposed

When two candidates explain the held-out run nearly as well, the result says so (``discrimination`` in the JSON)
and writes the trajectory that separates them (``--proposal FILE``, default ``discriminate_trajectory.yaml`` in the
report or JSON directory), to play with the trajectory node while the compensator is in bypass.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

if TYPE_CHECKING:
    from ..core.recording.run import RunData

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "diagnose", help="diagnose the sim-to-real gap of a model against measured runs",
        description="Replay the measured voltages through the model, localise the residual, fit a library of "
                    "unmodelled effects on TRAIN and score them on TEST; JSON + Markdown/PNG report; optionally "
                    "write the corrected config.")
    p.add_argument("--model", metavar="CONFIG.yaml", help="model config (default: the paper's PT230.94)")
    p.add_argument("--variant", help="config variant (e.g. gyx_gain_div10)")
    p.add_argument("--train", metavar="TRAIN", help="training run (.mcap, .csv t,u_x,u_y,x,y, or .mat)")
    p.add_argument("--test", metavar="TEST", help="held-out run, other excitation")
    p.add_argument("--data", metavar="FILE", help="one run, split into a training and a held-out part")
    p.add_argument("--split", type=float, default=0.5, help="fraction of --data used for training (default 0.5)")
    p.add_argument("--sample-rate", type=float, metavar="HZ",
                   help="MCAP: the sample rate to read the recording at, when its metadata and its block stamps "
                        "disagree (refused otherwise); u_<tag>.npy/y_<tag>.npy records: their sample rate "
                        "(required, the layout holds none)")
    p.add_argument("--realization", type=int, default=0, metavar="K",
                   help=".npy records of several realizations: which one is the run (default 0)")
    p.add_argument("--json", metavar="OUT.json", help="write the machine-readable result")
    p.add_argument("--report", metavar="DIR", help="write report.md and PNG plots into DIR")
    p.add_argument("--apply", metavar="OUT.yaml", help="write the config corrected where the cascade can compensate")
    p.add_argument("--candidates", help="comma-separated subset of candidate effects (default: all)")
    p.add_argument("--discriminate", metavar="RUN",
                   help="a run of the proposed discrimination experiment: decides between tied candidates")
    p.add_argument("--proposal", metavar="OUT.yaml",
                   help="where to write the proposed discrimination trajectory (when the verdict is ambiguous)")
    p.add_argument("--quiet", action="store_true", help="print only the verdict line")
    p.set_defaults(func=run)
    return p


def _load_inputs(args: argparse.Namespace) -> tuple[RunData, RunData, RunData | None, dict[str, Any]]:
    """TRAIN, TEST, TEST's history (or None) and the report's ``input`` (which voltage, which stretches)."""
    from ..core.diagnosis.inputs import load_for_diagnosis, split_record

    rate = getattr(args, "sample_rate", None)
    if args.data and (args.train or args.test):
        raise ValueError("give either --data FILE or --train TRAIN --test TEST, not both")
    if args.data:
        if not 0.1 <= args.split <= 0.9:
            raise ValueError(f"--split must be within [0.1, 0.9], got {args.split}")
        run = load_for_diagnosis(args.data, rate, args.realization)
        parts = split_record(run, args.split)
        info = {"voltage": run.meta.get("voltage", "voltage"), "segments": parts.notes or None,
                "warnings": list(parts.warnings)}
        return parts.train, parts.test, parts.history, info
    if not (args.train and args.test):
        raise ValueError("need --train TRAIN and --test TEST (or --data FILE)")
    train = load_for_diagnosis(args.train, rate, args.realization)
    test = load_for_diagnosis(args.test, rate, args.realization)
    info = {"voltage": {"train": train.meta.get("voltage"), "test": test.meta.get("voltage")},
            "segments": None, "warnings": []}
    return train, test, None, info


def keep_freed_memory_for_reuse() -> bool:
    """Serve large arrays from the heap and keep freed memory for the next one (glibc only; returns whether set).

    A long record's diagnosis allocates and frees arrays of hundreds of MB many times over.  glibc maps each such
    block afresh (``mmap``) and unmaps it on ``free``, so every allocation faults its pages in again: about 4 s of
    system time on a 10-minute 20 kHz record (``bench/bench_diagnose_speed.py``).  Without ``mmap`` and with a high
    trim threshold, a freed block's pages stay mapped and the next array reuses them.  The process keeps its peak
    heap until it exits, which a one-shot command can afford.
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):      # not glibc (musl, macOS, Windows): leave the allocator as it is
        return False
    m_trim_threshold, m_top_pad, m_mmap_max = -1, -2, -4
    return bool(mallopt(m_mmap_max, 0) and mallopt(m_trim_threshold, 2 ** 31 - 1)
                and mallopt(m_top_pad, 64 << 20))


def run(args: argparse.Namespace) -> int:
    from ..core.config import load_config
    from ..core.diagnosis import DiagnosisOptions, diagnose, json_ready
    from ..core.diagnosis.report import tracking_comparison, write_apply, write_report
    from ..core.models.effects import EFFECT_NAMES
    from ..core.diagnosis.inputs import load_for_diagnosis

    keep_freed_memory_for_reuse()
    cfg = load_config(args.model, args.variant)
    train, test, history, input_info = _load_inputs(args)
    opts = DiagnosisOptions(verbose=not args.quiet)
    if args.candidates:
        names = tuple(c.strip() for c in args.candidates.split(",") if c.strip())
        bad = [c for c in names if c not in EFFECT_NAMES]
        if bad:
            raise ValueError(f"--candidates: unknown effect(s) {bad}; known: {', '.join(EFFECT_NAMES)}")
        opts.candidates = names
    # a held-out part split from one file is replayed after the training part (its start state is not at rest)
    disc_run = load_for_diagnosis(args.discriminate, getattr(args, "sample_rate", None)) if args.discriminate \
        else None
    res = diagnose(cfg, train, test, opts, test_history=history, discriminate=disc_run)
    proposal = _write_proposal(res, args)
    A = res.arrays
    out = res.to_json()          # the JSON written by --json: the report, plus "input" and "apply" below
    out["input"] = json_ready(input_info)
    for w in input_info["warnings"] + list(res.get("warnings", [])):
        print(f"warning: {w}", file=sys.stderr)
    apply_notes, tracking = None, None
    if args.apply:
        effects = A.stack_effects
        apply_notes = write_apply(args.apply, A.cfg, effects, res)
        ref = test.reference if test.reference is not None and test.reference.shape == test.y.shape \
            else A.y_test_final - A.y_test_final[:1]
        if effects:
            tracking = tracking_comparison(A.cfg, effects, ref)
            tracking["reference"] = ref
            out["apply"] = json_ready({"config": str(args.apply), "notes": apply_notes,
                                       "tracking_rms_um": {"before": tracking["before"]["rms_um"],
                                                           "after": tracking["after"]["rms_um"]},
                                       "tracking_note": "simulated: the diagnosed model stands in for the rig"})
        else:
            apply_notes = [f"nothing to correct (verdict {res['verdict']})"]
            out["apply"] = {"config": str(args.apply), "notes": apply_notes}
        if not args.quiet:
            print(f"wrote {args.apply}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
        if not args.quiet:
            print(f"wrote {args.json}")
    if args.report:
        path = write_report(res, args.report, tracking, apply_notes)
        if not args.quiet:
            print(f"wrote {path}")
    h = res["heldout"]
    print(f"verdict: {res['verdict']} (confidence {res['confidence']}); held-out NRMSE "
          f"{h['before_nrmse_percent']:.3g} % -> {h['after_nrmse_percent']:.3g} % "
          f"(stacked {h['stacked_after_nrmse_percent']:.3g} %, noise floor {h['noise_floor_nrmse_percent']:.3g} %)")
    if proposal:
        print(proposal)
    if not args.quiet:
        print("where: " + res["where"]["summary"])
        if res.get("explainable"):
            e = res["explainable"]
            print(f"explainable: the flexible model fitted on train removes {e['share_percent']:.3g} % of the "
                  f"held-out residual energy ({e['before_nrmse_percent']:.3g} % -> {e['after_nrmse_percent']:.3g} %)")
        for r in res["ranking"][:5]:
            print(f"  {r['effect']:28s} {r['heldout_before_nrmse_percent']:8.3f} % -> "
                  f"{r['heldout_after_nrmse_percent']:8.3f} %{'  *' if r['accepted'] else ''}")
    return 0


def _write_proposal(res: Mapping[str, Any], args: argparse.Namespace) -> str:
    """Write the discrimination trajectory when the verdict is ambiguous; returns the line to print ('' if none)."""
    import yaml

    d = res.get("discrimination") or {}
    exp = d.get("experiment")
    if not exp or "trajectory" not in exp:
        return ""
    if args.proposal:
        path = Path(args.proposal)
    elif args.report:
        path = Path(args.report) / "discriminate_trajectory.yaml"
    elif args.json:
        path = Path(args.json).with_name("discriminate_trajectory.yaml")
    else:
        path = None
    cmd = ("ros2 run piezo_ff_ros compensator --ros-args -p bypass:=true &  "
           f"ros2 run piezo_ff_ros trajectory --ros-args -p trajectory_file:={path or 'discriminate_trajectory.yaml'}"
           " -p autostart:=true")
    exp["command"] = cmd
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        header = (f"# Discrimination experiment proposed by piezo-ff diagnose: {' vs '.join(exp['between'])}\n"
                  f"# {exp['purpose']}\n# {exp['duration_s']:.4g} s; expected RMS difference "
                  f"{exp['expected_rms_difference_um']:.3g} um (z = {exp['expected_z']:.3g}); voltages [V]: play "
                  f"with the compensator in bypass:\n#   {cmd}\n# then: piezo-ff diagnose --train A --test B "
                  f"--discriminate RECORDED_RUN\n")
        path.write_text(header + yaml.safe_dump(exp["trajectory"], sort_keys=False, default_flow_style=None))
        exp["file"] = str(path)
    return (f"ambiguous: {' vs '.join(exp['between'])}; proposed experiment '{exp['design']}' "
            f"({exp['duration_s']:.4g} s, expected difference {exp['expected_rms_difference_um']:.3g} µm RMS, "
            f"z = {exp['expected_z']:.3g})" + (f" written to {path}" if path else " (give --proposal FILE to write it)"))


if __name__ == "__main__":  # pragma: no cover
    from . import main

    sys.exit(main(["diagnose", *sys.argv[1:]]))
