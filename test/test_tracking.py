"""Tracking beyond the paper: preview inversion, constrained QP, iterative learning, `piezo-ff track`."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import scipy.signal

from piezo_ff_ros.core.config import ConfigError
from piezo_ff_ros.core.tracking.ilc import (ILCConfig, IterativeLearning, LearnedCorrection, convergence_factor,
                                            load_correction, save_correction)
from piezo_ff_ros.core.tracking.linear import CompensatedModel, controller_matrices
from piezo_ff_ros.core.tracking.preview import PreviewConfig, PreviewStage
from piezo_ff_ros.core.tracking.qp import QPSolver
from piezo_ff_ros.core.trajectories import Circle


@pytest.fixture(scope="module")
def setup(paper_config):
    from piezo_ff_ros.core.compensators.cascade import CompensatorCascade

    cfg = paper_config
    casc = CompensatorCascade(cfg)
    ctrl = controller_matrices(casc)
    model = CompensatedModel.from_config(cfg, ctrl, n=4096)
    return cfg, casc, ctrl, model


def _splits(n, rng):
    cuts = np.sort(rng.choice(np.arange(1, n), size=12, replace=False))
    return np.split(np.arange(n), cuts)


def _ahead(r, L):
    return np.vstack([r[L:], np.repeat(r[-1:], L, axis=0)])


# -- config --------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad,field", [({"horizon_s": 0}, "horizon_s"), ({"bandwidth_hz": float("nan")}, "bandwidth_hz"),
                                       ({"filter_order": 2.5}, "filter_order"), ({"constrained": "yes"}, "constrained"),
                                       ({"qp_step_s": 0.5}, "qp_step_s"), ({"horizon": 1}, "horizon")])
def test_preview_config_refuses_bad_values_naming_the_field(bad, field):
    with pytest.raises(ConfigError, match=rf"^preview\.{field}"):
        PreviewConfig.from_dict(bad)


@pytest.mark.parametrize("bad,field", [({"gain": -1}, "gain"), ({"q_order": 0}, "q_order"), ({"iterations": 1.5}, "iterations"),
                                       ({"q_bw": 3}, "q_bw")])
def test_ilc_config_refuses_bad_values_naming_the_field(bad, field):
    with pytest.raises(ConfigError, match=rf"^learning\.{field}"):
        ILCConfig.from_dict(bad)


# -- the compensated model and its inversion, against references we did not write ---------------------------------

def test_compensated_model_matches_python_control(setup):
    """T = G_L·C from our streaming stages vs python-control's ZOH discretisation of the same continuous parts."""
    import control

    cfg, _, ctrl, model = setup
    G = control.c2d(cfg.dynamics.G_L.to_control(), cfg.dt, "zoh")
    C = control.c2d(control.ss(*ctrl), cfg.dt, "zoh")
    f = np.array([1.0, 10.0, 50.0, 200.0, 1000.0])
    w = 2 * np.pi * f
    ref = np.einsum("ijf,jkf->fik", G(np.exp(1j * w * cfg.dt)), C(np.exp(1j * w * cfg.dt)))
    Tf = np.einsum("kij,fk->fij", model.T, np.exp(-1j * np.outer(w, np.arange(len(model.T))) * cfg.dt))
    assert np.max(np.abs(Tf - ref)) < 1e-6 * np.max(np.abs(ref))


def test_inversion_matches_a_direct_least_squares_solve(setup):
    """The streaming FIR inverse vs scipy's solve of min ‖T·y − r‖² (+ a 1e-12 ridge) on a short windowed case."""
    cfg, _, ctrl, model = setup
    fs, N = cfg.sample_rate, 1000
    t = np.arange(N) / fs
    ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(150) / 150)
    w = np.concatenate([np.zeros(450), ramp, np.ones(200), ramp[::-1], np.zeros(50)])
    r = w[:, None] * np.column_stack([1e-6 * np.sin(2 * np.pi * 20 * t) + 0.5e-6 * np.sin(2 * np.pi * 70 * t + 1),
                                      1e-6 * np.cos(2 * np.pi * 35 * t)])
    Tl = model.lifted("T", N)
    lam = 1e-12 * np.trace(Tl.T @ Tl) / len(Tl)
    y_ls = scipy.linalg.solve(Tl.T @ Tl + lam * np.eye(2 * N), Tl.T @ r.ravel(), assume_a="pos").reshape(N, 2)
    st = PreviewStage(cfg, ctrl, PreviewConfig(), model=model)
    y_fir = st.process(_ahead(r, st.preview_samples))
    sl = slice(450, 950)
    out_fir = (Tl @ y_fir.ravel()).reshape(N, 2)[sl]
    out_ls = (Tl @ y_ls.ravel()).reshape(N, 2)[sl]
    assert np.abs(out_ls - r[sl]).max() < 1e-9 * 1e-6          # the reference solve is exact
    assert np.abs(out_fir - out_ls).max() < 5e-3 * 1e-6        # ours within 0.5 % of a 1 µm signal
    # the shaped references agree too, in the band the low-pass F keeps (above it T ≈ 0 leaves y free)
    sos = scipy.signal.butter(4, 300, fs=fs, output="sos")
    a, b = (scipy.signal.sosfiltfilt(sos, y, axis=0)[sl] for y in (y_fir, y_ls))
    assert np.abs(a - b).max() < 2e-3 * np.abs(b).max()


