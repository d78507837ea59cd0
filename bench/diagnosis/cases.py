"""Case list of the independent diagnosis benchmark: withheld effects, their forms, and the verdict each should get.

Every template draws its parameters, sample rate, record length and noise from a generator seeded by (seed,
template name), so a seed set fixes the whole benchmark.  The forms are this benchmark's own and differ from the
diagnosis candidates' parameterisations on purpose (an asymmetric Prandtl–Ishlinskii or a voltage-biased Bouc-Wen
gain instead of the Δ1/Δ2 terms, a logarithmic or power creep law instead of a bank of first-order lags, a
heating ramp or a sensor-offset drift instead of one exponential, Lagrange FIR or DAC-latency delays instead of
interpolation, tanh-knee and asymmetric clipping instead of a hard clip, a current-limited amplifier instead of a
rate limiter, 2nd-order roll-offs, pole–zero series modes and static-free parallel modes, several per axis and
cross-coupled, instead of one shared band-pass mode, voltage-side and cross-gain errors, amplitude-dependent
resonances).

Expected verdicts use the diagnosis vocabulary (``docs/diagnosis.md``): an effect is named by the library member
that describes its physics, whatever the form the truth uses.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["Template", "TEMPLATES", "Case", "make_cases", "in_family_cases", "REGIMES", "NOISE_KINDS"]

UM = 1e-6

#: sample rate [Hz] and record length [s] ranges per regime; quick mode shortens records (tests, smoke runs)
REGIMES = {
    "slow": {"fs": (200.0, 250.0, 400.0, 500.0), "duration": (60.0, 225.0), "quick": 30.0},
    "mid": {"fs": (1000.0, 2000.0), "duration": (15.0, 45.0), "quick": 8.0},
    "fast": {"fs": (5000.0, 10000.0, 20000.0), "duration": None, "quick": 1.5},
}
#: record length at the fast rates [s], about the same number of samples whatever the rate
FAST_DURATION = {5000.0: (4.0, 10.0), 10000.0: (2.5, 6.0), 20000.0: (1.5, 3.5)}

#: sensor noise kinds: white Gaussian + ADC step; + a low-passed (coloured) part; a coarse ADC
NOISE_KINDS = {
    "white": {"white": 30e-9, "quantum": 10e-9},
    "coloured": {"white": 20e-9, "coloured": 25e-9, "corner": None, "quantum": 10e-9},
    "quantised": {"white": 5e-9, "quantum": 40e-9},
}


@dataclass
class Template:
    """One withheld-effect form: ``draw(rng, fs, duration, nom) -> list of truth stages`` (see truth.simulate)."""

    name: str
    expected: str
    regimes: tuple
    draw: Callable
    amplitude: float = 110.0
    note: str = ""


@dataclass
class Case:
    """One instantiated benchmark case (what run.py generates, diagnoses and scores)."""

    name: str
    template: str
    expected: str
    family: str
    seed: int
    regime: str
    fs: float
    duration: float
    noise_kind: str
    noise: dict
    effects: list = field(default_factory=list)
    amplitude: float = 110.0
    in_family: dict | None = None   # the project's own generator: {'case': …} of truth_cases()


def _pm(rng, lo, hi, n=None):
    """Magnitude in [lo, hi] with a random sign."""
    v = rng.uniform(lo, hi, n)
    return v * rng.choice([-1.0, 1.0], n)


def _light_modes(nom, axis):
    """The lightly damped resonances (ζ < 0.1) of G_L's diagonal entry of ``axis``: [(f Hz, ζ)]."""
    tf = nom["G_L_tf"][axis, axis]
    out = []
    for f in tf.den:
        if len(f) == 3:
            w = math.sqrt(f[2] / f[0])
            z = f[1] / f[0] / (2 * w)
            if z < 0.1:
                out.append((w / (2 * math.pi), z))
    return out


def _mode_freq(rng, fs, where):
    """A structural mode below (150–700 Hz) or above (2–4.5 kHz) the main resonances, resolvable at fs."""
    top = 0.3 * fs
    if where == "above" and top > 2200:
        return rng.uniform(2000.0, min(4500.0, top))
    return rng.uniform(min(150.0, 0.1 * fs), min(700.0, top))


# ---- the forms ---------------------------------------------------------------------------------------------------

def _asym_pi(rng, fs, T, nom):
    return [{"kind": "asym_pi", "radii": list(rng.uniform(8, 40, 3)), "weights": list(rng.uniform(0.03, 0.07, 3)),
             "c_up": list(rng.uniform(0.04, 0.1, 2)), "c_down": list(rng.uniform(-0.06, 0.0, 2)), "u_ref": 100.0}]


