"""Rate vs amplitude dependence told apart by what the excitation allows: when the runs' voltage rate and amplitude
vary together, a rate-dependent loop and an amplitude-dependent one predict the same, and the diagnosis says it is
ambiguous and proposes the experiment that varies them apart; that experiment decides."""
from __future__ import annotations

import numpy as np
import pytest

from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose
from piezo_ff_ros.core.diagnosis.decision import CONFOUND_RHO, excitation_rate_amplitude_correlation
from piezo_ff_ros.core.models.effects import build_plant
from piezo_ff_ros.core.recording.run import RunData
from piezo_ff_ros.core.trajectories import from_dict

FS = 5000.0
TRUTH = [("hysteresis_rate_dependence", {"alpha": 0.4})]
CANDS = ("hysteresis_rate_dependence", "amplitude_dependent_dynamics", "gain_mismatch")


@pytest.fixture(scope="module")
def cfg():
    return load_config().with_sample_rate(FS)


def _record(cfg, u, seed):
    y = build_plant(cfg, TRUTH, noise_std=20e-9, seed=seed).process(u)
    return RunData(np.arange(len(u)) / FS, u, y, ("x", "y"))


def _confounded(seed, f0):
    """Sine stretches whose amplitude grows with their frequency: the peak rate follows the amplitude."""
    parts = []
    for k, scale in enumerate((0.25, 0.5, 0.75, 1.0)):
        t = np.arange(int(1.5 * FS)) / FS
        f = f0 * scale * 8
        parts.append(np.c_[120 * scale * np.sin(2 * np.pi * f * t + seed),
                           100 * scale * np.sin(2 * np.pi * 1.1 * f * t + 1 + seed)])
    return np.vstack(parts)


def test_confounded_excitation_gives_ambiguous_and_the_experiment_decides(cfg):
    train = _record(cfg, _confounded(0, 1.0), 1)
    test = _record(cfg, _confounded(1, 1.3), 2)
    assert excitation_rate_amplitude_correlation([train, test]) >= CONFOUND_RHO
    opts = DiagnosisOptions(candidates=CANDS, max_stack=1)
    res = diagnose(cfg, train, test, opts)
    d = res["discrimination"]
    assert d is not None and set(d["ambiguous_between"]) >= {"hysteresis_rate_dependence",
                                                             "amplitude_dependent_dynamics"}, res["confidence_reason"]
    assert d["confounded"]["rate_amplitude_correlation"] >= CONFOUND_RHO
    assert res["confidence"] == "low"
    exp = d["experiment"]
    _, u = from_dict(exp["trajectory"]).sample(FS)
    res2 = diagnose(cfg, train, test, opts, discriminate=_record(cfg, u, 3))
    assert res2["verdict"] == "hysteresis_rate_dependence"
    assert res2["discrimination"]["decided_on_run"]["winner"] == "hysteresis_rate_dependence"


def test_independent_rate_and_amplitude_are_not_confounded():
    t = np.arange(int(4 * FS)) / FS
    # one amplitude at two rates, then two amplitudes at one rate
    u = np.concatenate([np.c_[100 * np.sin(2 * np.pi * f * t[:5000]), 80 * np.sin(2 * np.pi * f * t[:5000])] * s
                        for s, f in ((1.0, 2.0), (1.0, 8.0), (0.25, 8.0), (0.25, 2.0))])
    run = RunData(np.arange(len(u)) / FS, u, np.zeros_like(u), ("x", "y"))
    assert excitation_rate_amplitude_correlation([run]) < CONFOUND_RHO