def test_preview_is_bit_identical_whatever_the_block_split(setup):
    cfg, _, ctrl, model = setup
    st = PreviewStage(cfg, ctrl, PreviewConfig(), model=model)
    r = Circle(radius=20e-6, frequency=10, revolutions=1).sample(cfg.sample_rate)[1]
    whole = st.process(r)
    for seed in range(3):
        st.reset()
        parts = [st.process(r[idx]) for idx in _splits(len(r), np.random.default_rng(seed))]
        np.testing.assert_array_equal(np.vstack(parts), whole)


def test_constrained_preview_is_split_invariant_and_respects_the_limit(setup):
    cfg, _, ctrl, model = setup
    lim = dataclasses.replace(cfg.limits, voltage=120.0)
    c = dataclasses.replace(cfg, limits=lim)
    st = PreviewStage(c, ctrl, PreviewConfig(constrained=True, qp_horizon_s=0.01, qp_step_s=0.005, qp_knot_s=0.001),
                      model=model)
    r = Circle(radius=20e-6, frequency=10, revolutions=1).sample(cfg.sample_rate)[1][:1200]
    ahead = _ahead(r, st.preview_samples)
    whole = st.process(ahead)
    assert st.qp_solves > 0
    st.reset()
    parts = [st.process(ahead[idx]) for idx in _splits(len(r), np.random.default_rng(1))]
    np.testing.assert_array_equal(np.vstack(parts), whole)
    # what the shaped reference asks of the (limitless) cascade stays near the limit, not the 150 V it would ask
    from piezo_ff_ros.core.tracking.linear import CascadeReplica

    u, _ = CascadeReplica(c, ctrl).process(whole)
    free = PreviewStage(c, ctrl, PreviewConfig(), model=model)
    u_free, _ = CascadeReplica(c, ctrl).process(free.process(_ahead(r, free.preview_samples)))
    assert np.abs(u_free[300:]).max() > 135.0
    assert np.abs(u[300:]).max() < c.limits.voltage


@pytest.mark.parametrize("f,limit", [(1.0, 0.05), (10.0, 0.2)])
def test_preview_meets_the_circle_targets_model_equals_plant(setup, f, limit):
    from piezo_ff_ros.core.models.plant import Plant

    cfg, casc, ctrl, model = setup
    st = PreviewStage(cfg, ctrl, PreviewConfig(), model=model)
    r = Circle(radius=20e-6, frequency=f, revolutions=2).sample(cfg.sample_rate)[1]
    casc.reset()
    u = casc.process(st.process(_ahead(r, st.preview_samples)))
    y = Plant(cfg).process(u)
    last = slice(len(r) - int(cfg.sample_rate / f), len(r))
    e = np.linalg.norm(y[last] - r[last], axis=1)
    assert np.sqrt(np.mean(e ** 2)) < limit * 1e-6
    assert np.abs(u).max() <= cfg.limits.voltage


# -- QP against scipy ------------------------------------------------------------------------------------------------

def test_qp_matches_scipy_lsq_linear_and_slsqp():
    rng = np.random.default_rng(1)
    M, b = rng.standard_normal((40, 12)), rng.standard_normal(40)
    P, q = M.T @ M, -M.T @ b
    ref = scipy.optimize.lsq_linear(M, b, bounds=(-0.2, 0.3), tol=1e-12).x
    res = QPSolver(P, np.eye(12), eps_abs=1e-10, eps_rel=1e-10, max_iter=50000).solve(q, -0.2 * np.ones(12), 0.3 * np.ones(12))
    assert res.converged and np.abs(res.x - ref).max() < 1e-7
    G = rng.standard_normal((20, 12))
    ref2 = scipy.optimize.minimize(lambda x: 0.5 * x @ P @ x + q @ x, np.zeros(12), jac=lambda x: P @ x + q,
                                   constraints=[scipy.optimize.LinearConstraint(G, -0.5, 0.5)], method="SLSQP",
                                   options={"ftol": 1e-14, "maxiter": 1000}).x
    res2 = QPSolver(P, G, eps_abs=1e-10, eps_rel=1e-10, max_iter=50000).solve(q, -0.5 * np.ones(20), 0.5 * np.ones(20))
    assert res2.converged and np.abs(res2.x - ref2).max() < 1e-6
    with pytest.raises(ValueError, match="lower bound exceeds"):
        QPSolver(P, G).solve(q, np.ones(20), -np.ones(20))


