"""The measured outputs as nonlinear channels of a model on actuator coordinates, in one equation-error fit
(core/identification/feedback_nonlinearity.py ``identify_feedback_nonlinearity(..., channels='outputs')``)."""
import numpy as np
import pytest
import scipy.signal

from piezo_ff_ros.core.identification import feedback_nonlinearity as fnl

PERIOD = 512
DT = 1e-4
FEATURES = ("lin", "cube")
#: a coupled 2×2 plant (inputs mix into both outputs), so the actuator coordinates differ from the outputs
MIX = np.array([[1.0, 0.4], [0.3, 1.0]])


def _records(rng, n):
    """Two periods of random-phase multisines on both inputs through two lightly damped modes and ``MIX``, with a
    cubic term on the first output (a stiffness nonlinearity)."""
    b, a = scipy.signal.cheby1(2, 1.0, 0.2)
    us, ys = [], []
    for _ in range(n):
        spec = np.zeros((PERIOD // 2 + 1, 2), complex)
        spec[1:150] = np.exp(2j * np.pi * rng.random((149, 2)))
        u = np.tile(np.fft.irfft(spec, PERIOD, axis=0) * 20, (2, 1))
        x = scipy.signal.lfilter(b, a, np.concatenate([u[:PERIOD], u]), axis=0)[PERIOD:]
        y = x @ MIX.T
        y[:, 0] += 0.05 * y[:, 0] ** 3
        us.append(u)
        ys.append(y)
    return us, ys


@pytest.fixture(scope="module")
def records():
    return _records(np.random.default_rng(3), 4)


def test_the_outputs_as_channels_are_the_fit_with_the_static_gain_rows_given_explicitly(records):
    elementwise = fnl.identify_feedback_nonlinearity(*records, PERIOD, DT, 6, FEATURES, coordinates="actuators")
    assert elementwise.output_map is not None
    explicit = fnl.identify_feedback_nonlinearity(*records, PERIOD, DT, 6, FEATURES, coordinates="actuators",
                                                  channels=elementwise.output_map)
    named = fnl.identify_feedback_nonlinearity(*records, PERIOD, DT, 6, FEATURES, coordinates="actuators",
                                               channels="outputs")
    assert named.n_channels == 4
    np.testing.assert_array_equal(named.channel_map, explicit.channel_map)
    np.testing.assert_array_equal(named.theta, explicit.theta)
    # the channels after the coordinates are the measured outputs (unit RMS): y' mapped by the static gain
    u, y = records
    zs = (np.vstack(y) - np.vstack(y).mean(0)) @ np.linalg.inv(named.output_map).T / named.z_scale
    ch = zs @ named.channel_map[2:].T
    out = np.vstack(y) - np.vstack(y).mean(0)
    for i in range(2):
        assert abs(np.corrcoef(ch[:, i], out[:, i])[0, 1]) > 1 - 1e-9


@pytest.mark.parametrize("coordinates, channels", [("outputs", "outputs"), ("actuators", "differences")])
def test_a_named_channel_set_that_does_not_apply_is_refused_in_one_line(records, coordinates, channels):
    with pytest.raises(ValueError, match="channels=") as err:
        fnl.identify_feedback_nonlinearity(*records, PERIOD, DT, 6, FEATURES, coordinates=coordinates,
                                           channels=channels)
    assert "\n" not in str(err.value)
