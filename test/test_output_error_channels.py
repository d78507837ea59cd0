"""Several nonlinear channels in the feedback model: features on directions through all outputs
(core/identification/feedback_nonlinearity.py ``channel_map``, ``add_channels``; output_error.py ``refine_channels``)."""
import numpy as np
import pytest
import scipy.signal

from piezo_ff_ros.core.identification import feedback_nonlinearity as fnl
from piezo_ff_ros.core.identification import output_error as oe

PERIOD = 1024
DT = 1e-4
#: the truth: two lightly damped modes (400 and 700 Hz, ζ = 0.03) driven by two inputs, seen by two outputs, with a
#: hardening cubic spring acting on the DIFFERENCE of the two outputs (a coupling element between them)
FREQS, ZETA, K3 = (400.0, 700.0), 0.03, 0.01
B_IN = np.array([[1.0, 0.3], [0.2, 1.0]])          # inputs → modal forces
C_OUT = np.array([[1.0, 0.4], [0.3, 1.0]])         # modal displacements → outputs
SPRING = np.array([1.0, -1.0])                     # the spring's elongation y1 − y2
FEATURES = ("lin", "abs2", "cube")


def _truth(u: np.ndarray) -> np.ndarray:
    """``y [T, 2]`` of the truth for ``u [T, 2]``: each mode the exact ZOH of ω²/(s² + 2ζωs + ω²); the spring's
    force ``K3·d³`` (``d = y1 − y2``) acts back on the modes through ``C_OUTᵀ·SPRING`` (strictly proper)."""
    mats = []
    for f in FREQS:
        w = 2 * np.pi * f
        A, B, _, _, _ = scipy.signal.cont2discrete((np.array([[0.0, 1.0], [-w * w, -2 * ZETA * w]]),
                                                    np.array([[0.0], [w * w]]), np.eye(2), np.zeros((2, 1))), DT,
                                                   method="zoh")
        mats.append((A, B[:, 0]))
    back = C_OUT.T @ SPRING
    x = [np.zeros(2), np.zeros(2)]
    y = np.empty((len(u), 2))
    for k in range(len(u)):
        y[k] = C_OUT @ np.array([x[0][0], x[1][0]])
        force = B_IN @ u[k] - K3 * float(SPRING @ y[k]) ** 3 * back
        x = [A @ xi + b * force[i] for i, (xi, (A, b)) in enumerate(zip(x, mats))]
    return y


def _records(rng, levels, per_level):
    """Two periods of random-phase multisines (bins 1 … 300, both inputs) per record, from the periodic steady
    state."""
    us, ys = [], []
    for a in levels:
        for _ in range(per_level):
            cols = []
            for _ in range(2):
                spec = np.zeros(PERIOD // 2 + 1, complex)
                spec[1:301] = np.exp(2j * np.pi * rng.random(300))
                s = np.fft.irfft(spec, PERIOD)
                cols.append(np.tile(s / np.std(s) * a, 2))
            u = np.column_stack(cols)
            us.append(u)
            ys.append(_truth(np.concatenate([u[:PERIOD], u]))[PERIOD:])
    return us, ys


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(11)
    train = _records(rng, (0.2, 0.45, 0.7), 2)
    val = _records(rng, (0.35, 0.6), 1)
    test = _records(rng, (0.3, 0.65), 2)         # new phases, levels between the trained ones
    return train, val, test


def _nrmse(model, recs):
    u, y = recs
    return fnl.benchmark_nrmse_percent(y, model.simulate(u, warmup=PERIOD), PERIOD)


def test_a_spring_between_two_outputs_is_recovered_by_a_channel_along_their_difference(data):
    """The elementwise model (features of each output alone), refined on the simulation error with its iteration
    chosen on validation records, stays > 5 % off on new records: y1³ and y2³ cannot make (y1 − y2)³. The same
    model class with one more channel along y1 − y2 simulates them within 0.05 %."""
    train, val, test = data
    elem = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES)
    if not np.isfinite(oe.simulation_loss(elem, *train, PERIOD)):
        elem = oe.linear_part(elem)
    elem = oe.refine_output_error(elem, *train, warmup=PERIOD, max_iterations=60, validation=val).model
    chan = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES, channels=[SPRING])
    assert chan.n_channels == 3 and elem.n_channels == 2
    e_elem, e_chan = _nrmse(elem, test), _nrmse(chan, test)
    assert e_elem > 5.0, e_elem
    assert e_chan < 0.05, e_chan


