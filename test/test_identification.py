"""Identification: recovery of the paper's parameters from simulated characterisation runs, held-out fits, the
``piezo-ff identify`` CLI on CSV files, and clear errors for bad input.

Each stage is tested on a sim plant holding only that stage (rate-independent Bouc-Wen at a low sample rate, creep
at 100 Hz, G_L at 20 kHz over 0.4 s) so the whole file stays well under a minute.
"""
import dataclasses

import numpy as np
import pytest

from piezo_ff_ros.core.characterisation import (CharacterisationSettings, creep_trajectories,
                                                dynamics_trajectories, hysteresis_trajectories, run_open_loop)
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.identification.bouc_wen import identify_bouc_wen
from piezo_ff_ros.core.identification.creep import identify_creep, step_events
from piezo_ff_ros.core.identification.dynamics import identify_dynamics
from piezo_ff_ros.core.models.plant import Plant

AXES = ("x", "y")


def _hyst_runs(cfg, fs, noise, seed=0):
    plant = Plant(cfg.with_sample_rate(fs), stages=("hysteresis",), noise_std=noise, seed=seed)
    ht = hysteresis_trajectories(CharacterisationSettings(sine_frequency=0.5), AXES)
    fit = [run_open_loop(plant, tr, fs, n, AXES) for n, tr in ht["fit"]]
    val = [run_open_loop(plant, tr, fs, n, AXES) for n, tr in ht["validation"]]
    return fit, val


def _split_runs(plant, trajs, fs):
    fit, val = [], []
    for name, tr, t_down in trajs:
        r = run_open_loop(plant, tr, fs, name, AXES)
        k = int(round(t_down * fs))
        fit.append(r.slice(0, k))
        r.meta["score_start"] = k
        val.append(r)
    return fit, val


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def test_bouc_wen_recovers_paper_parameters(cfg):
    fit, val = _hyst_runs(cfg, 400.0, 0.0)
    res = identify_bouc_wen(fit, val)
    assert np.all(res.fit_validation >= 99.0), res.fit_validation
    got, true = res.config.arrays(), cfg.hysteresis.arrays()
    for key in ("Dp", "A", "B"):
        np.testing.assert_allclose(np.diag(got[key]), np.diag(true[key]), rtol=0.02, err_msg=key)
    # the model it returns is the one the compensator inverts: held-out output reproduced
    yh = res.simulate(val[0].u)
    assert np.max(np.abs(yh - val[0].y)) < 0.01 * np.ptp(val[0].y)


def test_bouc_wen_with_100nm_noise(cfg):
    fit, val = _hyst_runs(cfg, 400.0, 100e-9, seed=3)
    res = identify_bouc_wen(fit, val)
    assert np.all(res.fit_validation >= 95.0), res.fit_validation
    np.testing.assert_allclose(np.diag(res.config.arrays()["Dp"]), np.diag(cfg.hysteresis.arrays()["Dp"]),
                               rtol=0.03)


def test_bouc_wen_rejects_flat_input(cfg):
    fit, _ = _hyst_runs(cfg, 100.0, 0.0)
    flat = dataclasses.replace(fit[0], u=np.zeros_like(fit[0].u))
    with pytest.raises(ValueError, match="never moves"):
        identify_bouc_wen([flat])


def test_creep_recovers_K_and_drift(cfg):
    fs = 100.0
    plant = Plant(cfg.with_sample_rate(fs), stages=("creep",))
    s = CharacterisationSettings(creep_duration=60.0, step_ramp=0.02)
    fit, val = _split_runs(plant, creep_trajectories(s, AXES), fs)
    res = identify_creep(fit, val)
    np.testing.assert_allclose(np.array(res.config.K), np.array(cfg.creep.K), atol=3e-3)
    for key in ("xx", "yy", "yx"):
        assert res.fit_validation[key] >= 99.0, res.fit_validation
    assert res.fit_validation["xy"] >= 90.0, res.fit_validation   # barely damped 77-min pole pair in 60 s
    assert 1 <= min(res.orders.values()) and max(res.orders.values()) <= 3


