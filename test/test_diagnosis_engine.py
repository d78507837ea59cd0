"""Honest verdicts (the z-test on coloured/quantised noise, `none`, `unexplained`), the richer candidates
(several modes per axis, amplitude-dependent dynamics, 2nd-order roll-off per axis), discrimination of near-tied
candidates by a proposed experiment, and a slow-sample-rate record that the pre-fix ZOH turned into a false verdict.

Truths here are built with scipy filters or the nominal plant plus hand-written terms, except where a candidate's
own parameterisation is the point (recovering its parameters).
"""
import json

import numpy as np
import pytest
import scipy.signal

from bench.synthetic.in_family import excitation, make_runs
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose, json_ready
from piezo_ff_ros.core.diagnosis import stats
from piezo_ff_ros.core.models.effects import build_plant
from piezo_ff_ros.core.recording.run import RunData
from piezo_ff_ros.core.trajectories import from_dict

FS = 5000.0
DUR = 10.0


@pytest.fixture(scope="module")
def cfg():
    return load_config().with_sample_rate(FS)


def _ar1(n, rho, std, rng, axes=2):
    """AR(1) noise of the given marginal standard deviation (strongly coloured for rho near 1)."""
    e = rng.standard_normal((n, axes)) * std * np.sqrt(1 - rho ** 2)
    x0 = rng.standard_normal((1, axes)) * std
    return scipy.signal.lfilter([1.0], [1.0, -rho], e, axis=0, zi=rho * x0)[0]


def _quantise(y, q):
    return np.round(y / q) * q


# ----------------------------------------------------------------------------------------------------------------
# The statistical test
# ----------------------------------------------------------------------------------------------------------------

def test_z_test_holds_its_level_on_coloured_quantised_noise_where_a_white_test_fails():
    """H0 true (residual = coloured + quantised noise, correction independent of it): the spectral z-test rejects
    at about its nominal 1 % level; a test assuming white noise of the same variance rejects most of the time."""
    rng = np.random.default_rng(0)
    n = 20000
    t = np.arange(n) / 1000.0
    d = 1e-9 * np.c_[np.sin(2 * np.pi * 0.3 * t), np.cos(2 * np.pi * 0.2 * t)]  # a small slow correction
    zc = stats.z_critical(1, 0.01)
    hits_spectral = hits_white = 0
    trials = 200
    for _ in range(trials):
        r = _quantise(_ar1(n, 0.995, 30e-9, rng), 10e-9)
        r -= r.mean(axis=0)
        r_after = r - d
        r_after -= r_after.mean(axis=0)
        psd = stats.noise_psd(r_after)
        delta, sd, z = stats.improvement_z(r, r_after, psd)
        hits_spectral += z > zc
        sd_white = 2 * np.std(r) * np.sqrt(np.sum((r - r_after) ** 2))
        hits_white += delta / sd_white > zc
    assert hits_spectral / trials <= 0.04
    assert hits_white / trials >= 0.2


def test_z_test_has_power_on_a_real_effect():
    rng = np.random.default_rng(1)
    n = 20000
    t = np.arange(n) / 1000.0
    d = 2e-8 * np.c_[np.sin(2 * np.pi * 7 * t), np.cos(2 * np.pi * 11 * t)]
    noise = _quantise(_ar1(n, 0.9, 30e-9, rng), 10e-9)
    r = noise + d
    psd = stats.noise_psd(noise)
    _, _, z = stats.improvement_z(r - r.mean(0), noise - noise.mean(0), psd)
    assert z > 8


# ----------------------------------------------------------------------------------------------------------------
# Verdicts end to end
# ----------------------------------------------------------------------------------------------------------------

def _runs_from(cfg, truth, seed=0, noise=None, dur=DUR):
    """TRAIN/TEST runs of ``truth(u) -> y`` with the in-family excitations and the given noise function."""
    runs = []
    for j, kind in enumerate(("train", "test")):
        u = excitation(kind, FS, dur, seed=seed + j)
        y = truth(u)
        rng = np.random.default_rng(seed + 10 + j)
        y = y + (noise(len(u), rng) if noise else 50e-9 * rng.standard_normal(y.shape))
        runs.append(RunData(np.arange(len(u)) / FS, u, y, ("x", "y")))
    return runs