def test_a_widened_model_is_the_same_model_and_its_refinement_cannot_do_worse_on_validation(data):
    """``add_channels`` gives the same simulation to the last bit (zero coefficients on the new channels); refined
    with the channels' directions learnt, the kept iterate's validation loss is no larger than the start's, its
    training loss lower, and the refinement moves the new channels' coefficients off zero."""
    train, val, _ = data
    start = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES, channels=[[1.0, -0.7]])
    narrow = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES)
    if not np.isfinite(oe.simulation_loss(narrow, *train, PERIOD)):
        narrow = oe.linear_part(narrow)
    wide = fnl.add_channels(narrow, [[1.0, -0.7]], train[1])
    u = train[0][:2]
    for a, b in zip(narrow.simulate(u, warmup=PERIOD), wide.simulate(u, warmup=PERIOD)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(wide.channel_map[2], start.channel_map[2], rtol=1e-12)
    res = oe.refine_output_error(wide, *train, warmup=PERIOD, max_iterations=20, validation=val, every=5,
                                 refine_channels=True)
    h = res.history
    kept = [r for r in h if r["iteration"] == res.iteration][0]
    assert kept["validation"] <= h[0]["validation"]
    assert h[-1]["loss"] < h[0]["loss"]
    ns = oe._n_states(wide.poles)
    m, nq = wide.n_inputs, wide.n_channels
    new_rows = np.concatenate([np.arange((m + f * nq + 2) * ns, (m + f * nq + 3) * ns) for f in range(len(FEATURES))])
    last = oe.refine_output_error(wide, *train, warmup=PERIOD, max_iterations=5, every=5, refine_channels=True)
    assert np.any(last.model.theta[new_rows] != 0)


def test_the_adjoint_gradient_in_the_channel_directions_is_the_finite_difference_one(data):
    """With three channels (one a learnt direction) and every feature kind, the reverse-sweep gradient equals
    central finite differences on every channel-direction entry and on output coefficients of every channel."""
    train, _, _ = data
    u, y = train[0][:2], train[1][:2]
    m = fnl.identify_feedback_nonlinearity(u, y, PERIOD, DT, order=4, features=fnl.FEATURES, channels=[[1.0, -0.7]])
    theta = m.theta * 0.5                   # a start that does not diverge on these two records
    prob = oe._Problem(m, u, y, PERIOD)
    loss, grad = prob.evaluate(theta)
    assert np.isfinite(loss)
    P = m.channel_matrix()
    off = theta.size + len(oe._pole_vector(m.poles))
    for i in range(P.size):
        h = 1e-6
        a, b = P.ravel().copy(), P.ravel().copy()
        a[i] += h
        b[i] -= h
        fd = (prob.evaluate(theta, False, None, a.reshape(P.shape))[0]
              - prob.evaluate(theta, False, None, b.reshape(P.shape))[0]) / (2 * h)
        assert grad[off + i] == pytest.approx(fd, rel=1e-4, abs=1e-9 * abs(loss)), i
    ns = oe._n_states(m.poles)
    rows = [(m.n_inputs + f * m.n_channels + c) * ns for f in range(len(m.features)) for c in range(m.n_channels)]
    for i in rows:
        h = 1e-6 * max(1.0, abs(theta[i, 0]))
        tp, tm = theta.copy(), theta.copy()
        tp[i, 0] += h
        tm[i, 0] -= h
        fd = (prob.evaluate(tp, False)[0] - prob.evaluate(tm, False)[0]) / (2 * h)
        assert grad[i * theta.shape[1]] == pytest.approx(fd, rel=1e-4, abs=1e-9 * abs(loss)), i


def test_a_channel_direction_of_the_wrong_width_is_refused_in_one_line(data):
    """A direction that does not have one entry per output is a clear error."""
    train, _, _ = data
    with pytest.raises(ValueError, match="channels must be"):
        fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES, channels=[[1.0, 0, 0]])
    m = fnl.identify_feedback_nonlinearity(*train, PERIOD, DT, order=4, features=FEATURES)
    with pytest.raises(ValueError, match="directions must be"):
        fnl.add_channels(m, [[1.0]], train[1])
