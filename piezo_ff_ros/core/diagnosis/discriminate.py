"""Discriminate, don't guess: the experiment that separates two candidates that explain a run nearly as well.

When the held-out run cannot tell two fitted candidates apart (a fast amplifier roll-off and a sample-level delay
both lag the phase; thermal drift and level-dependent creep both make slow trends), :func:`propose` simulates both
fitted models on a small library of voltage excitations — steps, a chirp through the dynamics band, a hold followed
by a long step, multisines at three levels, a large slow sine — and picks the one on which the two predictions
differ the most per second of experiment, relative to the measured noise spectrum.  It returns the excitation as a
:func:`~piezo_ff_ros.core.trajectories.from_dict` spec (volts: play it with the compensator in ``bypass``), how long
to play it, and the expected RMS difference and z between the two explanations.  :func:`decide_on_run` scores the
tied candidates (still fitted on TRAIN only) on the recorded experiment and names the winner.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Iterable

import numpy as np

from ..config import PiezoConfig
from ..recording.run import RunData
from ..trajectories import from_dict
from . import stats
from .replay import residual, simulate

if TYPE_CHECKING:
    from .candidates import FitResult
    from .scored import Scored

__all__ = ["designs", "propose", "decide_on_run", "TARGET_Z", "MAX_SECONDS"]

#: the proposed experiment is made long enough for this expected z between the two explanations
TARGET_Z = 8.0
#: and never longer than this [s]
MAX_SECONDS = 600.0


def designs(cfg: PiezoConfig, u_max: float) -> dict[str, tuple[dict[str, Any], str]]:
    """The candidate excitations (trajectory specs in volts) with a one-line purpose each."""
    fs = cfg.sample_rate
    axes = list(cfg.axes)
    a = float(u_max)
    f_hi = float(min(0.4 * fs, 5000.0))
    f_ra = float(min(5.0, 0.01 * fs))   # rate vs amplitude: 5 Hz and 20 Hz (slower on a slow record)

    def seq(*segs: tuple[str, dict[str, Any]]) -> dict[str, Any]:
        return {"type": "sequence", "axes": axes,
                "segments": [{"name": n, "trajectory": dict(t, axes=axes)} for n, t in segs]}

    lv = [0.0, 0.6, -0.6, 0.3, -0.3, 0.9, 0.0]
    out = {
        "steps": (seq(*[(f"step_{ax}", {"type": "staircase", "levels": [v * a for v in lv], "dwell": 0.4, "axis": ax})
                        for ax in axes]),
                  "voltage steps on each axis: a delay shifts the response, a roll-off rounds it, slew ramps it"),
        "chirp": (seq(*[(f"chirp_{ax}", {"type": "chirp", "amplitude": 0.3 * a, "f0": 1.0, "f1": f_hi,
                                          "duration": 8.0, "method": "logarithmic", "axis": ax}) for ax in axes]),
                  "logarithmic chirp 1 Hz–%g Hz on each axis: phase lag ∝ f (delay) vs roll-off magnitude loss, "
                  "modes" % f_hi),
        "hold_then_step": (seq(("rest", {"type": "hold", "value": 0.0, "duration": 30.0}),
                               ("step", {"type": "step", "amplitude": [0.7 * a] * len(axes), "hold": 60.0})),
                           "30 s at rest then a 60 s step: drift moves at rest, creep only after the step"),
        "levels": (seq(*[(f"level_{k}", {"type": "multisine", "amplitude": s * a, "f_min": 2.0, "f_max": f_hi,
                                         "n_tones": 40, "duration": 4.0, "axis": None})
                         for k, s in enumerate((0.05, 0.15, 0.35))]),
                   "broadband multisine at three levels: dynamics that move with amplitude vs fixed ones"),
        "large_slow": (seq(*[(f"sine_{ax}", {"type": "sine", "amplitude": 0.98 * a, "frequency": 0.5,
                                             "duration": 8.0, "axis": ax}) for ax in axes]),
                       "large slow sine on each axis: saturation, asymmetry and level-dependent effects"),
        "rate_vs_amplitude": (seq(*[(f"{name}_{ax}", {"type": "sine", "amplitude": amp * a, "frequency": f,
                                                       "duration": 2.0, "axis": ax})
                                    for ax in axes
                                    for name, amp, f in (("a_f", 0.7, f_ra), ("a_4f", 0.7, 4 * f_ra),
                                                         ("quarter_a_4f", 0.175, 4 * f_ra))]),
                              "sines on each axis: one amplitude at two rates, then a quarter of it at the higher "
                              "frequency (the first rate again): rate dependence moves with the rate at a fixed "
                              "amplitude, amplitude dependence with the amplitude at a fixed rate"),
    }
    return out


def _repeat(spec: dict[str, Any], times: int) -> dict[str, Any]:
    if times <= 1:
        return spec
    segs = []
    for k in range(times):
        for s in spec["segments"]:
            segs.append({"name": f"{s['name']}_{k + 1}", "trajectory": s["trajectory"]})
    return dict(spec, segments=segs)


def propose(cfg: PiezoConfig, best: FitResult, rivals: list[FitResult], psd: "stats.NoisePSD", sigma: np.ndarray,
            u_ref: np.ndarray) -> dict[str, Any]:
    """The experiment that best separates the fitted ``best`` candidate from each of ``rivals`` (FitResults).

    ``u_ref``: the voltages of the held-out run (the proposal stays within their range and the config's limits).
    """
    fs = cfg.sample_rate
    u_max = float(np.max(np.abs(u_ref)))
    if cfg.limits.voltage:
        u_max = min(u_max, float(cfg.limits.voltage))
    if not u_max > 0:
        raise ValueError("the held-out voltages are all zero: no range to design an experiment in")
    rows: list[dict[str, Any]] = []
    for name, (spec, why) in designs(cfg, u_max).items():
        traj = from_dict(spec)
        _, u = traj.sample(fs)
        y_best = simulate(cfg, u, best.effects)
        worst_z, worst_rms = math.inf, math.inf
        for rv in rivals:
            d = residual(simulate(cfg, u, rv.effects), y_best)
            dd = float(np.sum(d ** 2))
            sd = 2.0 * stats.inner_sd(d, psd)
            z = dd / sd if sd > 0 else math.inf
            if z < worst_z:
                worst_z, worst_rms = z, math.sqrt(dd / d.size)
        dur = traj.duration
        rows.append({"design": name, "why": why, "spec": spec, "base_seconds": dur, "z": worst_z,
                     "rms_difference_um": worst_rms * 1e6, "z_per_sqrt_s": worst_z / math.sqrt(dur)})
    rows.sort(key=lambda r: -r["z_per_sqrt_s"])
    top = rows[0]
    # z grows like √(repetitions) for a repeated excitation (the difference energy adds, its noise std as √)
    reps = 1 if top["z"] >= TARGET_Z else int(math.ceil((TARGET_Z / max(top["z"], 1e-9)) ** 2))
    reps = max(1, min(reps, int(MAX_SECONDS // top["base_seconds"]) or 1))
    spec = _repeat(top["spec"], reps)
    traj = from_dict(spec)
    return {
        "design": top["design"],
        "purpose": top["why"],
        "duration_s": float(traj.duration),
        "repetitions": reps,
        "expected_rms_difference_um": top["rms_difference_um"],
        "expected_z": top["z"] * math.sqrt(reps),
        "between": [best.effect] + [r.effect for r in rivals],
        "trajectory": spec,
        "units": "volts (play with the compensator in bypass: its reference is the voltage)",
        "alternatives": [{k: r[k] for k in ("design", "z", "rms_difference_um", "base_seconds")} for r in rows[1:]],
    }


def decide_on_run(cfg: PiezoConfig, scored: Iterable[Scored], run: RunData) -> dict[str, Any]:
    """Which of the tied candidates (``Scored`` with fits from TRAIN) explains the discrimination run best."""
    res: dict[str, np.ndarray] = {}
    for s in scored:
        res[s.fit.effect] = residual(run.y, simulate(cfg, run.u, s.fit.effects))
    r_nom = residual(run.y, simulate(cfg, run.u, []))
    order = sorted(res, key=lambda k: float(np.sum(res[k] ** 2)))
    winner = order[0]
    psd = stats.noise_psd(res[winner])
    pz = stats.paired_z(res[winner], res[order[1]], psd) if len(order) > 1 else None
    den = float(np.sqrt(np.sum((run.y - run.y.mean(axis=0)) ** 2)))
    nrmse = {k: float(100 * np.sqrt(np.sum(v ** 2)) / max(den, 1e-300)) for k, v in res.items()}
    nrmse_nom = float(100 * np.sqrt(np.sum(r_nom ** 2)) / max(den, 1e-300))
    summary = (f"{winner} explains the discrimination run best (" +
               ", ".join(f"{k} {nrmse[k]:.3g} %" for k in order) + f"; nominal {nrmse_nom:.3g} %" +
               (f"; paired z = {pz:.3g}" if pz is not None else "") + ")")
    return {"winner": winner, "nrmse_percent": nrmse, "nominal_nrmse_percent": nrmse_nom, "paired_z": pz,
            "summary": summary}