def _biased_bw(rng, fs, T, nom):
    return [{"kind": "biased_bw", "kappa": list(_pm(rng, 0.15, 0.35, 2)), "u_bias": list(rng.uniform(-30, 30, 2)),
             "u_scale": float(rng.uniform(40, 80))}]


def _rate_power(rng, fs, T, nom):
    return [{"kind": "rate_law", "alpha": float(rng.uniform(0.15, 0.35)), "rate_ref": 5000.0,
             "exponent": float(rng.uniform(0.4, 0.7)), "smoothing": float(rng.uniform(2, 5) / fs)}]


def _lagged_h(rng, fs, T, nom):
    return [{"kind": "lagged_hysteresis", "tau": float(rng.uniform(0.5e-3, 3e-3))}]


def _creep_log(rng, fs, T, nom):
    return [{"kind": "creep_law", "law": "log", "gamma": list(rng.uniform(0.02, 0.04, 2)),
             "tau0": float(rng.uniform(0.02, 0.2)), "level_coef": float(_pm(rng, 0.3, 0.8)), "y_ref": 10 * UM}]


def _creep_power(rng, fs, T, nom):
    return [{"kind": "creep_law", "law": "power", "gamma": list(rng.uniform(0.06, 0.12, 2)),
             "alpha": float(rng.uniform(0.08, 0.15)), "tau0": float(rng.uniform(0.05, 0.5)),
             "level_coef": float(_pm(rng, 0.3, 0.8)), "y_ref": 10 * UM}]


def _heating(rng, fs, T, nom):
    return [{"kind": "heating", "ramp_time": float(rng.uniform(0.5, 1.5) * T),
             "gain_per_unit": list(_pm(rng, 0.01, 0.03, 2)), "offset": list(_pm(rng, 0.5, 1.5, 2) * UM)}]


def _sensor_drift(rng, fs, T, nom):
    total = _pm(rng, 0.5, 1.5, 2) * UM
    return [{"kind": "sensor_drift", "rate": list(total / T), "curvature": list(_pm(rng, 0.05, 0.2, 2) * UM / T ** 2),
             "period": float(rng.uniform(1.5, 4.0) * T), "wobble": list(_pm(rng, 0.02, 0.08, 2) * UM)}]


def _lagrange(rng, fs, T, nom):
    return [{"kind": "lagrange_delay", "samples": float(rng.uniform(1.2, 3.5))}]


def _dac(rng, fs, T, nom):
    return [{"kind": "dac_latency", "samples": float(rng.uniform(0.25, 1.8))}]


def _soft_clip(rng, fs, T, nom):
    L = float(rng.uniform(88, 102))
    return [{"kind": "clip", "upper": L, "lower": L, "knee": float(rng.uniform(8, 20))}]


def _asym_clip(rng, fs, T, nom):
    a, b = float(rng.uniform(85, 102)), float(rng.uniform(108, 125))
    if rng.random() < 0.5:
        a, b = b, a
    return [{"kind": "clip", "upper": a, "lower": b, "knee": float(rng.uniform(2, 6))}]


def _current_sym(rng, fs, T, nom):
    S = float(fs * rng.uniform(2.0, 8.0))
    return [{"kind": "current_limit", "rate_up": S, "rate_down": S, "tau": 0.2 / fs}]


def _current_asym(rng, fs, T, nom):
    S = float(fs * rng.uniform(2.0, 8.0))
    r = float(rng.uniform(0.3, 0.6))
    up, down = (S, S * r) if rng.random() < 0.5 else (S * r, S)
    return [{"kind": "current_limit", "rate_up": up, "rate_down": down, "tau": 0.2 / fs}]


def _rolloff1(rng, fs, T, nom):
    return [{"kind": "rolloff", "order": 1, "cutoff": float(fs / rng.uniform(5.0, 30.0))}]


def _rolloff2(rng, fs, T, nom):
    return [{"kind": "rolloff", "order": 2, "zeta": float(rng.uniform(0.5, 0.8)),
             "cutoff": float(fs / rng.uniform(4.0, 25.0))}]


def _series_modes(rng, fs, T, nom):
    per_axis = []
    for ax in range(2):
        fp = _mode_freq(rng, fs, rng.choice(["below", "above"]))
        zp = rng.uniform(0.01, 0.04)
        fz = fp * (rng.uniform(0.85, 0.93) if rng.random() < 0.5 else rng.uniform(1.07, 1.15))
        per_axis.append([(float(fp), float(zp), float(fz), float(rng.uniform(0.01, 0.04)))])
    return [{"kind": "series_modes", "per_axis": per_axis}]


