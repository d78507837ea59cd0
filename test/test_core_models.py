"""Core models and compensators: discretisation, exact inverses, block-size invariance, config validation."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from piezo_ff_ros.core.compensators.cascade import CompensatorCascade
from piezo_ff_ros.core.compensators.creep import CreepCompensator, creep_inverse_poles
from piezo_ff_ros.core.compensators.hysteresis import HysteresisCompensator
from piezo_ff_ros.core.config import ConfigError, PiezoConfig, load_config
from piezo_ff_ros.core.lti import DiscreteModalSS, FactoredTF, LTIFilter, TFMatrix
from piezo_ff_ros.core.models.bouc_wen import BoucWenModel
from piezo_ff_ros.core.models.creep import CreepModel
from piezo_ff_ros.core.models.dynamics import DynamicsModel
from piezo_ff_ros.core.models.plant import Plant

FS = 20000.0


def _random_split(x, rng, n_cuts=40):
    idx = np.sort(rng.choice(np.arange(1, len(x)), size=n_cuts, replace=False))
    return np.split(x, idx)


def _signal(n, seed=0, scale=1.0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    # smooth multi-tone + 1 % white noise: rich, but with the slew a real reference has
    return scale * np.column_stack([np.sin(2 * np.pi * 3 * t) + 0.3 * np.sin(2 * np.pi * 41 * t + 1)
                                    + 0.01 * rng.standard_normal(n),
                                    np.cos(2 * np.pi * 5 * t) + 0.2 * np.sin(2 * np.pi * 97 * t)
                                    + 0.01 * rng.standard_normal(n)])


# ---------------------------------------------------------------------------------------------------- LTI / ZOH
def _scipy_zoh_reference(tf: FactoredTF, u, dt):
    num = np.array([tf.gain])
    for f in tf.num:
        num = np.polymul(num, f)
    den = np.array([1.0])
    for f in tf.den:
        den = np.polymul(den, f)
    A, B, C, D = scipy.signal.tf2ss(num, den)
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((A, B, C, D), dt, method="zoh")
    _, y, _ = scipy.signal.dlsim((Ad, Bd, Cd, Dd, dt), u)
    return y[:, 0]


@pytest.mark.parametrize("tf", [
    FactoredTF(2.0, (), ((1.0, 50.0),)),
    FactoredTF(3.0, ((1.0, 10.0),), ((1.0, 40.0, 1.0e4), (1.0, 300.0))),
    FactoredTF(1.5, ((1.0, 2.0), (1.0, -3.0)), ((1.0, 5.0), (1.0, 20.0, 900.0))),  # proper (D ≠ 0), RHP zero
])
def test_modal_zoh_matches_scipy(tf):
    dt = 1e-3
    u = _signal(2000)[:, :1]
    ss = DiscreteModalSS.zoh_from_tf_matrix(TFMatrix.from_nested([[tf]]), dt)
    y = LTIFilter(ss).process(u)[:, 0]
    ref = _scipy_zoh_reference(tf, u[:, 0], dt)
    assert np.allclose(y, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_zoh_from_ss_matches_tf_route():
    tf = FactoredTF(4.0, ((1.0, 3.0),), ((1.0, 2.0, 50.0), (1.0, 7.0)))
    A, B, C, D = TFMatrix.from_nested([[tf]]).to_control().A, None, None, None
    sysc = TFMatrix.from_nested([[tf]]).to_control()
    a = DiscreteModalSS.zoh_from_ss(sysc.A, sysc.B, sysc.C, sysc.D, 1e-3)
    b = DiscreteModalSS.zoh_from_tf_matrix(TFMatrix.from_nested([[tf]]), 1e-3)
    u = _signal(500)[:, :1]
    assert np.allclose(LTIFilter(a).process(u), LTIFilter(b).process(u), atol=1e-12)


def test_dynamics_strictly_proper_one_sample_delay(paper_config):
    dm = DynamicsModel(paper_config.dynamics, paper_config.dt)
    u = np.zeros((10, 2))
    u[3:, 0] = 1e-6
    y = dm.process(u)
    assert np.all(y[:4] == 0.0)          # output at k depends on inputs up to k − 1
    assert np.all(y[4:, 0] != 0.0)


def test_printed_gl_dc_gain_and_duplicate_factor(paper_config):
    G = paper_config.dynamics.G_L
    assert G[1, 0].duplicated_factors() == [(1.0, 679.5, 9.584e07)]
    G0 = G.dc_gain()
    assert np.linalg.norm(np.linalg.inv(G0), 2) == pytest.approx(0.948, abs=1e-3)
    ss = DiscreteModalSS.zoh_from_tf_matrix(G, 1 / FS)
    assert ss.is_stable()
    assert np.allclose(ss.dc_gain(), G0, rtol=1e-6)


def test_variant_gain_div10():
    cfg = load_config(None, variant="gyx_gain_div10")
    G0 = cfg.dynamics.G_L.dc_gain()
    assert np.linalg.norm(np.linalg.inv(G0), 2) == pytest.approx(0.934, abs=1e-3)
    with pytest.raises(ConfigError, match="variant"):
        load_config(None, variant="nope")


# ---------------------------------------------------------------------------------------------------- hysteresis
def test_bouc_wen_loop_width_matches_independent_reading(paper_config):
    """h/H of the printed model at 200 V, 0.1 Hz (an independent reading got 16.76 % / 17.21 %)."""
    t = np.arange(int(20 * FS)) / FS
    for axis, expected in ((0, 16.76), (1, 17.21)):
        u = np.zeros((len(t), 2))
        u[:, axis] = 200 * np.sin(2 * np.pi * 0.1 * t)
        y = BoucWenModel(paper_config.hysteresis).process(u)[:, axis]
        last = t >= 10.0  # second period: the loop has closed
        ul, yl = u[last, axis], y[last]
        asc = np.gradient(ul) > 0
        grid = np.linspace(-150, 150, 301)
        ya = np.interp(grid, ul[asc][np.argsort(ul[asc])], yl[asc][np.argsort(ul[asc])])
        yd = np.interp(grid, ul[~asc][np.argsort(ul[~asc])], yl[~asc][np.argsort(ul[~asc])])
        ratio = 100 * np.max(np.abs(yd - ya)) / (yl.max() - yl.min())
        assert ratio == pytest.approx(expected, abs=0.3)


@pytest.mark.parametrize("loop", ["exact", "delayed"])
def test_hysteresis_compensator_inverts_model(paper_config, loop):
    yh = _signal(40000, scale=15e-6)
    # exact: identity to rounding; delayed: off by one sample's increment of h, bounded by ~A/(Dp−A)·|ΔY_H|
    tol = 1e-17 if loop == "exact" else 0.6 * np.max(np.abs(np.diff(yh, axis=0)))
    comp = HysteresisCompensator(paper_config.hysteresis, loop=loop)
    u = comp.process(yh)
    y = BoucWenModel(paper_config.hysteresis).process(u)
    assert np.max(np.abs(y - yh)) < tol
    assert comp.fallbacks == 0


def test_hysteresis_compensator_saturates_like_the_amplifier(paper_config):
    comp = HysteresisCompensator(paper_config.hysteresis, voltage_limit=200.0)
    yh = _signal(4000, scale=60e-6)        # asks for ~±350 V
    u = comp.process(yh)
    assert np.max(np.abs(u)) <= 200.0 and comp.saturated > 0
    # the internal state is the plant's: replaying the clamped voltage gives the compensator's own h
    h = BoucWenModel(paper_config.hysteresis).process_with_taps(u)[1]["h"]
    assert np.allclose(h[-1], comp.h, atol=1e-15)


def test_generalized_bouc_wen_is_asymmetric_and_inverted(paper_config):
    from dataclasses import replace

    gen = replace(paper_config.hysteresis, Delta1=((0.002, 0.0), (0.0, 0.002)), Delta2=((0.001, 0.0), (0.0, 0.001)))
    assert gen.generalized
    t = np.arange(int(20 * FS)) / FS
    u = np.column_stack([200 * np.sin(2 * np.pi * 0.1 * t), np.zeros_like(t)])
    y_sym = BoucWenModel(paper_config.hysteresis).process(u)[:, 0]
    y_gen = BoucWenModel(gen).process(u)[:, 0]
    # symmetric model: odd map → y(+200 V) = −y(−200 V); the generalized one is not
    i_max, i_min = np.argmax(u[len(t) // 2:, 0]) + len(t) // 2, np.argmin(u[len(t) // 2:, 0]) + len(t) // 2
    assert abs(y_sym[i_max] + y_sym[i_min]) < 1e-3 * abs(y_sym[i_max])
    assert abs(y_gen[i_max] + y_gen[i_min]) > 1e-2 * abs(y_gen[i_max])
    yh = _signal(20000, scale=15e-6)
    assert np.max(np.abs(BoucWenModel(gen).process(HysteresisCompensator(gen).process(yh)) - yh)) < 1e-17


# ---------------------------------------------------------------------------------------------------- creep
def test_creep_compensator_inverts_model(paper_config):
    yl = _signal(20000, scale=20e-6)
    yh = CreepCompensator(paper_config.creep, paper_config.dt).process(yl)
    y = CreepModel(paper_config.creep, paper_config.dt).process(yh)
    assert np.max(np.abs(y - yl)) < 1e-18


def test_creep_compensator_loop_is_stable_but_barely(paper_config):
    p = creep_inverse_poles(paper_config.creep, paper_config.dt)
    assert np.all(np.abs(p) < 1.0)
    assert np.max(np.abs(p)) > 1.0 - 1e-9   # the barely damped pair (real part ≈ −2e-6 rad/s)


# ---------------------------------------------------------------------------------------------------- streaming
def _stages(cfg):
    return {
        "bouc_wen": (lambda: BoucWenModel(cfg.hysteresis), 100.0),
        "hyst_comp": (lambda: HysteresisCompensator(cfg.hysteresis), 15e-6),
        "hyst_comp_delayed": (lambda: HysteresisCompensator(cfg.hysteresis, "delayed"), 15e-6),
        "creep": (lambda: CreepModel(cfg.creep, cfg.dt), 20e-6),
        "creep_comp": (lambda: CreepCompensator(cfg.creep, cfg.dt), 20e-6),
        "dynamics": (lambda: DynamicsModel(cfg.dynamics, cfg.dt), 20e-6),
        "plant_noisy": (lambda: Plant(cfg, noise_std=1e-7, seed=3), 100.0),
    }


@pytest.mark.parametrize("name", ["bouc_wen", "hyst_comp", "hyst_comp_delayed", "creep", "creep_comp", "dynamics",
                                  "plant_noisy"])
def test_block_size_invariance(paper_config, name):
    make, scale = _stages(paper_config)[name]
    x = _signal(6000, seed=7, scale=scale)
    whole = make().process(x)
    rng = np.random.default_rng(11)
    stage = make()
    parts = np.vstack([stage.process(p) for p in _random_split(x, rng)])
    assert np.array_equal(whole, parts)
    stage.reset()
    assert np.array_equal(stage.process(x), whole)


# ---------------------------------------------------------------------------------------------------- config
@pytest.mark.parametrize("path,value,field", [
    ("hysteresis.Dp", [[1.0, 2.0], [2.0, 4.0]], "hysteresis.Dp"),
    ("hysteresis.A", [[1.0, float("nan")], [0.0, 1.0]], "hysteresis.A"),
    ("hysteresis.B", [[1.0, 2.0, 3.0]], "hysteresis.B"),
    ("creep.K", [[1.0, 1.0], [1.0, 1.0]], "creep.K"),
    ("creep.Cr.xx", {"k": 1.0, "num": [[1.0, 1.0]], "den": [[1.0, -0.5]]}, "creep.Cr.xx"),
    ("creep.Cr.xx", {"k": 1.0, "num": [[1.0, 1.0]], "den": [[1.0, 0.5]]}, "creep.Cr.xx"),  # not strictly proper
    ("dynamics.G_L.yy", {"k": 1.0, "num": [[1.0, 1.0], [1.0, 2.0]], "den": [[1.0, 3.0]]}, "dynamics.G_L.yy"),
    ("vibration.t_r", -1.0, "vibration.t_r"),
    ("vibration.W2", [1.0], "vibration.W2"),
    ("cascade.order", "sideways", "cascade.order"),
    ("limits.voltage", 0.0, "limits.voltage"),
])
def test_bad_config_names_the_field(path, value, field):
    import yaml
    from piezo_ff_ros.core.config import default_config_path

    d = yaml.safe_load(default_config_path().read_text())
    cur = d
    keys = path.split(".")
    for k in keys[:-1]:
        cur = cur[k]
    cur[keys[-1]] = value
    with pytest.raises(ConfigError) as err:
        PiezoConfig.from_dict(d)
    assert str(err.value).startswith(field), str(err.value)


def test_yaml_round_trip(paper_config, tmp_path):
    p = tmp_path / "c.yaml"
    paper_config.to_yaml(p)
    again = load_config(p)
    assert np.allclose(np.array(again.hysteresis.Dp), np.array(paper_config.hysteresis.Dp), rtol=1e-12)
    assert again.dynamics.G_L[0, 0] == paper_config.dynamics.G_L[0, 0]


# ---------------------------------------------------------------------------------------------------- cascade
def _cfg_with(cfg, **cascade):
    from dataclasses import replace

    return replace(cfg, cascade=replace(cfg.cascade, **cascade)).validate()


def test_cascade_without_vibration_inverts_hysteresis_and_creep(paper_config):
    cfg = _cfg_with(paper_config, vibration=False)
    yr = _signal(20000, scale=15e-6)
    u = CompensatorCascade(cfg).process(yr)
    y = Plant(cfg, stages=("hysteresis", "creep")).process(u)
    assert np.max(np.abs(y - yr)) < 1e-17


def test_cascade_taps_and_block_invariance(paper_config):
    static = (np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((2, 0)), np.eye(2))  # C(s) = I
    yr = _signal(6000, scale=15e-6)
    casc = CompensatorCascade(paper_config, controller=static)
    u, taps = casc.process_with_taps(yr)
    assert np.array_equal(taps["yl"], yr) and np.array_equal(taps["u"], u)
    casc.reset()
    parts = np.vstack([casc.process(p) for p in _random_split(yr, np.random.default_rng(5))])
    assert np.array_equal(parts, u)


def test_cascade_stages_can_be_switched_off(paper_config):
    cfg = _cfg_with(paper_config, vibration=False, creep=False, hysteresis=False)
    yr = _signal(1000, scale=15e-6)
    u = CompensatorCascade(cfg).process(yr)
    assert np.allclose(u, yr @ np.linalg.inv(np.array(cfg.hysteresis.Dp)).T, rtol=1e-12)


def test_commuted_cascade_compensates_slow_signals(paper_config):
    cfg = _cfg_with(paper_config, vibration=False, order="commuted")
    t = np.arange(int(20 * FS)) / FS
    yr = 15e-6 * np.column_stack([np.sin(2 * np.pi * 0.1 * t), np.cos(2 * np.pi * 0.1 * t)])
    plant = Plant(cfg, stages=("hysteresis", "creep"))
    y_comp = plant.process(CompensatorCascade(cfg).process(yr))
    plant.reset()
    y_raw = plant.process(yr @ np.linalg.inv(np.array(cfg.hysteresis.Dp)).T)  # linear inverse only
    err_comp, err_raw = np.max(np.abs(y_comp - yr)), np.max(np.abs(y_raw - yr))
    assert err_comp < 0.25 * err_raw


def test_config_check_report(paper_config):
    from piezo_ff_ros.core.checks import config_report

    rep = config_report(paper_config)
    assert rep["dynamics_G_L"]["yx"]["duplicated_factors"] == [[1.0, 679.5, 9.584e07]]
    assert rep["dynamics_G_L"]["yx"]["order_after_cancellation"] == 7
    assert rep["creep"]["compensator_stable"]
    assert rep["dynamics"]["hinf_gamma_lower_bound_dc"] == pytest.approx(0.948, abs=1e-3)


def test_non_square_bouc_wen_with_input_map():
    """k = 4 electrodes (+x, −x, +y, −y) → n = 2 displacements: Û = P·U with an explicit input map."""
    from piezo_ff_ros.core.config import BoucWenConfig

    P = ((0.5, -0.5, 0.0, 0.0), (0.0, 0.0, 0.5, -0.5))          # differential drive of each axis
    Dp = tuple(tuple(0.17e-6 * v for v in row) for row in P)
    A = tuple(tuple(0.06e-6 * v for v in row) for row in P)
    cfg = BoucWenConfig(Dp=Dp, A=A, B=((0.007, 0.0), (0.0, 0.005)), Gamma=((0.0016, 0.0), (0.0, 0.001)),
                        input_map=P).validate()
    assert (cfg.n_out, cfg.n_in) == (2, 4)
    t = np.arange(40000) / FS
    ux = 200 * np.sin(2 * np.pi * 1 * t)
    U = np.column_stack([ux, -ux, np.zeros_like(t), np.zeros_like(t)])
    y = BoucWenModel(cfg).process(U)
    # differential drive of x only: y stays at rest, x shows a loop (ascending ≠ descending at U = 0)
    assert np.max(np.abs(y[:, 1])) == 0.0
    zero_cross = np.where(np.diff(np.sign(ux)) != 0)[0][1:]
    assert np.ptp(y[zero_cross, 0]) > 1e-6
    # the compensator of a non-square system uses Dp⁺ and the delayed loop, and still nearly inverts it
    comp = HysteresisCompensator(cfg)
    assert comp.loop == "delayed"
    yh = 15e-6 * np.column_stack([np.sin(2 * np.pi * 1 * t), np.cos(2 * np.pi * 1 * t)])
    err = BoucWenModel(cfg).process(comp.process(yh)) - yh
    assert np.max(np.abs(err)) < 0.02 * 15e-6


@pytest.mark.parametrize("order", ["paper", "commuted"])
def test_cascade_and_plant_one_sample_blocks(paper_config, order):
    """Blocks of one sample (a 1-row matrix product takes another BLAS path, which rounds differently) give the
    numbers of one whole block, for both cascade orders and the plant."""
    static = (np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((2, 0)), np.eye(2))  # C(s) = I: fast to build
    cfg = _cfg_with(paper_config, order=order)
    yr = _signal(3000, scale=15e-6)
    for make, x in ((lambda: CompensatorCascade(cfg, controller=static), yr), (lambda: Plant(cfg), yr * 1e7)):
        whole = make().process(x)
        st = make()
        assert np.array_equal(np.vstack([st.process(x[i:i + 1]) for i in range(len(x))]), whole)
