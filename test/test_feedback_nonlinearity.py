"""The linear model with a static output nonlinearity in feedback (core/identification/feedback_nonlinearity.py)."""
import numpy as np
import pytest

from piezo_ff_ros.core.identification import feedback_nonlinearity as fnl

PERIOD = 1024
DT = 1e-4
#: the truth: one lightly damped mode at 800 Hz (ζ = 0.03) with a hardening cubic spring fed back around it
F0, ZETA, K3 = 800.0, 0.03, 0.025


def _truth(u: np.ndarray) -> np.ndarray:
    """Duffing-like truth ``y = G(q)·(u − K3·y³)`` (G: the exact ZOH of ω²/(s² + 2ζωs + ω²)), strictly proper."""
    import scipy.signal

    w = 2 * np.pi * F0
    A, B, _, _, _ = scipy.signal.cont2discrete((np.array([[0.0, 1.0], [-w ** 2, -2 * ZETA * w]]),
                                                np.array([[0.0], [w ** 2]]), np.array([[1.0, 0.0]]),
                                                np.zeros((1, 1))), DT, method="zoh")
    x = np.zeros(2)
    y = np.empty(len(u))
    for k in range(len(u)):
        y[k] = x[0]
        x = A @ x + B[:, 0] * (u[k] - K3 * y[k] ** 3)
    return y


