"""Unmodelled-effect stages: block invariance and the behaviour each one is meant to have."""
import numpy as np
import pytest

from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.models import effects as fx
from piezo_ff_ros.core.models.bouc_wen import BoucWenModel
from piezo_ff_ros.core.models.plant import Plant

FS = 5000.0
DT = 1.0 / FS


@pytest.fixture(scope="module")
def cfg():
    return load_config().with_sample_rate(FS)


def _signal(n=4000, seed=0):
    t = np.arange(n) * DT
    rng = np.random.default_rng(seed)
    u = np.c_[120 * np.sin(2 * np.pi * 3 * t) + 5 * rng.standard_normal(n),
              80 * np.sign(np.sin(2 * np.pi * 2 * t + 0.3))]
    return u


def _all_stages(cfg):
    n = 2
    return [
        fx.InputDelay(3.4 * DT, DT, n), fx.InputDelay(0.0, DT, n), fx.AmplifierSlewLimit(2e4, DT, n),
        fx.AmplifierSaturation(90.0, n), fx.AmplifierBandwidth(300.0, DT, n), fx.GainMismatch([1.05, 0.97], n),
        fx.ThermalDrift([1e-6, -2e-6], 0.3, DT, n), fx.CreepNonlinearity([0.01, 0.02], 0.5, DT, n),
        fx.UnmodelledMode(400.0, 0.02, [0.1, 0.2], DT, n),
        fx.HysteresisStage(fx.asymmetric_hysteresis_config(cfg.hysteresis, [0.003, 0.002], [0.001, 0.0]), 0.4, DT),
        # richer forms: 2nd-order roll-off per axis, several cross-coupled modes, amplitude-dependent dynamics, cross-talk
        fx.AmplifierBandwidth([300.0, 700.0], DT, n, order=2, damping=0.6),
        fx.UnmodelledMode([150.0, 900.0], [0.02, 0.05], [[[0.2, 0.1], [0.0, 0.3]], [[0.1, 0.0], [0.05, 0.2]]], DT, n),
        fx.AmplitudeDependentDynamics([400.0], [0.03], [[0.1, 0.2]], [[0.5, -0.3]], DT, n),
        fx.GainMismatch([1.02, 0.98], n, [[0.0, 0.01], [-0.02, 0.0]]),
        fx.BranchEvenTerm([0.01, -0.02], [0.02, 0.01], DT, n),
        # the richer candidates' stages: each must stream like the others
        fx.RelaxedHysteresisStage(fx.asymmetric_hysteresis_config(cfg.hysteresis, [0.003, 0.002], [0.001, 0.0]),
                                  0.4, DT, relaxation=2e-3),
        fx.AsymmetricSaturation(90.0, 60.0, n),
        fx.PlayWidthTerm([2e-7, 6e-7], [[0.1, -0.05], [0.02, 0.08]], n),
        fx.CubicAmplitudeDynamics([400.0], [0.03], [[0.1, 0.2]], [[0.5, -0.3]], DT, n,
                                  cubic_gains=[[0.2, -0.1]]),
    ]


VOLTAGE_STAGES = (0, 1, 2, 3, 4, 9, 10, 15, 16)


@pytest.mark.parametrize("index", range(19))
def test_block_split_invariance(cfg, index):
    st = _all_stages(cfg)[index]
    u = _signal()
    x = u if index in VOLTAGE_STAGES else u * 1e-7  # voltage stages get volts, displacement stages metres
    whole = st.process(x)
    st.reset()
    parts, i = [], 0
    for size in (1, 7, 0, 333, 1000, 2659):
        parts.append(st.process(x[i:i + size]))
        i += size
    assert i == len(x)
    assert np.array_equal(np.concatenate(parts), whole)


def test_delay_shifts_by_whole_and_fractional_samples():
    u = np.c_[np.arange(20.0), -np.arange(20.0)]
    y = fx.InputDelay(3 * DT, DT, 2).process(u)
    assert np.array_equal(y[3:], u[:-3]) and np.all(y[:3] == u[0])
    y = fx.InputDelay(2.5 * DT, DT, 2).process(u)
    assert np.allclose(y[5:, 0], np.arange(20.0)[5:] - 2.5)


def test_slew_limit_ramps_a_step():
    u = np.zeros((50, 2))
    u[10:] = 10.0
    y = fx.AmplifierSlewLimit(1e4, DT, 2).process(u)  # 2 V per sample
    assert np.allclose(y[10:15, 0], [2, 4, 6, 8, 10]) and np.all(y[15:] == 10.0)


