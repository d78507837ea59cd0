"""``piezo-ff feedforward --trajectory SPEC --config CFG --out U.(csv|npy|mat)``: the compensated voltages for a
trajectory, computed offline with the full cascade and the amplifier's limits — for a real-time target of your own
(dSPACE, LabVIEW, a microcontroller) and for the PI backend's wave tables.

The reference is ``core.trajectories.from_dict`` (SPEC: JSON/YAML text or a file); the voltages are the
:class:`~piezo_ff_ros.core.compensators.cascade.CompensatorCascade` output passed through the driver's own
:class:`~piezo_ff_ros.core.safety.VoltageGuard` (clamp to ±limits.voltage, slew ≤ limits.slew, from the safe
voltage), so that what the file says is exactly what the driver would apply.  Formats: CSV with a header ``t,u_<axis>…``
(seconds, volts), ``.npy`` ``[N, axes]`` volts, ``.mat`` with ``t``, ``u``, ``axes``, ``sample_rate``.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

if TYPE_CHECKING:
    from ..core.config import PiezoConfig
    from ..core.trajectories import Trajectory

FORMATS = (".csv", ".npy", ".mat")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("feedforward", help="offline compensated voltages of a trajectory (CSV/.npy/.mat)")
    p.add_argument("--trajectory", required=True,
                   help="trajectory spec: JSON/YAML text or a file, e.g. '{type: circle, radius: 1.0e-5, "
                        "frequency: 10, revolutions: 2}'")
    p.add_argument("--config", default=None, help="positioner config YAML (default: config/pt230_94.yaml)")
    p.add_argument("--variant", default=None, help="a named variant of the config")
    p.add_argument("--out", required=True, help="output file: .csv, .npy or .mat")
    p.add_argument("--stages", default=None,
                   help="comma list of stages to use (vibration,creep,hysteresis); default: the config's cascade")
    p.add_argument("--duration", type=float, default=None, help="seconds to compute (required for endless "
                                                                 "trajectories; default: the trajectory's)")
    p.add_argument("--json", default=None, help="also write a summary (samples, limits hit) as JSON")
    p.add_argument("--clip", action="store_true",
                   help="write a trajectory the amplifier cannot follow anyway, clipped to limits.voltage/limits.slew "
                        "(counted and reported); without it such a trajectory is refused")
    p.set_defaults(func=run)


def parse_spec(text: str) -> Trajectory:
    """Trajectory from spec text or a file; ValueError naming the problem otherwise."""
    import yaml

    from ..core.trajectories import from_dict

    p = Path(text)
    if len(text) < 4096 and p.suffix.lower() in (".yaml", ".yml", ".json"):
        if not p.is_file():
            raise ValueError(f"--trajectory: {text}: no such file")
        text = p.read_text()
    try:
        spec = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"--trajectory: not valid JSON/YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(spec, dict):
        raise ValueError("--trajectory: expected a mapping such as '{type: circle, radius: 1.0e-5, frequency: 10}'")
    return from_dict(spec, prefix="trajectory")


def compute(cfg: PiezoConfig, traj: Trajectory, duration: float | None = None,
            ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """``(t [s], u [N, axes] V, summary)``: the cascade's voltages through the driver's guard."""
    from ..core.compensators.cascade import CompensatorCascade
    from ..core.safety import VoltageGuard

    fs = cfg.sample_rate
    n = traj.n_samples(fs) if duration is None else int(round(duration * fs))
    if isinstance(n, float) and math.isinf(n):
        raise ValueError("--duration: the trajectory is endless; give the seconds to compute")
    n = int(n)
    if n < 1 or n > 3600 * fs:
        raise ValueError(f"--duration: {n} samples is outside [1, 1 h]")
    if set(traj.axes) < set(cfg.axes):   # some axes of the stage (a circle on an XYZ stage): the others at rest
        from ..core.trajectories import PerAxis

        traj = PerAxis([traj], axes=cfg.axes)
    if tuple(traj.axes) != tuple(cfg.axes):
        raise ValueError(f"--trajectory: axes {list(traj.axes)} do not match the config's {list(cfg.axes)}")
    ref = traj.block(0, n, fs)
    cascade = CompensatorCascade(cfg)
    guard = VoltageGuard(cfg.limits, cfg.n_axes, fs, max_block=n)
    u_cmd = cascade.process(ref)
    u = guard.apply(u_cmd)
    c = guard.counters
    lim = cfg.limits
    comp_limited = int(getattr(cascade.hysteresis, "saturated", 0) or 0)
    u_free = u_cmd
    if comp_limited and cfg.cascade.respect_limits:
        # the hysteresis inverse held itself to the limits: what it would have asked for says by how much
        free = replace(cfg, cascade=replace(cfg.cascade, respect_limits=False))
        u_free = CompensatorCascade(free).process(ref)
    # what the compensator asks for, against the amplifier's limits (from the safe voltage, as the driver starts)
    over_v = np.max(np.abs(u_free), axis=1) - lim.voltage
    rate = np.max(np.abs(np.diff(np.vstack([np.full((1, cfg.n_axes), lim.safe_voltage), u_free]), axis=0)),
                  axis=1) * fs - lim.slew
    summary = {"samples": int(n), "sample_rate_hz": fs, "duration_s": n / fs, "axes": list(cfg.axes),
               "stages": [k for k in ("vibration", "creep", "hysteresis") if getattr(cfg.cascade, k)],
               "voltage_limit_v": cfg.limits.voltage, "slew_limit_v_per_s": cfg.limits.slew,
               "max_abs_voltage_v": float(np.max(np.abs(u))),
               "max_step_v": float(np.max(np.abs(np.diff(
                   np.vstack([np.full((1, cfg.n_axes), cfg.limits.safe_voltage), u]), axis=0)))),
               "saturated_samples": c.saturated_samples, "slew_limited_samples": c.slew_limited_samples,
               "changed_by_limits": int(np.count_nonzero(np.any(u != u_cmd, axis=1))),
               # the hysteresis inverse clamps/slews like the driver (cascade.respect_limits): counted there
               "compensator_limited_samples": comp_limited,
               "beyond_voltage_samples": int(np.count_nonzero(over_v > 1e-9)),
               "beyond_voltage_by_v": float(max(over_v.max(), 0.0)),
               "beyond_slew_samples": int(np.count_nonzero(rate > 1e-6 * lim.slew)),
               "beyond_slew_by_v_per_s": float(max(rate.max(), 0.0))}
    return np.arange(n) / fs, u, summary


def write(path: Path, t: np.ndarray, u: np.ndarray, axes: Sequence[str], fs: float) -> None:
    """Write the voltages as .csv (``t,u_<axis>…``), .npy (``u``) or .mat (``t``, ``u``, ``axes``,
    ``sample_rate``)."""
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"--out: {path.name}: use one of {', '.join(FORMATS)}")
    if path.is_dir():
        raise ValueError(f"--out: {path} is a directory")
    if not path.parent.is_dir():
        raise ValueError(f"--out: directory {path.parent} does not exist")
    if suffix == ".csv":
        header = ",".join(["t"] + [f"u_{a}" for a in axes])
        np.savetxt(path, np.column_stack([t, u]), delimiter=",", header=header, comments="", fmt="%.17g")
    elif suffix == ".npy":
        np.save(path, u)
    else:
        import scipy.io

        scipy.io.savemat(str(path), {"t": t[:, None], "u": u, "axes": np.array(list(axes), dtype=object),
                                     "sample_rate": fs}, do_compression=True)


def limits_problem(summary: dict[str, Any], cfg: PiezoConfig) -> str:
    """One line saying how the trajectory exceeds the amplifier's limits (which setting, how many samples, by how
    much), or "" if the compensated voltages need no limiting."""
    parts = []
    n = summary["samples"]
    if summary["beyond_voltage_samples"]:
        parts.append(f"{summary['beyond_voltage_samples']} of {n} samples exceed limits.voltage "
                     f"±{cfg.limits.voltage:g} V by up to {summary['beyond_voltage_by_v']:.3g} V")
    if summary["beyond_slew_samples"]:
        parts.append(f"{summary['beyond_slew_samples']} of {n} samples exceed limits.slew {cfg.limits.slew:g} V/s by "
                     f"up to {summary['beyond_slew_by_v_per_s']:.3g} V/s")
    if summary["compensator_limited_samples"]:
        parts.append(f"{summary['compensator_limited_samples']} sample value(s) were held to limits.voltage "
                     f"±{cfg.limits.voltage:g} V / limits.slew {cfg.limits.slew:g} V/s inside the hysteresis compensator "
                     "(cascade.respect_limits)")
    return ("the amplifier cannot follow this trajectory: " + "; ".join(parts)) if parts else ""


def run(args: argparse.Namespace) -> int:
    from ..core.config import load_config

    cfg = load_config(args.config, variant=args.variant)
    if args.stages is not None:
        stages = {s.strip() for s in args.stages.split(",") if s.strip()}
        bad = stages - {"vibration", "creep", "hysteresis"}
        if bad:
            raise ValueError(f"--stages: unknown stage(s) {sorted(bad)}; use vibration, creep, hysteresis")
        cfg = replace(cfg, cascade=replace(cfg.cascade, vibration="vibration" in stages, creep="creep" in stages,
                                           hysteresis="hysteresis" in stages)).validate()
    traj = parse_spec(args.trajectory)
    out = Path(args.out)
    t, u, summary = compute(cfg, traj, args.duration)
    problem = limits_problem(summary, cfg)
    if problem and not args.clip:
        raise ValueError(f"{problem}; nothing written (lower the trajectory's amplitude or frequency, raise the "
                         "config's limits if the amplifier allows, or pass --clip to write it clipped)")
    if problem:
        print(f"piezo-ff feedforward: warning: CLIPPED: {problem}; the file holds the clipped voltages",
              file=sys.stderr)
    summary["clipped"] = bool(problem)
    write(out, t, u, cfg.axes, cfg.sample_rate)
    summary["out"] = str(out)
    print(f"feedforward: {summary['samples']} samples ({summary['duration_s']:g} s at {cfg.sample_rate:g} Hz), "
          f"stages {summary['stages']}, |U| ≤ {summary['max_abs_voltage_v']:.3f} V, "
          f"{summary['changed_by_limits'] + summary['compensator_limited_samples']} sample(s) limited → {out}")
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2))
    return 0