# -- learning ----------------------------------------------------------------------------------------------------------

def test_learning_converges_on_a_mismatched_truth_and_beats_the_cascade_5x(setup):
    from piezo_ff_ros.core.reproduce import truth_plant
    from piezo_ff_ros.core.tracking.benchmark import Case, reference_with_lead_in

    cfg, casc, ctrl, model = setup
    st = PreviewStage(cfg, ctrl, PreviewConfig(), model=model)
    fs = cfg.sample_rate
    r = reference_with_lead_in(Case("circle", 20, 10, Circle(radius=20e-6, frequency=10, revolutions=3)), fs)[0]
    yr = st.process(_ahead(r, st.preview_samples))
    seeds = iter(range(1, 100))

    def trial(delta, noise=100e-9):
        casc.reset()
        return truth_plant(cfg, "asymmetric", noise, next(seeds)).process(casc.process(yr + delta))

    res = IterativeLearning(model, ILCConfig(iterations=4)).learn(trial, r)
    h = res.rms_history_m
    assert h[-1] < 0.3 * h[0]                                       # whole trial, noise included
    casc.reset()
    y_cascade = truth_plant(cfg, "asymmetric").process(casc.process(r))
    y_learned = trial(res.correction, noise=0.0)                   # played without the sensor
    last = slice(len(r) - int(fs / 10), len(r))
    rms = lambda y: np.sqrt(np.mean(np.sum((y[last] - r[last]) ** 2, axis=1)))  # noqa: E731
    assert rms(y_learned) * 5 < rms(y_cascade)
    assert rms(y_learned) < 0.05e-6


def test_learning_condition_and_the_guard_when_it_is_violated(setup, paper_config):
    """An unmodelled 1 ms delay violates |1 − γT̂⁻¹T| < 1 above ≈ 167 Hz; a wide Q lets it diverge, the guard stops it."""
    from piezo_ff_ros.core.tracking.benchmark import Case, TrackingModel, evaluation_window, reference_with_lead_in, violation_demo

    cfg = paper_config
    m = TrackingModel.build(cfg, PreviewConfig())
    case = Case("circle", 20, 10, Circle(radius=20e-6, frequency=10, revolutions=2))
    r, n_lead = reference_with_lead_in(case, cfg.sample_rate)
    out = violation_demo(m, cfg, ILCConfig(), r, evaluation_window(case, r, n_lead, cfg.sample_rate), quick=True)
    runs = out["runs"]
    assert runs["wide_q_no_guard"]["condition"]["rho"] > 1 > runs["default_q"]["condition"]["rho"]
    assert 150 < runs["default_q"]["condition"]["f_violation_hz"] < 190
    diverging = runs["wide_q_no_guard"]["rms_history_um"]
    guarded = runs["wide_q_guard"]["rms_history_um"]
    assert diverging[-1] > 2 * diverging[0]                         # the violation is real
    assert max(guarded[1:]) < diverging[0] and runs["wide_q_guard"]["guard_events"] >= 1
    assert runs["default_q"]["rms_history_um"][-1] < 0.3 * runs["default_q"]["rms_history_um"][0]
    f, T = m.compensated.frequency_response()
    assert convergence_factor(T, T, f, ILCConfig(gain=1.0))["rho"] < 1e-12


def test_learned_correction_store_replay_and_refusals(tmp_path):
    corr = np.random.default_rng(0).normal(0, 1e-7, (500, 2))
    spec = {"type": "circle", "radius": 2e-5}
    p = save_correction(tmp_path / "c", corr, 20000.0, spec, {"truth": "asymmetric"})
    got, info = load_correction(p, 20000.0, spec)
    np.testing.assert_array_equal(got, corr)
    stage = LearnedCorrection(got)
    x = np.ones((700, 2))
    whole = stage.process(x)
    stage.reset()
    parts = np.vstack([stage.process(x[i]) for i in np.split(np.arange(700), [3, 250, 251, 600])])
    np.testing.assert_array_equal(parts, whole)
    np.testing.assert_array_equal(whole[600], 1 + corr[-1])          # held after the end
    with pytest.raises(ConfigError, match="learned at 20000 Hz, played at 10000 Hz"):
        load_correction(p, 10000.0)
    with pytest.raises(ConfigError, match="another trajectory"):
        load_correction(p, 20000.0, {"type": "raster"})
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ConfigError, match=r"^learning\.file"):
        load_correction(tmp_path / "junk.npz")