def test_saturation_and_bandwidth():
    u = np.c_[np.linspace(-200, 200, 101), np.zeros(101)]
    assert np.max(np.abs(fx.AmplifierSaturation(150.0).process(u))) == 150.0
    t = np.arange(20000) * DT
    f0 = 100.0
    s = np.c_[np.sin(2 * np.pi * f0 * t), np.zeros_like(t)]
    y = fx.AmplifierBandwidth(f0, DT, 2).process(s)[10000:, 0]
    # first-order low-pass at its corner: |H| = 1/√2 (interval-averaged discretisation: within 3 %)
    assert abs(np.std(y) * np.sqrt(2) / np.sqrt(0.5) - 1) < 0.03


def test_mode_peak_gain_and_no_static_effect():
    st = fx.UnmodelledMode(200.0, 0.05, [0.3, 0.0], DT, 2)
    step = np.ones((20000, 2)) * 1e-5
    assert np.allclose(st.process(step)[-1], 1e-5, rtol=1e-6)
    t = np.arange(40000) * DT
    s = np.sin(2 * np.pi * 200 * t)[:, None] * np.ones(2) * 1e-6
    st.reset()
    y = st.process(s)[20000:]
    assert np.std(y[:, 0]) / np.std(s[20000:, 0]) == pytest.approx(1.3, rel=0.02)
    assert np.allclose(y[:, 1], s[20000:, 1])


def test_creep_nonlinearity_is_log_time_and_level_dependent():
    n = int(300 * 50)
    dt = 0.02
    step = np.full((n, 2), 10e-6)
    out = fx.CreepNonlinearity([0.01, 0.01], 1.0, dt, 2).process(step)
    extra = out[:, 0] - 10e-6
    t = (np.arange(n) + 1) * dt
    per_decade = [np.interp(v, t, extra) for v in (0.3, 3.0, 30.0)]
    d1, d2 = per_decade[1] - per_decade[0], per_decade[2] - per_decade[1]
    assert d1 == pytest.approx(d2, rel=0.3)  # roughly equal creep per decade
    assert d1 > 0
    small = fx.CreepNonlinearity([0.01, 0.01], 1.0, dt, 2).process(step * 0.1)[:, 0] - 1e-6
    assert (small[-1] / 1e-6) < 0.8 * (extra[-1] / 10e-6)  # relative creep grows with the level


def test_thermal_drift_shape():
    st = fx.ThermalDrift([1e-6, 0.0], 1.0, DT, 2)
    y = st.process(np.zeros((int(5 * FS), 2)))
    assert y[0, 0] == 0.0 and y[int(FS) - 1, 0] == pytest.approx(1e-6 * (1 - np.exp(-1)), rel=1e-3)


def test_hysteresis_stage_matches_nominal_and_changes_with_terms(cfg):
    u = _signal(3000)
    ref = BoucWenModel(cfg.hysteresis).process(u)
    assert np.allclose(fx.HysteresisStage(cfg.hysteresis, 0.0, DT).process(u), ref, rtol=0, atol=1e-15)
    asym = fx.HysteresisStage(fx.asymmetric_hysteresis_config(cfg.hysteresis, [0.004, 0.004], 0.0), 0.0, DT)
    assert np.max(np.abs(asym.process(u) - ref)) > 1e-8
    # rate dependence: the loop (h) is wider at a faster rate
    t = np.arange(40000) * DT
    widths = []
    for f in (1.0, 20.0):
        uu = np.c_[100 * np.sin(2 * np.pi * f * t), np.zeros_like(t)]
        y = fx.HysteresisStage(cfg.hysteresis, 1.0, DT).process(uu)[:, 0]
        lin = BoucWenModel(cfg.hysteresis).process(uu)[:, 0]
        widths.append(np.max(np.abs(y - lin)))
    assert widths[1] > 2 * widths[0]


def test_build_plant_equals_nominal_without_effects_and_rejects_unknown(cfg):
    u = _signal(2000)
    ref = Plant(cfg).process(u)
    assert np.array_equal(fx.build_plant(cfg, []).process(u), ref)
    y = fx.build_plant(cfg, [("hysteresis_rate_dependence", {"alpha": 0.0})]).process(u)
    assert np.allclose(y, ref, atol=1e-14)
    y = fx.build_plant(cfg, [("gain_mismatch", {"gains": [1.1, 1.0]})]).process(u)
    assert np.allclose(y[:, 0], 1.1 * ref[:, 0])
    with pytest.raises(ValueError, match="unknown effect"):
        fx.build_plant(cfg, [("friction", {})])
    with pytest.raises(ValueError, match="amplifier_slew_limit.rate"):
        fx.AmplifierSlewLimit(-1.0, DT)


