"""Section VII-A metrics on signals whose answer is known analytically."""
import math

import numpy as np
import pytest
from scipy import signal

from piezo_ff_ros.core import metrics as M

FS = 20000.0


def test_hysteresis_ellipse_known_width():
    # u = U cos θ, y = a cos θ + b sin θ: vertical width at u is 2b·sin θ, max 2b at u = 0; range 2√(a²+b²)
    th = np.linspace(0, 2 * np.pi, 40001)
    for a, b in ((1.0, 0.3), (2e-5, 1e-6), (1.0, 0.0)):
        r = M.hysteresis_ratio(200 * np.cos(th), a * np.cos(th) + b * np.sin(th))
        assert r.h == pytest.approx(2 * b, rel=1e-4, abs=1e-12)
        assert r.H == pytest.approx(2 * math.hypot(a, b), rel=1e-6)
        assert r.ratio == pytest.approx(b / math.hypot(a, b), rel=1e-4, abs=1e-9)


def test_hysteresis_uses_last_period_of_a_long_record():
    t = np.arange(0, 25.0, 1 / 2000.0)
    u = 200 * np.sin(2 * np.pi * 0.1 * t)
    # a first-order lag (ellipse) whose amplitude builds up: only the steady last period must count
    phase = 0.2
    y = (1 - np.exp(-t / 2.0)) * np.sin(2 * np.pi * 0.1 * t - phase)
    r = M.hysteresis_ratio(u, y, period_t=t, period=10.0)
    assert r.ratio == pytest.approx(math.sin(phase), rel=2e-3)
    with pytest.raises(ValueError, match="shorter than one period"):
        M.hysteresis_ratio(u[:100], y[:100], period_t=t[:100], period=10.0)


def test_hysteresis_rejects_monotone_input():
    with pytest.raises(ValueError, match="rise and fall"):
        M.hysteresis_ratio(np.linspace(0, 1, 100), np.linspace(0, 1, 100))


def _step(sys, t, t_step, amp):
    y = np.zeros_like(t)
    after = t >= t_step
    _, ys = signal.step(sys, T=t[after] - t_step)
    y[after] = amp * ys
    return y


def test_overshoot_second_order_analytic():
    t = np.arange(0, 1.0, 1 / FS)
    wn = 2 * np.pi * 40
    for zeta in (0.05, 0.2, 0.5):
        y = _step(signal.lti([wn ** 2], [1, 2 * zeta * wn, wn ** 2]), t, 0.05, -20e-6) + 3e-6
        r = M.overshoot_ratio(t, y, t_step=0.05)
        assert r.ratio == pytest.approx(math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2)), rel=2e-3)
        assert r.A_f == pytest.approx(-20e-6, rel=1e-3)  # relative to the pre-step level, sign kept
        assert r.t_peak == pytest.approx(math.pi / (wn * math.sqrt(1 - zeta ** 2)), abs=2 / FS)


def test_overshoot_first_order_is_zero_and_settling_time():
    t = np.arange(0, 0.5, 1 / FS)
    tau = 0.01
    y = _step(signal.lti([1], [tau, 1]), t, 0.02, 20e-6)
    r = M.overshoot_ratio(t, y, t_step=0.02)
    assert abs(r.ratio) < 1e-6
    # 2 % band: t = τ·ln(50)
    assert M.settling_time(t, y, t_step=0.02, band=0.02, final=20e-6) == pytest.approx(tau * math.log(50),
                                                                                       abs=2 / FS)
    assert math.isnan(M.settling_time(t[:400], y[:400], t_step=0.0, final=20e-6))


def test_creep_known_drift():
    # y = A_f·(1 + c·(1 − e^{−t/T})) after a fast step: (A_m − A_f)/A_f → c·(1 − e^{−t_end/T}) (up to windows)
    fs = 1000.0
    t = np.arange(0, 600.05, 1 / fs)
    t_step, c, T = 0.05, 0.05, 60.0
    tr = np.clip(t - t_step, 0, None)
    y = np.where(t >= t_step, 20e-6 * (1 + c * (1 - np.exp(-tr / T))), 0.0) + 1e-6
    r = M.creep_ratio(t, y, t_step=t_step)
    A_f = 20e-6 * (1 + c * (1 - np.exp(-0.225 / T)))
    A_m = 20e-6 * (1 + c * (1 - np.exp(-599.5 / T)))
    assert r.A_f == pytest.approx(A_f, rel=1e-6)
    assert r.A_m == pytest.approx(A_m, rel=1e-5)
    assert r.ratio == pytest.approx((A_m - A_f) / A_f, rel=1e-4)
    assert r.ratio_over_Am == pytest.approx((A_m - A_f) / A_m, rel=1e-4)
    assert r.ratio == pytest.approx(0.0494, abs=5e-4)
    # creep time shorter than the record
    r60 = M.creep_ratio(t, y, t_step=t_step, t_creep=60.0)
    assert r60.ratio < r.ratio * 0.7
    with pytest.raises(ValueError, match="beyond the record"):
        M.creep_ratio(t, y, t_step=t_step, t_creep=700.0)