def test_front_rebuilt_for_a_new_cascade_keeps_the_correction_index(tmp_path, paper_config):
    """A cascade swap rebuilds the front (the preview inverts the running cascade); the learned correction belongs
    to the trajectory's sample index and must go on from where it was, not restart at 0."""
    from piezo_ff_ros.core.tracking.front import TrackingFront

    corr = np.random.default_rng(1).normal(0, 1e-7, (900, 2))
    p = save_correction(tmp_path / "c", corr, paper_config.sample_rate, {"type": "circle"})
    values = {"learning.file": str(p)}
    x = np.zeros((300, 2))
    whole = TrackingFront(paper_config, None, values)
    ref = np.vstack([whole.process(x), whole.process(x), whole.process(x)])
    a = TrackingFront(paper_config, None, values)
    first = a.process(x)
    b = TrackingFront(paper_config, None, values)
    b.continue_from(a)
    got = np.vstack([first, b.process(x), b.process(x)])
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(got, corr[:900])


def test_table_states_the_voltage_limit_found():
    """Cases whose exact shaped reference asks more than the amplifier are named with the voltage asked, the limit,
    the clipped peak and the resulting error floor; the slew used is compared with its limit."""
    from piezo_ff_ros.cli.track import physical_limit_lines

    def row(size, f, asked, peak, rms, slew):
        return {"trajectory": "circle", "size_um": size, "frequency_hz": f, "method": "preview", "truth": "nominal",
                "asked_peak_voltage_v": asked, "peak_voltage_v": peak, "rms_error_um": rms,
                "peak_slew_v_per_s": slew}

    res = {"conditions": {"voltage_limit_v": 200.0, "slew_limit_v_per_s": 1e7},
           "cases": [row(20, 1, 155.2, 155.2, 0.0002, 2e3), row(30, 1, 218.4, 200.0, 1.25, 5e4)]}
    text = "\n".join(physical_limit_lines(res))
    assert "±200 V" in text and "circle 30 µm 1 Hz 218 V" in text and "1.25 µm RMS floor" in text
    assert "circle 20 µm 1 Hz" in text and "155 V asked" in text
    assert "50 V/ms used" in text and "0.5 % of it" in text
    res["cases"] = res["cases"][:1]
    assert "never binds" in physical_limit_lines(res)[0]


# -- the command -------------------------------------------------------------------------------------------------------

def test_track_cli_quick_json_contract(tmp_path, capsys):
    from piezo_ff_ros.cli import main

    out = tmp_path / "track.json"
    assert main(["track", "--quick", "--truths", "nominal,asymmetric", "--iterations", "2", "--json", str(out),
                 "--quiet"]) == 0
    res = json.loads(out.read_text())
    keys = {"trajectory", "size_um", "frequency_hz", "method", "truth", "rms_error_um", "max_error_um",
            "peak_voltage_v"}
    assert res["cases"] and all(keys <= set(c) for c in res["cases"])
    assert {c["method"] for c in res["cases"]} == {"open", "cascade", "preview", "learning"}
    assert {c["trajectory"] for c in res["cases"]} == {"circle", "raster", "spiral"}
    assert {c["truth"] for c in res["cases"]} == {"nominal", "asymmetric"}
    t = res["targets"]
    assert t["circle_20um_1hz_preview_rms_um"]["pass"] and t["circle_20um_10hz_preview_rms_um"]["pass"]
    assert t["raster_20um_10hz_preview_max_percent_of_range"]["pass"]
    assert "RMS µm" in capsys.readouterr().out


@pytest.mark.parametrize("argv,msg", [(["--json", "."], "is a directory"), (["--truths", "martian"], "unknown truth"),
                                      (["--iterations", "-1"], "--iterations"),
                                      (["--graph-iterations", "0"], "--graph-iterations")])
def test_track_cli_bad_options_give_one_line_errors(argv, msg, capsys):
    from piezo_ff_ros.cli import main

    assert main(["track", "--quick", *argv]) == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