@pytest.mark.parametrize("order,damping", [(1, 0.7), (2, 0.5), (2, 0.7071), (2, 1.5), (3, 0.5)])
def test_rolloff_is_the_continuous_filter_on_the_staircase_averaged_over_each_sample(order, damping):
    """The roll-off equals the continuous low-pass (scipy's lsim, from rest at the first voltage) driven by the
    voltage held over each sample, its output averaged over each sample interval (on a 64× finer grid:
    trapezoids); it tends to the identity as the cutoff goes far above the sample rate."""
    import scipy.signal

    fc = 250.0
    w = 2 * np.pi * fc
    sec1 = ([w], [1.0, w])
    sec2 = ([w * w], [1.0, 2 * damping * w, w * w])
    num, den = {1: sec1, 2: sec2, 3: (np.polymul(sec1[0], sec2[0]), np.polymul(sec1[1], sec2[1]))}[order]
    u = _signal(1200)
    F = 64
    tf = np.arange(len(u) * F) * DT / F
    sys = scipy.signal.lti(num, den).to_ss()
    x0 = -np.linalg.solve(sys.A, sys.B[:, 0])
    ours = fx.AmplifierBandwidth(fc, DT, 2, order=order, damping=damping).process(u)
    for j in range(2):
        uf = np.repeat(u[:, j], F)
        _, yf, _ = scipy.signal.lsim(sys, uf, tf, X0=x0 * u[0, j], interp=False)
        # the mean over each interval: trapezoids on the fine grid (the next interval's first point closes it)
        yc = np.append(yf, yf[-1])
        ref = ((yc[:-1] + yc[1:]) / 2).reshape(-1, F).mean(axis=1)
        assert np.allclose(ours[:, j], ref, rtol=0, atol=2e-3 * np.max(np.abs(u)))
    fc_fast = 1e4 / DT
    fast = fx.AmplifierBandwidth(fc_fast, DT, 2, order=order, damping=damping).process(u)
    step = np.max(np.abs(np.diff(u, axis=0)))
    assert np.allclose(fast, u, atol=3 * step / (2 * np.pi * fc_fast * DT))


def test_several_modes_and_cross_coupling_add_up():
    y = _signal(6000) * 1e-7
    G1 = [[0.2, 0.1], [0.0, 0.3]]
    G2 = [[0.1, 0.0], [0.05, 0.2]]
    both = fx.UnmodelledMode([150.0, 900.0], [0.02, 0.05], [G1, G2], DT, 2).process(y)
    one = fx.UnmodelledMode(150.0, 0.02, [G1], DT, 2).process(y)
    two = fx.UnmodelledMode(900.0, 0.05, [G2], DT, 2).process(y)
    assert np.allclose(both - y, (one - y) + (two - y), atol=1e-20)
    # the x→y coupling of mode 2: output y moves when only x moves
    yx = np.c_[y[:, 0], np.zeros(len(y))]
    out = fx.UnmodelledMode(900.0, 0.05, [G2], DT, 2).process(yx)
    bp_x = fx.UnmodelledMode(900.0, 0.05, [1.0, 1.0], DT, 2).bandpass(yx)[:, 0]
    assert np.max(np.abs(out[:, 1])) > 0 and np.allclose(out[:, 1], 0.05 * bp_x, rtol=0, atol=1e-22)
    with pytest.raises(ValueError, match="unmodelled_mode.gains"):
        fx.UnmodelledMode([100.0, 200.0], 0.05, [0.1, 0.2, 0.3], DT, 2)


def test_amplitude_dependent_dynamics_grows_with_level():
    st = fx.AmplitudeDependentDynamics([300.0], [0.05], [[0.0, 0.0]], [[1.0, 1.0]], DT, 2)
    t = np.arange(20000) * DT
    s = np.sin(2 * np.pi * 300 * t)[:, None] * np.ones(2)
    extra = []
    for a in (1e-6, 4e-6):
        st.reset()
        extra.append(np.std((st.process(a * s) - a * s)[10000:, 0]) / a)
    assert extra[1] == pytest.approx(4 * extra[0], rel=0.05)  # the relative extra response ∝ level


@pytest.mark.parametrize("index", range(19))
def test_one_sample_blocks_give_the_whole_blocks_numbers(cfg, index):
    """A block of one sample takes other numpy/BLAS paths than a long one (a 1-row matrix product rounds
    differently): the output must still be the same numbers."""
    st = _all_stages(cfg)[index]
    u = _signal(n=3000)
    x = u if index in VOLTAGE_STAGES else u * 1e-7
    whole = st.process(x)
    st.reset()
    assert np.array_equal(np.concatenate([st.process(x[i:i + 1]) for i in range(len(x))]), whole)