def _parallel_modes(rng, fs, T, nom):
    modes = []
    for ax in range(2):
        for where in ("below", "above"):
            modes.append((ax, ax, float(_mode_freq(rng, fs, where)), float(rng.uniform(0.01, 0.05)),
                          float(_pm(rng, 0.04, 0.1))))
    j = int(rng.integers(2))
    modes.append((1 - j, j, float(_mode_freq(rng, fs, "below")), float(rng.uniform(0.01, 0.05)),
                  float(_pm(rng, 0.03, 0.08))))
    return [{"kind": "parallel_modes", "modes": modes}]


def _voltage_gain(rng, fs, T, nom):
    M = np.eye(2) + np.diag(_pm(rng, 0.02, 0.05, 2))
    M[0, 1], M[1, 0] = _pm(rng, 0.005, 0.02, 2)
    return [{"kind": "voltage_gain", "matrix": M.tolist()}]


def _cross_gain(rng, fs, T, nom):
    M = np.eye(2) + np.diag(_pm(rng, 0.01, 0.04, 2))
    M[0, 1], M[1, 0] = _pm(rng, 0.01, 0.04, 2)
    return [{"kind": "output_gain", "matrix": M.tolist()}]


def _amp_envelope(rng, fs, T, nom):
    modes = [(lambda ms: ms[int(rng.integers(len(ms)))])(_light_modes(nom, ax)) for ax in range(2)]
    return [{"kind": "amplitude_mode", "modes": modes, "kw": list(rng.uniform(0.04, 0.1, 2)),
             "kz": list(rng.uniform(0.5, 1.5, 2)), "duffing": [0.0, 0.0], "y_ref": 10 * UM, "env_tau": 0.05}]


def _amp_duffing(rng, fs, T, nom):
    modes = [(lambda ms: ms[int(rng.integers(len(ms)))])(_light_modes(nom, ax)) for ax in range(2)]
    return [{"kind": "amplitude_mode", "modes": modes, "kw": [0.0, 0.0], "kz": [0.0, 0.0],
             "duffing": list(rng.uniform(0.1, 0.3, 2)), "y_ref": 10 * UM, "env_tau": 0.05}]


def _scaled(draw, **scale):
    """A secondary effect: ``draw`` with its deviation scaled down (gains toward 1, amplitudes toward 0)."""
    def f(rng, fs, T, nom):
        out = []
        for e in draw(rng, fs, T, nom):
            e = dict(e)
            for k, s in scale.items():
                v = np.asarray(e[k], float)
                e[k] = (np.eye(2) + s * (v - np.eye(2))).tolist() if k == "matrix" else (v * s).tolist()
            out.append(e)
        return out
    return f


def _combo(main, second):
    return lambda rng, fs, T, nom: main(rng, fs, T, nom) + second(rng, fs, T, nom)


ALL = ("slow", "mid", "fast")
TEMPLATES = [
    Template("asymmetry/asym_prandtl_ishlinskii", "hysteresis_asymmetry", ALL, _asym_pi),
    Template("asymmetry/biased_bouc_wen", "hysteresis_asymmetry", ALL, _biased_bw),
    Template("rate/power_law_gain", "hysteresis_rate_dependence", ("mid", "fast"), _rate_power),
    Template("rate/lagged_state", "hysteresis_rate_dependence", ("mid", "fast"), _lagged_h),
    Template("creep/log_law_level", "creep_nonlinearity", ("slow", "mid"), _creep_log),
    Template("creep/power_law_level", "creep_nonlinearity", ("slow", "mid"), _creep_power),
    Template("drift/heating_ramp", "thermal_drift", ("slow", "mid"), _heating),
    Template("drift/sensor_offset", "thermal_drift", ("slow", "mid"), _sensor_drift),
    Template("delay/lagrange_fir", "input_delay", ALL, _lagrange),
    Template("delay/dac_latency", "input_delay", ALL, _dac),
    Template("saturation/soft_knee", "amplifier_saturation", ALL, _soft_clip, amplitude=135.0),
    Template("saturation/asymmetric", "amplifier_saturation", ALL, _asym_clip, amplitude=135.0),
    Template("slew/current_limited", "amplifier_slew_limit", ALL, _current_sym),
    Template("slew/asymmetric_current", "amplifier_slew_limit", ALL, _current_asym),
    Template("rolloff/first_order", "amplifier_bandwidth", ALL, _rolloff1),
    Template("rolloff/second_order", "amplifier_bandwidth", ALL, _rolloff2),
    Template("mode/series_per_axis", "unmodelled_mode", ("fast",), _series_modes),
    Template("mode/several_cross_coupled", "unmodelled_mode", ("mid", "fast"), _parallel_modes),
    Template("gain/voltage_side", "gain_mismatch", ALL, _voltage_gain),
    Template("gain/sensor_cross_talk", "gain_mismatch", ALL, _cross_gain),
    Template("amplitude/envelope_resonance", "amplitude_dependent_dynamics", ("fast",), _amp_envelope),
    Template("amplitude/duffing_mode", "amplitude_dependent_dynamics", ("fast",), _amp_duffing),
    # two effects, the first dominant
    Template("two/rolloff+cross_gain", "amplifier_bandwidth", ("mid", "fast"),
             _combo(_rolloff1, _scaled(_cross_gain, matrix=0.3))),
    Template("two/creep+voltage_gain", "creep_nonlinearity", ("slow", "mid"),
             _combo(_creep_log, _scaled(_voltage_gain, matrix=0.25))),
    Template("two/asymmetry+sensor_drift", "hysteresis_asymmetry", ALL,
             _combo(_biased_bw, _scaled(_sensor_drift, rate=0.25, curvature=0.25, wobble=0.25))),
    Template("two/mode+dac_latency", "unmodelled_mode", ("fast",),
             _combo(_series_modes, lambda rng, fs, T, nom: [{"kind": "dac_latency",
                                                              "samples": float(rng.uniform(0.1, 0.2))}])),
    # nulls: several per regime and noise kind
    Template("null/slow_white", "none", ("slow",), lambda *a: []),
    Template("null/slow_coloured", "none", ("slow",), lambda *a: []),
    Template("null/mid_quantised", "none", ("mid",), lambda *a: []),
    Template("null/mid_coloured", "none", ("mid",), lambda *a: []),
    Template("null/fast_white", "none", ("fast",), lambda *a: []),
    Template("null/fast_coloured", "none", ("fast",), lambda *a: []),
]