def test_creep_needs_a_step_on_each_axis(cfg):
    fs = 100.0
    plant = Plant(cfg.with_sample_rate(fs), stages=("creep",))
    s = CharacterisationSettings(creep_duration=5.0, step_ramp=0.02)
    fit, _ = _split_runs(plant, creep_trajectories(s, AXES)[:1], fs)
    with pytest.raises(ValueError, match="every input"):
        identify_creep(fit)


def test_step_events_merge_a_ramped_edge():
    u = np.zeros((1000, 2))
    u[100:140, 0] = np.linspace(0.5, 20, 40)
    u[140:, 0] = 20
    assert step_events(u) == [100]


def test_dynamics_recovers_G_L(cfg):
    """Noise-free steps: held-out fit ≥ 99 %, and the exported (factored) G_L has the plant's DC gains."""
    fs = cfg.sample_rate
    plant = Plant(cfg, stages=("dynamics",))
    fit, val = _split_runs(plant, dynamics_trajectories(CharacterisationSettings(), AXES), fs)
    res = identify_dynamics(fit, val, order=8)
    for key in ("xx", "yy", "yx"):
        assert res.fit_validation[key] >= 99.0, res.fit_validation
    np.testing.assert_allclose(res.config.G_L.dc_gain(), cfg.dynamics.G_L.dc_gain(), rtol=0.02, atol=2e-3)


def test_dynamics_with_100nm_noise_reproduces_the_plant(cfg):
    """100 nm white noise at 20 kHz on 20 µm steps: the identified G_L (as exported in the config and simulated by
    the core) reproduces the noise-free plant on the held-out steps with fit ≥ 95 %; against the noisy record it
    reaches the noise floor (the fit the true model itself gets there, ~92–94 %)."""
    from piezo_ff_ros.core.identification.goodness_of_fit import fit_percent
    from piezo_ff_ros.core.models.dynamics import DynamicsModel

    fs = cfg.sample_rate
    plant = Plant(cfg, stages=("dynamics",), noise_std=100e-9, seed=1)
    fit, val = _split_runs(plant, dynamics_trajectories(CharacterisationSettings(), AXES), fs)
    res = identify_dynamics(fit, val, order=8)
    clean = Plant(cfg, stages=("dynamics",))
    model = DynamicsModel(res.config, 1.0 / fs)
    for j, r in enumerate(val):
        k = r.meta["score_start"]
        clean.reset()
        model.reset()
        y_true = clean.process(r.u)
        y_model = model.process(r.u)
        f = fit_percent(y_true[k:] - y_true[k - 1], y_model[k:] - y_model[k - 1])
        assert f[j] >= 95.0, (j, f)
        floor = fit_percent(r.y[k:] - r.y[k - 20:k].mean(0), y_true[k:] - y_true[k - 20:k].mean(0))[j]
        assert res.fit_validation[AXES[j] * 2] >= floor - 1.0, (res.fit_validation, floor)


def _write_csv(path, run, with_reference):
    cols = [run.t[:, None], run.u, run.y] + ([run.reference] if with_reference else [])
    header = "t,u_x,u_y,x,y" + (",r_x,r_y" if with_reference else "")
    np.savetxt(path, np.hstack(cols), delimiter=",", header=header, comments="", fmt="%.10g")
    return path


