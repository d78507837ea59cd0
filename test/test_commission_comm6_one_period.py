"""Hysteresis identification on the records the ROS graph rig makes: runs played from rest (a 2 ms ramp to a run's
first sample, kept in the run), one short sine period.

Core level, no ROS: the graph's simulated driver is the core ``Plant`` (its recorded sines match the core's sample
for sample), and :func:`~piezo_ff_ros.core.characterisation_graph.graph_run_trajectory` is what ``GraphRig.play``
plays, so ``SimRig`` playing those trajectories records what the graph records.  ``identify_bouc_wen`` is then
called on the fit/validation split ``commission`` makes (``_tagged``).
"""
from dataclasses import replace

import numpy as np
import pytest

from piezo_ff_ros.core.characterisation import CharacterisationSettings
from piezo_ff_ros.core.characterisation_graph import graph_run_trajectory
from piezo_ff_ros.core.commissioning import SimRig, _tagged, characterisation_plan
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.identification.bouc_wen import _block_means, _linear_abg, identify_bouc_wen
from piezo_ff_ros.core.models.plant import Plant


def graph_hysteresis_records(settings, tmp_path):
    """The hysteresis fit and held-out runs as the graph rig records them (from rest, graph types)."""
    cfg = load_config()
    fs = cfg.sample_rate
    plan = [replace(p, trajectory=graph_run_trajectory(p.name, p.trajectory, fs, tmp_path))
            for p in characterisation_plan(settings, cfg.axes)["hysteresis"]]
    fit, val = _tagged(SimRig(Plant(cfg), fs, cfg.axes).play(plan), plan, fs)
    return cfg, fit, val


def test_one_sine_period_played_from_rest_identifies_the_hysteresis(tmp_path):
    """One 1 Hz period per sine (``--sine-periods 1 --sine-frequency 1``), the two-axis run and the held-out run
    starting from rest with the graph's ramp: the identified Bouc-Wen predicts the held-out run (> 95 % per axis).
    The ramp's few large voltage steps must not decide the data-driven start."""
    _, fit, val = graph_hysteresis_records(CharacterisationSettings(sine_frequency=1.0, sine_periods=1), tmp_path)
    # the layout the graph records: the two-axis run begins with the ramp to 200 V on y
    sine_all = next(r for r in fit if r.meta["experiment"] == "sine_all")
    assert sine_all.u[0, 1] == pytest.approx(5.0) and len(sine_all) == 20040
    hf = identify_bouc_wen(fit, val)
    assert np.all(hf.fit_validation > 95), hf.fit_validation
    assert np.all(hf.fit_train > 95), hf.fit_train


def test_the_linear_start_is_not_decided_by_a_ramp_to_the_first_sample(tmp_path):
    """With Dp at the truth's, the linear regression of A, B, Γ on the block means (the start of the fit) gives the
    same direct terms on the graph's records as on the same records with the ramp from rest cut off: a positive B,
    A and B diagonals within 2 % (they were 2.5× and of the wrong sign)."""
    cfg, fit, _ = graph_hysteresis_records(CharacterisationSettings(sine_frequency=1.0, sine_periods=1), tmp_path)
    ramp = 40   # FROM_REST_S at 20 kHz
    cut = [r.slice(ramp, len(r)) if r.u[0].any() else r for r in fit]
    assert [len(r) for r in cut] == [20000, 20000, 20000] and not any(r.u[0].any() for r in fit[:2])
    dp = np.asarray(cfg.hysteresis.arrays()["Dp"])
    A, B, _, _, _ = _linear_abg(*_block_means(fit, 3000), dp, np.zeros(2), False)
    A_cut, B_cut, _, _, _ = _linear_abg(*_block_means(cut, 3000), dp, np.zeros(2), False)
    assert np.all(np.diag(B) > 0), B
    np.testing.assert_allclose(np.diag(A), np.diag(A_cut), rtol=0.02)
    np.testing.assert_allclose(np.diag(B), np.diag(B_cut), rtol=0.02)
