"""Physical forms of the dynamics candidates: a nonlinear first mode (cubic spring, quadratic damping) is named
``amplitude_dependent_dynamics`` by a few-parameter base-excited mode, and a linear-phase (Bessel) amplifier
roll-off is an ``amplifier_bandwidth``, not a delay.  Truths are small independent simulations (their own
integrators and scipy filters) on the nominal model's output or in front of it; excitations the in-family ones at
5 kHz (multisines up to 400 Hz, held steps)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from bench.synthetic.in_family import excitation
from piezo_ff_ros.core._jit import njit
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose
from piezo_ff_ros.core.models.effects import BaseExcitedNonlinearMode, build_plant

# the 5 kHz in-family runs and the ranking view of the linear-dynamics tests, shared
from test_diagnosis_linear_dynamics import DUR, FS, _filtered_voltage_truth, _ranking, _runs_from, cfg  # noqa: F401 (cfg is a fixture)


def test_base_excited_mode_is_block_split_invariant_and_silent_when_linear():
    """The stage gives the same output whatever the block split, and adds nothing when both nonlinear coefficients
    are zero (its linear twin is subtracted)."""
    dt = 1 / FS
    t = np.arange(6000) * dt
    y = np.stack([5e-6 * np.sign(np.sin(2 * np.pi * 3 * t)), 3e-6 * np.sin(2 * np.pi * 200 * t)], axis=1)
    st = BaseExcitedNonlinearMode(900.0, 0.05, [2.0, -0.5], [1.0, 0.0], dt)
    whole = st.process(y)
    st.reset()
    parts = np.vstack([st.process(y[:1]), st.process(y[1:777]), st.process(y[777:])])
    assert np.array_equal(whole, parts)
    assert np.max(np.abs(whole - y)) > 1e-8
    lin = BaseExcitedNonlinearMode(900.0, 0.05, 0.0, 0.0, dt)
    assert np.array_equal(lin.process(y), y)


@njit
def _nonlinear_mode_change(y, fs, f0, zeta, beta, kappa, yref, over=16):
    """d'' + 2ζω(1 + κ|d'|/(ω·yref))·d' + ω²·d·(1 + β(d/yref)²) = −y'' per column (d: the mode's deflection
    relative to its base y), minus the same with β = κ = 0: the base moves at a constant velocity over each sample
    interval (its velocity steps at the samples: an impulse on d'), semi-implicit Euler at ``over``× the record's
    rate (a different integrator from the package's RK4).  Compiled (the test's own loop, ~2.5 M steps a record)
    when numba is there, so that the truth does not cost more than the diagnosis it checks."""
    w = 2 * np.pi * f0
    h = 1 / (over * fs)
    out = np.zeros_like(y)
    for j in range(y.shape[1]):
        st = np.zeros((2, 2))  # rows: (d, d') nonlinear, linear
        yd_prev = 0.0
        for k in range(1, len(y)):
            yd = (y[k, j] - y[k - 1, j]) * fs
            for s in range(2):
                b = beta if s == 0 else 0.0
                kq = kappa if s == 0 else 0.0
                d = st[s, 0]
                v = st[s, 1] - (yd - yd_prev)
                for _ in range(over):
                    v += h * (-2 * zeta * w * (1 + kq * abs(v) / (w * yref)) * v - w * w * d * (1 + b * (d / yref) ** 2))
                    d += h * v
                st[s, 0] = d
                st[s, 1] = v
            yd_prev = yd
            out[k, j] = st[0, 0] - st[1, 0]
    return out


@pytest.mark.parametrize("beta, kappa", [(0.0, 1.5)])
def test_a_nonlinear_first_mode_is_named_by_the_base_excited_form(cfg, beta, kappa):
    """The nominal output shaken through a 900 Hz mode (ζ 0.046, participation 0.8) with quadratic damping, minus
    its linear twin: the level-modulated filter family fits it with 80 filter gains, the base-excited mode with
    2 + 3n physical parameters down to the noise — amplitude_dependent_dynamics in that form, at its frequency."""
    nominal = build_plant(cfg, [])

    def truth(u):
        nominal.reset()
        y = nominal.process(u)
        return y + 0.8 * _nonlinear_mode_change(y, FS, 900.0, 0.046, beta, kappa, 2e-6)

    train, test = _runs_from(cfg, truth, seed=31)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=("unmodelled_mode", "amplitude_dependent_dynamics",
                                                                  "gain_mismatch", "input_delay"), max_stack=1))
    assert res["verdict"] == "amplitude_dependent_dynamics", (_ranking(res), res["confidence_reason"])
    top = res["ranking"][0]
    assert top["params"]["form"]["value"] == "base_excited"
    assert top["params"]["freq"]["value"] == pytest.approx(900.0, rel=0.1)


OVER = 20


def test_a_bessel_roll_off_is_amplifier_bandwidth_not_a_delay(cfg):
    """A third-order Bessel low-pass (−3 dB at 1 kHz, maximally flat group delay) on the DAC's staircase in front
    of the nominal model, both at 20× the record's rate (scipy's Bessel, the nominal replayed by the benchmark's own
    code): in the band it is a delay, but the excitation's steps carry energy near the cut-off where its magnitude
    falls (a delay is all-pass) — an amplifier_bandwidth."""
    b, a = scipy.signal.bessel(3, 2 * np.pi * 1000.0, analog=True, norm="mag")
    bd, ad, _ = scipy.signal.cont2discrete((b, a), 1 / (OVER * FS), method="zoh")
    train, test = _runs_from(cfg, _filtered_voltage_truth(cfg, bd, ad), seed=41)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=("input_delay", "amplifier_bandwidth",
                                                                  "gain_mismatch", "unmodelled_mode"), max_stack=1))
    assert res["verdict"] == "amplifier_bandwidth", (_ranking(res), res["confidence_reason"])
    h = res["heldout"]
    assert h["after_nrmse_percent"] < 0.2 * h["before_nrmse_percent"]