def test_identify_cli_on_csv_writes_a_loadable_compensating_config(cfg, tmp_path, capsys):
    """A 'lab' at 20 kHz: hysteresis-only sines and creep-only / dynamics-only steps written as CSV files."""
    from piezo_ff_ros.cli import main
    from piezo_ff_ros.core.compensators.cascade import CompensatorCascade

    files, stages = [], []
    fs_h = 400.0
    fit, val = _hyst_runs(cfg, fs_h, 0.0)
    for i, r in enumerate(fit + val):
        files.append(_write_csv(tmp_path / f"s0_{i}.csv", r, False))
        stages.append("hysteresis" + (":validation" if i >= len(fit) else ""))
    fs_c = 100.0
    cplant = Plant(cfg.with_sample_rate(fs_c), stages=("creep",))
    cfit, cval = _split_runs(cplant, creep_trajectories(CharacterisationSettings(creep_duration=30.0,
                                                                                 step_ramp=0.02), AXES), fs_c)
    for i, r in enumerate(cfit):
        files.append(_write_csv(tmp_path / f"sh_{i}.csv", r, True))
        stages.append("creep")
    dplant = Plant(cfg, stages=("dynamics",))
    dfit, _ = _split_runs(dplant, dynamics_trajectories(CharacterisationSettings(), AXES), cfg.sample_rate)
    for i, r in enumerate(dfit):
        files.append(_write_csv(tmp_path / f"sl_{i}.csv", r, True))
        stages.append("dynamics")
    out = tmp_path / "identified.yaml"
    rc = main(["identify", "--data", *map(str, files), "--stage", *stages, "--out", str(out), "--no-hinf",
               "--creep-order", "2", "--dynamics-order", "8", "--quiet"])
    assert rc == 0
    assert "held-out fit" in capsys.readouterr().out
    ident = load_config(out)
    assert ident.sample_rate == pytest.approx(fs_h)     # the hysteresis runs' rate
    np.testing.assert_allclose(np.diag(np.array(ident.creep.K)), np.diag(np.array(cfg.creep.K)), atol=5e-3)
    # its hysteresis compensator linearises the true hysteresis: a 20 µm sine tracked to < 0.5 % of its range
    hcfg = dataclasses.replace(ident, cascade=dataclasses.replace(ident.cascade, creep=False, vibration=False))
    casc = CompensatorCascade(hcfg)
    plant = Plant(cfg.with_sample_rate(fs_h), stages=("hysteresis",))
    t = np.arange(int(2 / 0.5 * fs_h)) / fs_h
    ref = np.column_stack([20e-6 * np.sin(2 * np.pi * 0.5 * t), 10e-6 * np.sin(2 * np.pi * 0.5 * t + 1)])
    y = plant.process(casc.process(ref))
    err = np.max(np.abs(y - ref), axis=0)
    # uncompensated (U = Dp⁻¹·Y_R) for comparison: the identified cascade must do far better
    plant.reset()
    y0 = plant.process(ref @ np.linalg.inv(cfg.hysteresis.arrays()["Dp"]).T)
    err0 = np.max(np.abs(y0 - ref), axis=0)
    assert np.all(err < 0.005 * 40e-6), err
    assert np.all(err < 0.1 * err0), (err, err0)


def test_identify_cli_errors(cfg, tmp_path, capsys):
    """Bad files and options: exit code 2 and a message saying what and where, no traceback, no output file."""
    from piezo_ff_ros.cli import main

    out = str(tmp_path / "o.yaml")

    def fails(argv, expect):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert expect in err and "Traceback" not in err, err

    bad = tmp_path / "hyst_bad.csv"
    t = np.arange(100) / 1000.0
    data = np.column_stack([t, np.sin(t) * 100, np.cos(t) * 100, 1e-5 * np.sin(t), 1e-5 * np.cos(t)])
    data[42, 3] = np.nan
    np.savetxt(bad, data, delimiter=",", header="t,u_x,u_y,x,y", comments="")
    fails(["identify", "--data", str(bad), "--out", out, "--quiet"], "row 44")
    anon = tmp_path / "run.csv"
    data[42, 3] = 0.0
    np.savetxt(anon, data, delimiter=",", header="t,u_x,u_y,x,y", comments="")
    fails(["identify", "--data", str(anon), "--out", out, "--quiet"], "cannot tell its stage")
    fails(["identify", "--data", str(anon), "--stage", "creep", "dynamics", "--out", out], "--stage")
    # every identification starts with the hysteresis: runs of a later stage alone say which one is missing
    fails(["identify", "--data", str(anon), "--stage", "creep", "--out", out, "--quiet"], "'hysteresis'")
    fails(["identify", "--data", str(tmp_path / "missing.csv"), "--stage", "hysteresis", "--out", out],
          "missing.csv")
    assert not (tmp_path / "o.yaml").exists()


