"""The vocabulary of effects and the plant builder: :data:`EFFECTS` (name → :class:`EffectSpec`), :func:`build_plant`.

:data:`EFFECTS` gives each candidate effect its position (``pre``: voltage, ``post``: displacement, ``hysteresis``:
replaces the nominal Bouc-Wen), its parameters with units and its description and residual signature; the
diagnosis and the robustness runs name effects by these keys.  :func:`build_plant` turns ``[(name, params), …]``
into ``Plant(cfg, pre=[...], post=[...])`` with the stages of :mod:`.voltage`, :mod:`.displacement`, :mod:`.modes`
and :mod:`.hysteresis`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ...config import PiezoConfig
from ...stage import Processor
from ..plant import Plant
from .common import LEVEL_REF, LEVEL_TAU, RATE_REF
from .creep_kv import KelvinVoigtCreep
from .displacement import CreepNonlinearity, GainMismatch, ThermalDrift
from .hysteresis import (BranchEvenTerm, HysteresisStage, LoopShapeTerm, PlayWidthTerm, RatePlayTerm, RelayPlaneTerm,
                         RelaxedHysteresisStage, VelocityTerm, asymmetric_hysteresis_config)
from .modes import AmplitudeDependentDynamics, BaseExcitedNonlinearMode, CubicAmplitudeDynamics, UnmodelledMode
from .saturation import SoftSaturation
from .slew import AsymmetricSlewLimit
from .voltage import (AllPassDelay, AmplifierBandwidth, AmplifierSaturation, AmplifierSlewLimit, AsymmetricSaturation,
                      InputDelay)

__all__ = ["EffectSpec", "EFFECTS", "EFFECT_NAMES", "build_plant"]


@dataclass(frozen=True)
class EffectSpec:
    """Name, position and parameters of one candidate effect.

    ``params`` maps parameter name → (unit, per_axis).  ``position`` is 'pre' (voltage), 'post' (displacement) or
    'hysteresis' (replaces the nominal Bouc-Wen).
    """

    name: str
    position: str
    params: Mapping[str, tuple[str, bool]]
    description: str
    signature: str


EFFECTS: dict[str, EffectSpec] = {s.name: s for s in [
    EffectSpec("hysteresis_asymmetry", "hysteresis", {"Delta1": ("1/V", True), "Delta2": ("1/V", True),
                                                      "even": ("-", True), "branch_even": ("-", True),
                                                      "play_radii": ("m", False), "play_gains": ("-", True),
                                                      "input_even": ("-", True), "input_play_radii": ("V", False),
                                                      "input_play_gains": ("-", True),
                                                      "input_play_level_gains": ("-", True),
                                                      "relay_alpha": ("V", False), "relay_beta": ("V", False),
                                                      "relay_gains": ("V", True)},
               "generalized Bouc-Wen (+ an even, branch-dependent term): ascending and descending branches not "
               "point-symmetric",
               "even harmonics in the residual (error correlates with U², not U)"),
    EffectSpec("hysteresis_rate_dependence", "hysteresis", {"alpha": ("-", False), "relaxation": ("s", False),
                                                            "velocity_gain": ("V", True),
                                                            "velocity_exponent": ("-", False),
                                                            "velocity_smoothing": ("s", False),
                                                            "rate_play_radii": ("V", False),
                                                            "rate_play_gains": ("-", True),
                                                            "rate_play_ref": ("V/s", False),
                                                            "rate_play_smoothing": ("s", False)},
               f"loop width grows with the voltage rate (A·(1 + α·tanh(|dU/dt|/{RATE_REF:g} V/s))), or a "
               f"velocity-damping term Dp·c·sgn(dU/dt)·|dU/dt / {RATE_REF:g} V/s|^m on the hysteresis output, or "
               "play widths growing with the rate (rate-dependent Prandtl-Ishlinskii thresholds)",
               "loop-width error grows with frequency (error correlates with sign(dU/dt)·|dU/dt|)"),
    EffectSpec("creep_nonlinearity", "post", {"gamma": ("-", True), "beta": ("-", False),
                                              "beta_even": ("-", False), "spectrum": ("-", True),
                                              "retardation": ("s", False), "kv_gains": ("-", True),
                                              "kv_level_gains": ("-", True)},
               "creep growing with the level (γ per decade, β at 10 µm), logarithmic in time or, with a relaxation "
               "spectrum (Prony series over the decades), any linear creep law; or one Kelvin–Voigt element of "
               "free retardation time fed by the level and its signed square (``retardation``)",
               "slow residual after level changes, linear in log-time"),
    EffectSpec("thermal_drift", "post", {"amplitudes": ("m", True), "time_constant": ("s", False),
                                        "amplitudes2": ("m", True), "time_constant2": ("s", False),
                                        "gain_drift": ("-", True), "gain_drift2": ("-", True)},
               "thermal expansion after switch-on, a_i·(1 − exp(−t/τ))",
               "residual trend over the whole run, uncorrelated with the voltage"),
    EffectSpec("input_delay", "pre", {"delay": ("s", False), "form": ("-", False)},
               "delay between the commanded and the acting voltage: pure (interpolated), or all-pass (form "
               "'allpass': 2nd-order Padé, unit gain, the phase lag of the delay)",
               "residual ∝ −delay·dŶ/dt: phase lag growing linearly with frequency"),
    EffectSpec("amplifier_slew_limit", "pre", {"rate": ("V/s", False), "rate_down": ("V/s", False)},
               "amplifier slew-rate limit (``rate``; with ``rate_down`` the falling voltage has its own: a driver "
               "that sources and sinks different currents)",
               "error concentrated where |dU/dt| is large (steps, fast ramps)"),
    EffectSpec("amplifier_saturation", "pre", {"limit": ("V", False), "lower_limit": ("V", False),
                                               "sharpness": ("-", False)},
               "amplifier output rails clip the voltage (hard, or a soft knee v/(1 + (|v|/L)^p)^(1/p) per rail)",
               "error only at the largest |U|"),
    EffectSpec("amplifier_bandwidth", "pre", {"cutoff": ("Hz", True), "order": ("-", False),
                                              "damping": ("-", False), "form": ("-", False)},
               "first-, second- or third-order amplifier roll-off (cutoff per axis; form 'bessel': linear phase)",
               "amplitude loss and phase lag at high frequency; steps rounded, not shifted"),
    EffectSpec("unmodelled_mode", "post", {"freq": ("Hz", False), "damping": ("-", False), "gains": ("-", True),
                                          "hp_gains": ("-", True), "lp_gains": ("-", True)},
               "extra lightly damped structural resonances (one or several, per axis and cross-coupled)",
               "narrow peaks in the residual spectrum"),
    EffectSpec("amplitude_dependent_dynamics", "post",
               {"freq": ("Hz", False), "damping": ("-", False), "gains": ("-", True), "hp_gains": ("-", True),
                "level_gains": ("-", True), "level_hp_gains": ("-", True), "cubic_gains": ("-", True),
                "cubic_hp_gains": ("-", True), "lp_gains": ("-", True), "form": ("-", False), "cubic": ("-", True),
                "quadratic_damping": ("-", True), "participation": ("-", True)},
               f"resonances whose strength moves with the level (|Y| over {LEVEL_TAU:g} s per {LEVEL_REF:g} m); "
               "form 'base_excited': one mode with a cubic spring and a quadratic damping, shaken by the motion",
               "dynamics-band residual growing with the motion's amplitude"),
    EffectSpec("gain_mismatch", "post", {"gains": ("-", True), "cross_gains": ("-", True)},
               "gain error per axis and cross-talk between axes (piezo coefficient, amplifier, sensor calibration)",
               "residual ∝ Ŷ on each axis (a scaled copy of the prediction)"),
]}


EFFECT_NAMES = tuple(EFFECTS)


def _stage(name: str, p: Mapping[str, Any], cfg: PiezoConfig) -> Processor:
    n, dt = cfg.n_axes, cfg.dt
    if name == "input_delay":
        form = p.get("form", "pure")
        if form == "allpass":
            return AllPassDelay(p["delay"], dt, n)
        if form != "pure":
            raise ValueError(f"input_delay.form: must be 'pure' or 'allpass', got {form!r}")
        return InputDelay(p["delay"], dt, n)
    if name == "amplifier_slew_limit":
        if p.get("rate_down") is not None:
            return AsymmetricSlewLimit(p["rate"], p["rate_down"], dt, n)
        return AmplifierSlewLimit(p["rate"], dt, n)
    if name == "amplifier_saturation":
        if p.get("sharpness") is not None:
            return SoftSaturation(p["limit"], p.get("lower_limit") or p["limit"], p["sharpness"], n)
        if p.get("lower_limit") is not None:
            return AsymmetricSaturation(p["limit"], p["lower_limit"], n)
        return AmplifierSaturation(p["limit"], n)
    if name == "amplifier_bandwidth":
        return AmplifierBandwidth(p["cutoff"], dt, n, int(p.get("order", 1)), float(p.get("damping", 2 ** -0.5)),
                                  str(p.get("form", "filter")))
    if name == "gain_mismatch":
        return GainMismatch(p["gains"], n, p.get("cross_gains"))
    if name == "thermal_drift":
        return ThermalDrift(p["amplitudes"], p["time_constant"], dt, n, p.get("amplitudes2"), p.get("time_constant2"),
                            p.get("gain_drift"), p.get("gain_drift2"))
    if name == "creep_nonlinearity":
        if p.get("retardation") is not None:
            return KelvinVoigtCreep(p["retardation"], p["kv_gains"], p["kv_level_gains"], dt, n)
        return CreepNonlinearity(p["gamma"], p.get("beta", 0.0), dt, n, spectrum=p.get("spectrum"),
                                 beta_even=float(p.get("beta_even", 0.0)))
    if name == "unmodelled_mode":
        return UnmodelledMode(p["freq"], p["damping"], p["gains"], dt, n, p.get("hp_gains"), p.get("lp_gains"))
    if name == "amplitude_dependent_dynamics":
        if p.get("form", "filters") == "base_excited":
            return BaseExcitedNonlinearMode(p["freq"], p["damping"], p.get("cubic", 0.0), p.get("quadratic_damping", 0.0),
                                            dt, n, p.get("participation", 1.0))
        if p.get("cubic_gains") is not None:
            return CubicAmplitudeDynamics(p["freq"], p["damping"], p["gains"], p["level_gains"], dt, n,
                                          p.get("hp_gains"), p.get("level_hp_gains"), p["cubic_gains"],
                                          p.get("cubic_hp_gains"), p.get("lp_gains"))
        return AmplitudeDependentDynamics(p["freq"], p["damping"], p["gains"], p["level_gains"], dt, n,
                                          p.get("hp_gains"), p.get("level_hp_gains"), p.get("lp_gains"))
    raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")


def build_plant(cfg: PiezoConfig, effects: Sequence[tuple[str, Mapping[str, Any]]] = (), noise_std: float = 0.0,
                seed: int = 0) -> Plant:
    """The nominal plant of ``cfg`` with ``effects`` = ``[(name, params), …]`` added (see :data:`EFFECTS`).

    Voltage-side effects are applied in the order given, then the hysteresis (generalized/rate-dependent when
    those effects are present), creep and dynamics, then the displacement-side effects in the order given.
    """
    pre: list[Processor] = []
    post: list[Processor] = []
    hcfg, alpha, custom_h = cfg.hysteresis, 0.0, False
    relax = 0.0
    extras: list[VelocityTerm | LoopShapeTerm | RatePlayTerm | RelayPlaneTerm] = []
    for name, p in effects:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
        spec = EFFECTS[name]
        if name == "hysteresis_asymmetry":
            hcfg = asymmetric_hysteresis_config(hcfg, p["Delta1"], p.get("Delta2", 0.0))
            custom_h = True
            if "even" in p or "branch_even" in p:
                post.append(BranchEvenTerm(p.get("even", 0.0), p.get("branch_even", 0.0), cfg.dt, cfg.n_axes))
            if p.get("play_radii"):
                post.append(PlayWidthTerm(p["play_radii"], p["play_gains"], cfg.n_axes))
            if p.get("input_play_radii"):
                extras.append(LoopShapeTerm(np.diag(cfg.hysteresis.arrays()["Dp"]), p.get("input_even", 0.0),
                                            p["input_play_radii"], p["input_play_gains"],
                                            p["input_play_level_gains"]))
            if p.get("relay_alpha"):
                extras.append(RelayPlaneTerm(np.diag(cfg.hysteresis.arrays()["Dp"]), p["relay_alpha"],
                                             p["relay_beta"], p["relay_gains"]))
        elif name == "hysteresis_rate_dependence":
            alpha += float(p.get("alpha", 0.0))
            custom_h = True
            if p.get("velocity_gain") is not None:
                dp = np.diag(cfg.hysteresis.arrays()["Dp"])
                extras.append(VelocityTerm(dp, p["velocity_gain"], float(p.get("velocity_exponent", 0.5)),
                                           float(p.get("velocity_smoothing", 0.0)), cfg.dt))
            if p.get("rate_play_radii"):
                extras.append(RatePlayTerm(np.diag(cfg.hysteresis.arrays()["Dp"]), p["rate_play_radii"],
                                           p["rate_play_gains"], float(p["rate_play_ref"]),
                                           float(p.get("rate_play_smoothing", 0.0)), cfg.dt))
            if p.get("relaxation") is not None:
                r = float(p["relaxation"])
                if not (math.isfinite(r) and r >= 0):
                    raise ValueError(f"hysteresis_rate_dependence.relaxation: must be >= 0 s, got {r!r}")
                relax = max(relax, r)
        elif spec.position == "pre":
            pre.append(_stage(name, p, cfg))
        else:
            post.append(_stage(name, p, cfg))
    if custom_h:
        pre.append(HysteresisStage(hcfg, alpha, cfg.dt, tuple(extras)) if relax <= 0 else
                   RelaxedHysteresisStage(hcfg, alpha, cfg.dt, relax, tuple(extras)))
        return Plant(cfg, pre=pre, post=post, noise_std=noise_std, seed=seed, stages=("creep", "dynamics"))
    return Plant(cfg, pre=pre, post=post, noise_std=noise_std, seed=seed)
