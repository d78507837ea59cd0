"""A channels-from-the-start fit that diverges in simulation on its own training records is refined the stable way:
from the refined elementwise model widened by the channels (core/identification/output_error.py
``refine_with_channels``), not from its linear part."""
from dataclasses import replace

import numpy as np
import pytest

from piezo_ff_ros.core.identification import feedback_nonlinearity as fnl
from piezo_ff_ros.core.identification import output_error as oe

from test_output_error_channels import DT, FEATURES, PERIOD, SPRING, _records


@pytest.fixture(scope="module")
def fits():
    """Training and validation records of the 2×2 truth with a cubic spring between its outputs; the equation-error
    fits with and without a channel along the spring; a copy of the channel fit with its feature coefficients grown
    until it diverges on the training records (as the FSM's fit on 200 + 300 mV does, pole 1.12 at rest)."""
    rng = np.random.default_rng(23)
    train = _records(rng, (0.45, 0.7), 2)
    val = _records(rng, (0.3, 0.6), 1)
    chan = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES, channels=[SPRING])
    elem = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES)
    ns = oe._n_states(chan.poles)
    theta = np.array(chan.theta)
    theta[chan.n_inputs * ns:] *= 40.0
    bad = replace(chan, theta=theta)
    return train, val, chan, elem, bad


def test_a_diverging_channel_fit_is_refined_from_the_widened_elementwise_model(fits):
    """The diverging start takes the widened route: the elementwise fit refined, widened by the spring's channel and
    refined again; the result simulates the training records finitely, is stable at rest, has the added channel,
    and its validation loss is no larger than the refined elementwise model's (its start) and lower than that of
    the same budget spent from the diverging fit's linear part (the old route)."""
    train, val, _, elem, bad = fits
    assert not np.isfinite(oe.simulation_loss(bad, *train, PERIOD))
    res = oe.refine_with_channels(bad, elem, [SPRING], *train, warmup=PERIOD, max_iterations=15,
                                  elementwise_iterations=15, validation=val, every=5)
    assert res.route == "widened"
    assert res.elementwise is not None
    assert res.model.n_channels == 3
    assert np.max(np.abs(res.model.small_signal_poles())) < 1.0
    loss_val = oe.simulation_loss(res.model, *val, PERIOD)
    assert np.isfinite(oe.simulation_loss(res.model, *train, PERIOD))
    assert loss_val <= oe.simulation_loss(res.elementwise.model, *val, PERIOD) * (1 + 1e-12)
    old = oe.refine_output_error(oe.linear_part(bad), *train, warmup=PERIOD, max_iterations=15, validation=val,
                                 every=5, refine_channels=True).model
    assert loss_val < oe.simulation_loss(old, *val, PERIOD)


def test_a_channel_fit_that_simulates_is_refined_from_itself(fits):
    """A start that simulates finitely on its training records is refined directly (the channels-from-the-start
    route): no elementwise refinement, and the kept iterate is no worse on the validation records than the start."""
    train, val, chan, elem, _ = fits
    assert np.isfinite(oe.simulation_loss(chan, *train, PERIOD))
    res = oe.refine_with_channels(chan, elem, [SPRING], *train, warmup=PERIOD, max_iterations=5, validation=val,
                                  every=5)
    assert res.route == "from_start" and res.elementwise is None
    assert res.model.n_channels == chan.n_channels
    assert oe.simulation_loss(res.model, *val, PERIOD) <= oe.simulation_loss(chan, *val, PERIOD) * (1 + 1e-6)


def test_outputs_and_their_differences_as_channels_are_those_directions_fitted_explicitly(fits):
    """``channels='outputs+differences'`` on actuator coordinates is the fit with the measured outputs and their
    pairwise differences given as explicit directions (the same model to rounding)."""
    train = fits[0]
    named = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES, coordinates="actuators",
                                               channels="outputs+differences")
    M = np.asarray(named.output_map, float)
    explicit = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES,
                                                  coordinates="actuators", channels=np.vstack([M, [M[0] - M[1]]]))
    assert named.n_channels == 2 + 3
    np.testing.assert_allclose(named.channel_map, explicit.channel_map, rtol=1e-12)
    np.testing.assert_allclose(named.theta, explicit.theta, rtol=1e-8, atol=1e-12 * np.abs(explicit.theta).max())