def _rng(seed: int, name: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(name.encode())])


def make_cases(seeds, quick: bool = False, only: list[str] | None = None, cfg=None) -> list[Case]:
    """Instantiate every template for every seed (out-of-family cases); ``cfg`` = the nominal config (default:
    the package's PT230.94, read through the public ``load_config``)."""
    from piezo_ff_ros.core.config import load_config

    from . import truth

    base = cfg if cfg is not None else load_config()
    noms: dict = {}
    cases = []
    for seed in seeds:
        for tpl in TEMPLATES:
            name = f"{tpl.name}@{seed}"
            if only and not any(name.startswith(o) or tpl.expected == o for o in only):
                continue
            rng = _rng(seed, tpl.name)
            regime = tpl.regimes[int(rng.integers(len(tpl.regimes)))]
            R = REGIMES[regime]
            fs = float(R["fs"][int(rng.integers(len(R["fs"])))])
            lo, hi = R["duration"] if R["duration"] else FAST_DURATION[fs]
            duration = float(rng.uniform(lo, hi))
            if quick:
                duration = float(R["quick"])
            if tpl.name.startswith("null/"):
                noise_kind = tpl.name.rsplit("_", 1)[1]
            else:
                noise_kind = list(NOISE_KINDS)[int(rng.integers(len(NOISE_KINDS)))]
            noise = dict(NOISE_KINDS[noise_kind])
            if "corner" in noise:
                noise["corner"] = float(min(rng.uniform(1.0, 30.0), fs / 8))
            if fs not in noms:
                noms[fs] = truth.nominal_matrices(base.with_sample_rate(fs))
            effects = tpl.draw(rng, fs, duration, noms[fs])
            cases.append(Case(name=name, template=tpl.name, expected=tpl.expected, family="out", seed=int(seed),
                              regime=regime, fs=fs, duration=round(duration, 3), noise_kind=noise_kind, noise=noise,
                              effects=_plain(effects), amplitude=tpl.amplitude))
    return cases


def in_family_cases(seed: int, quick: bool = False, only: list[str] | None = None) -> list[Case]:
    """The old ``bench/bench_diagnosis.py`` cases, made by the project's own generator (same families as the
    candidates): 5 kHz, 20 s records, 100 nm white noise; ``seed`` shifts excitations and noise."""
    from bench.synthetic.in_family import truth_cases

    out = []
    for c in truth_cases():
        name = f"in/{c['name']}@{seed}"
        if only and not any(name.startswith(o) or c["effect"] == o for o in only):
            continue
        out.append(Case(name=name, template=f"in/{c['name']}", expected=c["effect"], family="in", seed=int(seed),
                        regime="fast", fs=5000.0, duration=4.0 if quick else 20.0, noise_kind="white(100 nm)",
                        noise={}, effects=[], in_family=_plain(c)))
    return out


def _plain(x):
    """JSON-friendly copy (numpy scalars/arrays → floats/lists, tuples → lists)."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x