def test_null_with_coloured_quantised_noise_is_none(cfg):
    """A perfect model measured through slowly wandering (AR(1), ρ = 0.999) 30 nm noise quantised at 10 nm: the gap
    is many times the white-noise floor yet not reproducible, so the verdict is `none`."""
    nominal = build_plant(cfg, [])

    def truth(u):
        nominal.reset()
        return nominal.process(u)

    train, test = _runs_from(cfg, truth, noise=lambda n, rng: _quantise(_ar1(n, 0.999, 30e-9, rng), 10e-9))
    res = json_ready(diagnose(cfg, train, test))
    assert res["verdict"] == "none", res["confidence_reason"]
    assert res["explainable"] is not None and not res["explainable"]["significant"]
    assert "z" in res["ranking"][0]
    assert res["test"]["z_critical"] > 2


def test_gap_outside_the_library_is_unexplained_with_its_explainable_share(cfg):
    """A resonance near 300 Hz on axis y (scipy band-pass) diagnosed with a library that has no mode candidate: the
    gap is reproducible (the flexible model fitted on TRAIN removes most of it on TEST) and nothing names it."""
    nominal = build_plant(cfg, [])
    b, a = scipy.signal.butter(1, [280.0, 320.0], btype="bandpass", fs=FS)

    def truth(u):
        nominal.reset()
        y = nominal.process(u)
        y[:, 1] += 0.8 * scipy.signal.lfilter(b, a, y[:, 1])
        return y

    train, test = _runs_from(cfg, truth)
    opts = DiagnosisOptions(candidates=("gain_mismatch", "input_delay", "thermal_drift", "amplifier_saturation"),
                            max_stack=1)
    res = json_ready(diagnose(cfg, train, test, opts))
    assert res["verdict"] == "unexplained", (res["verdict"], res["confidence_reason"])
    assert res["explainable"]["significant"] and res["explainable"]["share_percent"] > 50
    assert res["where"]["axis"]["y"]["energy_share"] > 0.8
    assert res["heldout"]["after_nrmse_percent"] == pytest.approx(res["heldout"]["before_nrmse_percent"])
    json.dumps(res)


def test_several_modes_different_per_axis(cfg):
    # the in-family excitations reach 400 Hz: both modes inside the excited band, each on its own axis
    params = {"freq": [140.0, 330.0], "damping": [0.03, 0.02], "gains": [[0.8, 0.0], [0.0, 0.6]]}
    train, test = make_runs(cfg, {"name": "m", "effect": "unmodelled_mode", "params": params, "seed": 2},
                            duration=DUR, noise_std=50e-9)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=("unmodelled_mode", "gain_mismatch", "input_delay"),
                                                      max_stack=1))
    assert res["verdict"] == "unmodelled_mode"
    fitted = np.sort(np.atleast_1d(res["ranking"][0]["params"]["freq"]["value"]))
    assert len(fitted) >= 2
    for f in (140.0, 330.0):
        assert np.min(np.abs(fitted - f)) < 0.03 * f
    h = res["heldout"]
    assert h["after_nrmse_percent"] < 1.3 * h["noise_floor_nrmse_percent"]


def test_amplitude_dependent_dynamics_beats_a_fixed_mode(cfg):
    """A resonance whose strength grows with the level (hand-written: the 300 Hz band-pass of the output scaled
    by its low-passed |y|): the level term generalises to the held-out run, a fixed mode does not."""
    nominal = build_plant(cfg, [])
    bb, ab = scipy.signal.butter(1, [270.0, 330.0], btype="bandpass", fs=FS)
    bl, al = scipy.signal.butter(1, 3.0, fs=FS)

    def truth(u):
        nominal.reset()
        y = nominal.process(u)
        level = scipy.signal.lfilter(bl, al, np.abs(y), axis=0) / 10e-6
        return y + 1.5 * level * scipy.signal.lfilter(bb, ab, y, axis=0)

    train, test = _runs_from(cfg, truth, seed=3)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=("unmodelled_mode", "amplitude_dependent_dynamics",
                                                                  "gain_mismatch"), max_stack=1))
    assert res["verdict"] == "amplitude_dependent_dynamics", res["confidence_reason"]
    ranks = {r["effect"]: r for r in res["ranking"]}
    assert ranks["amplitude_dependent_dynamics"]["heldout_after_nrmse_percent"] < \
        0.8 * ranks["unmodelled_mode"]["heldout_after_nrmse_percent"]