def _multisine(rng, rms: float) -> np.ndarray:
    """Two periods of a random-phase multisine exciting bins 1 … 300 (30 Hz – 2.9 kHz at 10 kHz), RMS ``rms``."""
    spec = np.zeros(PERIOD // 2 + 1, complex)
    spec[1:301] = np.exp(2j * np.pi * rng.random(300))
    s = np.fft.irfft(spec, PERIOD)
    return np.tile(s / np.std(s) * rms, 2)[:, None]


def _records(rng, levels, per_level):
    us = [_multisine(rng, a) for a in levels for _ in range(per_level)]
    # the truth from the periodic steady state: one period of warm-up, dropped
    ys = [_truth(np.concatenate([u[:PERIOD, 0], u[:, 0]]))[PERIOD:, None] for u in us]
    return us, ys


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(3)
    train = _records(rng, (0.1, 0.2, 0.3), 3)
    test = _records(rng, (0.15, 0.25), 2)        # levels between those trained on, new phases
    return train, test


def test_a_known_static_cubic_in_feedback_is_recovered_in_simulation(data):
    """Fitted on three levels, the cubic feedback model simulates new records (new phases, levels between the
    trained ones) within 0.1 % NRMSE while the linear model of the same data is off by > 5 %; the fitted cubic
    branch over the input branch is the truth's −K3 (the truth is noise-free and in the model class)."""
    (u_tr, y_tr), (u_te, y_te) = data
    nl = fnl.identify_feedback_nonlinearity(u_tr, y_tr, PERIOD, DT, order=2, features=("lin", "cube"))
    lin = fnl.identify_feedback_nonlinearity(u_tr, y_tr, PERIOD, DT, order=2, features=())
    e_nl = fnl.benchmark_nrmse_percent(y_te, nl.simulate(u_te, warmup=PERIOD), PERIOD)
    e_lin = fnl.benchmark_nrmse_percent(y_te, lin.simulate(u_te, warmup=PERIOD), PERIOD)
    assert e_nl < 0.1, e_nl
    assert e_lin > 5.0, e_lin
    # the cubic branch over the input branch, as coefficient of y³ [1/m³]: the truth injects −K3·y³ where u enters
    ns = 2
    g_u = nl.theta[:ns, 0]
    g_cube = nl.theta[2 * ns:3 * ns, 0] / nl.z_scale[0] ** 3   # groups: input, lin, cube
    ratio = float(np.dot(g_cube, g_u) / np.dot(g_u, g_u))
    assert ratio == pytest.approx(-K3, rel=0.02), ratio


def test_the_small_signal_poles_are_the_truths_linear_mode(data):
    """Linearised at rest, the identified loop has the truth's own mode (800 Hz, ζ 0.03) — not the shifted mode of
    the pooled best linear approximation its banks start from — and is stable."""
    (u_tr, y_tr), _ = data
    nl = fnl.identify_feedback_nonlinearity(u_tr, y_tr, PERIOD, DT, order=2, features=("lin", "cube"))
    z = nl.small_signal_poles()
    s = np.log(z[z.imag > 0]) / DT
    assert len(s) == 1 and np.all(np.abs(z) < 1)
    assert abs(s[0]) / (2 * np.pi) == pytest.approx(F0, rel=1e-3)
    assert -s[0].real / abs(s[0]) == pytest.approx(ZETA, rel=1e-2)
    bla_mode = nl.poles[nl.poles.imag > 0][0]
    assert abs(abs(bla_mode) / (2 * np.pi) - F0) > 2.0     # the banks' pooled mode is elsewhere


@pytest.mark.parametrize("features", [("lin",), ("lin", "abs2")])
def test_without_the_right_nonlinearity_the_fit_stays_off(features, data):
    """The linear loop alone, or with z·|z| instead of z³, leaves > 1 % NRMSE on the same records: the figure above
    comes from the cubic term, not from the loop or from any odd term."""
    (u_tr, y_tr), (u_te, y_te) = data
    model = fnl.identify_feedback_nonlinearity(u_tr, y_tr, PERIOD, DT, order=2, features=features)
    e = fnl.benchmark_nrmse_percent(y_te, model.simulate(u_te, warmup=PERIOD), PERIOD)
    assert e > 1.0, e


def test_actuator_coordinates_keep_an_exact_fit_and_map_back_to_the_outputs(data):
    """Features on the actuator coordinate G(0)⁻¹·y: the in-class truth is still reproduced (the cube of a scaled
    coordinate is the same feature), the model reports outputs (not actuator volts), and its map is the static gain
    (1 for this mode, within the multisine's lowest bins' resonance-free error)."""
    (u_tr, y_tr), (u_te, y_te) = data
    nl = fnl.identify_feedback_nonlinearity(u_tr, y_tr, PERIOD, DT, order=2, features=("lin", "cube"),
                                            coordinates="actuators")
    assert nl.output_map is not None and nl.output_map[0, 0] == pytest.approx(1.0, abs=0.05)
    assert fnl.benchmark_nrmse_percent(y_te, nl.simulate(u_te, warmup=PERIOD), PERIOD) < 0.1
    ee = nl.equation_error_output(u_te[0], y_te[0], warmup=PERIOD)
    assert fnl.benchmark_nrmse_percent([y_te[0]], [ee], PERIOD) < 0.1


def test_simulation_uses_only_the_input():
    """The simulated output of a model is the same whatever output records it is evaluated against, and the same
    for a record alone or in a batch (records are simulated independently)."""
    rng = np.random.default_rng(0)
    us, ys = _records(rng, (0.1, 0.4), 2)
    m = fnl.identify_feedback_nonlinearity(us, ys, PERIOD, DT, order=2, features=("cube",))
    together = m.simulate(us, warmup=PERIOD)
    alone = m.simulate([us[1]], warmup=PERIOD)[0]
    np.testing.assert_allclose(together[1], alone, rtol=1e-12, atol=1e-15)


def test_equation_error_output_is_the_fit_and_matches_the_simulation_of_an_exact_model(data):
    """With the features from the measured output, the exact (in-class, noise-free) model reproduces the record as
    its simulation does; a linear model's equation-error output is its simulation (no features)."""
    (u_tr, y_tr), (u_te, y_te) = data
    nl = fnl.identify_feedback_nonlinearity(u_tr, y_tr, PERIOD, DT, order=2, features=("lin", "cube"))
    ee = nl.equation_error_output(u_te[0], y_te[0], warmup=PERIOD)
    assert fnl.benchmark_nrmse_percent([y_te[0]], [ee], PERIOD) < 0.1
    lin = fnl.identify_feedback_nonlinearity(u_tr, y_tr, PERIOD, DT, order=2, features=())
    np.testing.assert_allclose(lin.equation_error_output(u_te[0], y_te[0] * 0, warmup=PERIOD),
                               lin.simulate([u_te[0]], warmup=PERIOD)[0], rtol=1e-9, atol=1e-12)


def test_benchmark_nrmse_is_error_rms_over_output_std_averaged():
    """Per channel and period: RMS(error)/std(y), then the mean — 10 % for a 10 % gain error on a zero-mean sine,
    and the offset of y does not enter the normaliser."""
    t = np.arange(2 * 100)
    y = np.column_stack([np.sin(2 * np.pi * t / 100) + 5.0, 2 * np.sin(2 * np.pi * t / 50)])
    y_hat = y.copy()
    y_hat[:, 0] = 5.0 + 1.1 * (y[:, 0] - 5.0)
    # channel 0: 10 %, channel 1: 0 % → mean 5 %
    assert fnl.benchmark_nrmse_percent([y], [y_hat], 100) == pytest.approx(5.0, rel=1e-9)


@pytest.mark.parametrize("kwargs, message", [
    ({"features": ("quartic",)}, "feature 'quartic'"),
    ({"period": 1000}, "whole periods"),
    ({"coordinates": "modal"}, "coordinates 'modal'"),
])
def test_bad_input_is_a_one_line_error(kwargs, message):
    rng = np.random.default_rng(1)
    us, ys = _records(rng, (0.1,), 1)
    args = {"period": PERIOD, "features": ("cube",), "coordinates": "outputs", **kwargs}
    with pytest.raises(ValueError, match=message):
        fnl.identify_feedback_nonlinearity(us, ys, args["period"], DT, order=2, features=args["features"],
                                           coordinates=args["coordinates"])
