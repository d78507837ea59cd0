"""Prandtl–Ishlinskii hysteresis by least squares (core/identification/prandtl_ishlinskii.py)."""
import numpy as np
import pytest

from piezo_ff_ros.core.identification.prandtl_ishlinskii import identify_prandtl_ishlinskii, play_operators


def test_play_operator_holds_inside_its_radius_and_follows_outside():
    """A play of radius 1 started at 0: follows a rise to 3 one unit behind, holds while the input comes back by
    less than 2, then follows the fall one unit above."""
    u = np.array([0.0, 1.0, 2.0, 3.0, 2.5, 1.5, 1.0, 0.0])
    p = play_operators(u, np.array([1.0]))[:, 0]
    np.testing.assert_allclose(p, [0.0, 0.0, 1.0, 2.0, 2.0, 2.0, 2.0, 1.0])


def _drive(n, f, fs, amp, decay=0.0):
    t = np.arange(n) / fs
    return 1.8 + amp * np.exp(-decay * t) * np.sin(2 * np.pi * f * t)


def test_known_play_weights_and_delay_are_recovered_and_predict_another_drive():
    """A truth made of 6 plays (radii on the fit's own grid), a cubic term and a one-sample delay, driven by a
    1 Hz sine: the fit returns its weights, and predicts a decaying 0.7 Hz drive (inner loops) within 1e-12 m."""
    fs = 200.0
    u = _drive(4000, 1.0, fs, 1.8)
    radii = np.arange(6) * np.ptp(u) / 12
    w_true = np.array([2.0, 0.8, 0.5, 0.3, 0.2, 0.1]) * 1e-6
    def truth(v):
        y = play_operators(v, radii) @ w_true + 0.4e-6 * v ** 3 - 5e-6
        return np.concatenate([[y[0]], y[:-1]])
    m = identify_prandtl_ishlinskii(u, truth(u), n_plays=6, poly_degree=3, delay=1, skip=0)
    np.testing.assert_allclose(m.weights, w_true, rtol=1e-6)
    np.testing.assert_allclose(m.poly, [0.0, 0.4e-6], atol=1e-12)
    v = _drive(3000, 0.7, fs, 1.7, decay=0.2)
    np.testing.assert_allclose(m.simulate(v), truth(v), atol=1e-12)


def test_without_plays_the_loop_is_not_reproduced():
    """The same truth fitted with the drive only (one 'play' of radius 0, no hysteresis) leaves an error larger
    than 5 % of the stroke: the plays are what carries the loop."""
    fs = 200.0
    u = _drive(4000, 1.0, fs, 1.8)
    radii = np.arange(6) * np.ptp(u) / 12
    y = play_operators(u, radii) @ (np.array([2.0, 0.8, 0.5, 0.3, 0.2, 0.1]) * 1e-6)
    m = identify_prandtl_ishlinskii(u, y, n_plays=1, poly_degree=3)
    assert np.sqrt(np.mean((m.simulate(u) - y) ** 2)) > 0.05 * np.ptp(y) / 2


def test_bad_input_is_a_one_line_error():
    with pytest.raises(ValueError, match="differ in length"):
        identify_prandtl_ishlinskii(np.zeros(100), np.zeros(99))
    with pytest.raises(ValueError, match="too few"):
        identify_prandtl_ishlinskii(np.zeros(50), np.zeros(50), n_plays=10)