def test_second_order_rolloff_with_a_cutoff_per_axis(cfg):
    params = {"cutoff": [180.0, 320.0], "order": 2}
    train, test = make_runs(cfg, {"name": "bw", "effect": "amplifier_bandwidth", "params": params, "seed": 4},
                            duration=DUR, noise_std=50e-9)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=("amplifier_bandwidth", "input_delay",
                                                                  "gain_mismatch"), max_stack=1))
    assert res["verdict"] == "amplifier_bandwidth"
    p = res["ranking"][0]["params"]
    assert p["order"]["value"] == 2
    assert np.allclose(p["cutoff"]["value"], [180.0, 320.0], rtol=0.1)


# ----------------------------------------------------------------------------------------------------------------
# Discriminate, don't guess
# ----------------------------------------------------------------------------------------------------------------

def test_delay_vs_rolloff_is_named_or_said_ambiguous_and_the_proposed_experiment_decides(cfg, tmp_path):
    """A 400 Hz first-order amplifier roll-off (a continuous filter on the DAC's staircase, simulated at 10× the
    record's rate) seen through slow excitations looks almost like a delay.  The diagnosis must name the roll-off, or
    say it is ambiguous, propose a playable trajectory, and get it right on that experiment."""
    over = 10
    bd, a, _ = scipy.signal.cont2discrete(([1.0], [1 / (2 * np.pi * 400.0), 1.0]), 1 / (over * FS), method="zoh")
    b = np.ravel(bd)
    nominal = build_plant(cfg.with_sample_rate(over * FS), [])

    def truth(u, seed):
        uo = np.repeat(u, over, axis=0)
        uf = scipy.signal.lfilter(b, a, uo, axis=0, zi=scipy.signal.lfilter_zi(b, a)[:, None] * uo[:1])[0]
        nominal.reset()
        y = nominal.process(uf)[::over]
        return y + 50e-9 * np.random.default_rng(seed).standard_normal(y.shape)

    def slow(f, seed):
        t = np.arange(int(10 * FS)) / FS
        u = np.c_[120 * np.sin(2 * np.pi * f * t) + 20 * np.sin(2 * np.pi * 3.1 * f * t + seed),
                  100 * np.sin(2 * np.pi * 1.3 * f * t + 1)]
        return RunData(t, u, truth(u, seed), ("x", "y"))

    train, test = slow(2.0, 1), slow(3.0, 2)
    opts = DiagnosisOptions(candidates=("input_delay", "amplifier_bandwidth", "gain_mismatch"), max_stack=1)
    res = diagnose(cfg, train, test, opts)
    d = res["discrimination"]
    if d is None:
        assert res["verdict"] == "amplifier_bandwidth", res["confidence_reason"]
        return
    assert set(d["ambiguous_between"]) == {"input_delay", "amplifier_bandwidth"}
    assert res["confidence"] == "low"
    exp = d["experiment"]
    assert exp["expected_z"] > 5 and exp["duration_s"] <= 600
    traj = from_dict(exp["trajectory"])  # what the trajectory node plays (trajectory_file)
    _, u = traj.sample(FS)
    assert np.max(np.abs(u)) <= np.max(np.abs(test.u)) + 1e-9
    run_c = RunData(np.arange(len(u)) / FS, u, truth(u, 7), ("x", "y"))
    res2 = diagnose(cfg, train, test, opts, discriminate=run_c)
    assert res2["verdict"] == "amplifier_bandwidth"
    assert res2["discrimination"]["decided_on_run"]["winner"] == "amplifier_bandwidth"
    assert res2["discrimination"]["decided_on_run"]["paired_z"] > 5


# ----------------------------------------------------------------------------------------------------------------
# Pinned: a slow, long record of a perfect model (the pre-fix ZOH gave it a `gain_mismatch` verdict)
# ----------------------------------------------------------------------------------------------------------------

def _reference_plant(cfg, u):
    """The nominal plant with every transfer function discretised by scipy's cont2discrete (test_zoh_reference),
    the hysteresis by the package's Bouc-Wen (no ZOH involved there)."""
    from test_zoh_reference import _reference_response

    _, taps = build_plant(cfg, []).process_with_taps(u)
    yh = taps["yh"]
    dt = cfg.dt
    K = np.asarray(cfg.creep.K, float)
    n = cfg.n_axes

    def tfm_apply(tfm, x):
        out = np.zeros_like(x)
        for i in range(n):
            for j in range(n):
                tf = tfm[i, j]
                if not tf.is_zero():
                    out[:, i] += _reference_response(tf.cancelled(), x[:, j], dt)
        return out

    yl = yh @ K.T + tfm_apply(cfg.creep.Cr, yh)
    return tfm_apply(cfg.dynamics.G_L, yl)