@pytest.mark.parametrize("noise_nm, target", [(0.0, 99.0), (100.0, 95.0)])
def test_commissioned_plant_reproduces_the_truth_on_held_out_voltages(cfg, noise_nm, target):
    """Stage-by-stage commissioning of the paper's sim plant (60 s creep steps), then the
    identified *whole* plant (Bouc-Wen → K + Cr → G_L, as exported) simulated from the held-out multisine + step
    pair record: fit ≥ 99 % noise-free, ≥ 95 % with 100 nm sensor noise scored against the noisy measurement."""
    from piezo_ff_ros.core.commissioning import commission_sim
    from piezo_ff_ros.core.identification.pipeline import identify_all
    from piezo_ff_ros.core.reproduce import truth_plant

    truth = truth_plant(cfg, "nominal", noise_nm * 1e-9, seed=2)
    ident, report, runs = commission_sim(truth, cfg.sample_rate, AXES, base=cfg,
                                         settings=CharacterisationSettings(creep_duration=60.0))
    plant_fit = report.fit_percent["plant"]
    assert min(plant_fit.values()) >= target, report.fit_percent
    assert report.plant_fit_basis.startswith("measured output")
    pv = [r for r in runs if r.meta["stage"] == "plant"]
    assert len(pv) == 1 and len(pv[0]) > 30 * cfg.sample_rate      # tens of seconds, never fitted on
    if noise_nm:
        # against the noisy record the fit is capped by the noise; against the noise-free truth it must be higher
        assert min(report.plant_fit_noise_free.values()) >= 99.0, report
        assert all(report.plant_fit_noise_free[a] > plant_fit[a] for a in AXES)
    else:
        # the figure is sensitive: the identified model with its Dp 2 % off fails it
        from piezo_ff_ros.core.identification.pipeline import plant_fit as score
        off = dataclasses.replace(ident, hysteresis=dataclasses.replace(
            ident.hysteresis, Dp=tuple(tuple(1.02 * v for v in row) for row in ident.hysteresis.Dp)))
        assert min(score(off, pv).values()) < target
        # Table I "after" creep (Section V-C: 20 µm step on y through creep⁻¹ + hysteresis⁻¹, 60 s): the printed
        # cascade gives 0.00 %; the identified one must be within 0.1 pp (it was −0.35 % before the Bouc-Wen refit)
        from piezo_ff_ros.core.compensators.creep import CreepCompensator
        from piezo_ff_ros.core.compensators.hysteresis import HysteresisCompensator
        fs = cfg.sample_rate
        ref = np.zeros((int(60 * fs), 2))
        ref[int(0.5 * fs):, 1] = 20e-6
        y = Plant(cfg).process(HysteresisCompensator(ident.hysteresis).process(
            CreepCompensator(ident.creep, 1 / fs).process(ref)))[:, 1]
        a_f = y[int(0.7 * fs)]
        assert abs(100 * (y[-1] - a_f) / a_f) <= 0.1, (y[-1], a_f)
        # identify_all on the recorded runs reports the same whole-plant figure
        _, rep2 = identify_all(runs, base=cfg, synthesize=False)
        assert rep2.fit_percent["plant"] == pytest.approx(plant_fit, abs=0.5)



def test_a_modal_fit_with_a_single_unknown_pole():
    """One real pole to fit (a single-axis creep entry of order 1): the bounded solver finds it (it stopped with
    an IndexError inside scipy's 2-D trust-region step)."""
    from piezo_ff_ros.core.identification.modal import fit_row, poles_to_theta

    dt = 1e-3
    t = np.arange(4000) * dt
    u = (t > 0.1).astype(float)
    y = 2.0 * (1 - np.exp(-5.0 * np.clip(t - 0.1, 0, None))) * (t > 0.1)   # 2/(s/5 + 1): pole at −5 rad/s
    y = y + 1e-3 * np.random.default_rng(0).standard_normal(len(t))
    th0, st = poles_to_theta(np.array([-0.001]))   # started slow, as an automatic order search may
    models, _ = fit_row([y], [[u]], [st], [th0], dt)
    assert models[0].poles().real[0] == pytest.approx(-5.0, rel=0.05)