def test_cross_coupling_ratios():
    t = np.linspace(0, 10, 1001)
    direct = 28e-6 * np.sin(t)
    cross = 0.9e-6 * np.sin(t + 0.3)
    assert M.cross_coupling_range_ratio(cross, direct) == pytest.approx(0.9 / 28, rel=1e-3)
    assert M.cross_coupling_final_ratio(-0.11e-6, 19e-6) == pytest.approx(0.11 / 19)


def test_static_and_tracking_errors():
    t = np.arange(0, 1, 1 / FS)
    ref = np.full_like(t, 20e-6)
    y = ref * 1.01
    se = M.static_error(t, y, ref)
    assert se.relative == pytest.approx(0.01) and se.error == pytest.approx(0.2e-6)
    th = 2 * np.pi * t
    R = np.column_stack([20e-6 * np.sin(th), 20e-6 * np.cos(th)])
    Y = np.column_stack([21e-6 * np.sin(th), 21e-6 * np.cos(th)])  # 1 µm radial error everywhere
    te = M.tracking_errors(R, Y)
    assert te.rms_norm == pytest.approx(1e-6) and te.max_norm == pytest.approx(1e-6)
    assert te.rms[0] == pytest.approx(1e-6 / math.sqrt(2), rel=1e-3)
    assert te.max[1] == pytest.approx(1e-6, rel=1e-6)
    masked = M.tracking_errors(R, np.where(t[:, None] < 0.5, Y + 5e-6, Y), mask=t >= 0.5)
    assert masked.max_norm == pytest.approx(1e-6)


def test_bad_signals_are_clear_errors():
    with pytest.raises(ValueError, match="NaN"):
        M.overshoot_ratio([0, 1, 2], [0, np.nan, 1])
    with pytest.raises(ValueError, match="differ in length"):
        M.creep_ratio([0, 1, 2], [0, 1])


def test_noise_robust_variants():
    rng = np.random.default_rng(0)
    th = np.linspace(0, 2 * np.pi, 20001)
    a, b = 28e-6, 2e-6
    y = a * np.cos(th) + b * np.sin(th)
    noisy = y + 100e-9 * rng.standard_normal(th.size)
    exact = b / math.hypot(a, b)
    raw = M.hysteresis_ratio(200 * np.cos(th), noisy).ratio
    robust = M.hysteresis_ratio(200 * np.cos(th), noisy, bins=200).ratio
    assert abs(robust - exact) < 0.3 * abs(raw - exact)
    assert robust == pytest.approx(exact, rel=0.02)
    assert M.hysteresis_ratio(200 * np.cos(th), y, bins=200).ratio == pytest.approx(exact, rel=1e-3)
    t = np.arange(0, 0.5, 1 / FS)
    step = np.where(t >= 0.05, 20e-6 * (1 - np.exp(-(t - 0.05) / 0.005)), 0.0)
    step_noisy = step + 100e-9 * rng.standard_normal(t.size)
    assert M.overshoot_ratio(t, step_noisy, 0.05).ratio > 0.01
    assert M.overshoot_ratio(t, step_noisy, 0.05, lowpass_hz=500.0).ratio < 0.005
    # the low-pass keeps a resonance below its cut-off: overshoot of a 1 kHz, ζ = 0.05 mode barely changes
    wn, zeta = 2 * np.pi * 1000, 0.05
    osc = _step(signal.lti([wn ** 2], [1, 2 * zeta * wn, wn ** 2]), t, 0.05, 20e-6)
    exact = math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2))
    assert M.overshoot_ratio(t, osc, 0.05, lowpass_hz=3000.0).ratio == pytest.approx(exact, rel=0.03)
    cross = 1e-6 * np.sin(th) + 100e-9 * rng.standard_normal(th.size)
    assert M.cross_coupling_range_ratio(cross, y, smooth=50) == pytest.approx(2e-6 / (2 * a), rel=0.05)