def test_slow_sample_rate_perfect_model_record_is_none():
    fs = 250.0
    cfg = load_config().with_sample_rate(fs)
    runs = []
    for j, kind in enumerate(("train", "test")):
        u = excitation(kind, fs, 120.0, seed=20 + j)
        y = _reference_plant(cfg, u) + 30e-9 * np.random.default_rng(30 + j).standard_normal(u.shape)
        runs.append(RunData(np.arange(len(u)) / fs, u, y, ("x", "y")))
    res = diagnose(cfg, runs[0], runs[1])
    assert res["verdict"] == "none", (res["verdict"], res["confidence_reason"])
    assert res["heldout"]["before_nrmse_percent"] < 1.2 * res["heldout"]["noise_floor_nrmse_percent"]


def test_cli_writes_the_proposed_trajectory_for_the_trajectory_node(cfg, tmp_path):
    """The proposal file is a trajectory spec the trajectory node's loader reads (YAML → from_dict), in volts."""
    import argparse

    import yaml

    from piezo_ff_ros.cli.diagnose import _write_proposal
    from piezo_ff_ros.core.diagnosis.discriminate import designs

    spec, why = designs(cfg, 100.0)["steps"]
    res = {"discrimination": {"ambiguous_between": ["input_delay", "amplifier_bandwidth"],
                              "experiment": {"design": "steps", "purpose": why, "duration_s": 5.6,
                                             "expected_rms_difference_um": 0.5, "expected_z": 12.0,
                                             "between": ["input_delay", "amplifier_bandwidth"], "trajectory": spec}}}
    args = argparse.Namespace(proposal=None, report=str(tmp_path / "rep"), json=None)
    line = _write_proposal(res, args)
    path = tmp_path / "rep" / "discriminate_trajectory.yaml"
    assert str(path) in line and "input_delay vs amplifier_bandwidth" in line
    traj = from_dict(yaml.safe_load(path.read_text()))
    _, u = traj.sample(FS)
    assert u.shape[1] == 2 and np.max(np.abs(u)) == pytest.approx(90.0)
    assert "bypass:=true" in res["discrimination"]["experiment"]["command"]
    assert res["discrimination"]["experiment"]["file"] == str(path)


def test_dac_latency_is_named_a_delay_not_absorbed_by_the_generic_mode_family(tmp_path):
    """The benchmark's tuning case delay/dac_latency@11 (a DAC updating 1.02 samples late, exact modified ZOH, from
    the independent truth simulator; 10 kHz, coloured noise): the interpolated `input_delay` takes all but ~0 % of
    the gap above the noise floor, two free modes fit its approximation error slightly better.  The generic family
    must not take the verdict (it absorbs the delay; GENERIC_MIN_EXTRA), and must not be reported as a rival."""
    from bench.diagnosis import cases as C
    from bench.diagnosis import run as R

    case = next(c for c in C.make_cases([11]) if c.template == "delay/dac_latency")
    (tr, te), _ = R.records(case)
    c = load_config().with_sample_rate(case.fs)
    train, test = (RunData(t, u, y, ("x", "y")) for t, u, y in (tr, te))
    # every check below reads the first round (verdict, discrimination, ranking), which the greedy stacking after it
    # does not change: no stacking round (max_stack=1) spares its refits of every candidate
    res = json_ready(diagnose(c, train, test, DiagnosisOptions(max_stack=1)))
    assert res["verdict"] == "input_delay", (res["verdict"], res["confidence_reason"])
    assert res["discrimination"] is None
    delay = next(r for r in res["ranking"] if r["effect"] == "input_delay")
    assert delay["params"]["delay"]["value"] == pytest.approx(1.017 / case.fs, rel=0.1)
    generic = [r for r in res["ranking"] if r["effect"] in ("unmodelled_mode", "amplitude_dependent_dynamics")]
    # the invariant behind the rules: whenever a generic candidate was demoted it was accepted and took < 5 pp more,
    # or, with more parameters, it did not beat the physical candidate significantly on the held-out run
    for r in generic:
        if r["absorbs"] is not None:
            assert r["accepted"] and (r["excess_shrink_percent"] - delay["excess_shrink_percent"] < 5.0
                                      or r["n_params"] > delay["n_params"])
