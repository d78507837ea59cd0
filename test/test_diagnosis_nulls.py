"""`none` at the noise floor: a record with no unmodelled effect, recorded under another equally valid timing
convention than the nominal model's (DAC edges settling a twentieth of a sample late) and with coloured noise, gets
`none`; a small real effect (a resonance at about the noise level) on the same record is still named.

The truths run the nominal plant at 20 times the record's rate on the held voltages and read it at the record's
samples (point sampling), as a continuous-time plant behind a real DAC would be.
"""
import numpy as np
import pytest
import scipy.signal

from bench.synthetic.in_family import excitation
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose, json_ready
from piezo_ff_ros.core.diagnosis.decision import TIMING_CONVENTION_SAMPLES, align_timing
from piezo_ff_ros.core.diagnosis.replay import residual, timing_sensitivity
from piezo_ff_ros.core.models.effects import build_plant
from piezo_ff_ros.core.recording.run import RunData

FS = 5000.0
DUR = 6.0
FINE = 20           # the truth's steps per record sample
EDGE_LATE = 1       # fine steps by which the truth's DAC edges settle late: 1/20 sample
CANDIDATES = ("unmodelled_mode", "gain_mismatch", "input_delay", "hysteresis_rate_dependence")


@pytest.fixture(scope="module")
def cfg():
    return load_config().with_sample_rate(FS)


def late_edge_response(cfg, u, effects):
    """The nominal plant (plus ``effects``) behind a DAC whose edges settle ``EDGE_LATE`` fine steps late, simulated
    ``FINE`` times faster than the record and sampled at its rate."""
    uf = np.repeat(u, FINE, axis=0)
    uf = np.vstack([np.repeat(u[:1], EDGE_LATE, axis=0), uf[:len(uf) - EDGE_LATE]])
    return build_plant(cfg.with_sample_rate(FS * FINE), effects).process(uf)[::FINE]


def _run(cfg, kind, seed, effects):
    """A record of the nominal plant (plus ``effects``) behind a DAC whose edges settle late, AR(1) noise."""
    u = excitation(kind, FS, DUR, seed=seed)
    y = late_edge_response(cfg, u, effects)
    rng = np.random.default_rng(seed + 7)
    noise = scipy.signal.lfilter([1.0], [1.0, -0.95], rng.standard_normal((len(u), 2)) * 3e-9 * np.sqrt(1 - 0.95 ** 2),
                                 axis=0)
    return RunData(t=np.arange(len(u)) / FS, u=u, y=y + noise, axes=tuple(cfg.axes))


def test_timing_sensitivity_accounts_for_a_late_dac_edge(cfg):
    """The nominal replay moved along its timing sensitivity by the fitted offset matches the late-edge plant to
    1 % of their difference, and the offset found is the truth's (a twentieth of a sample)."""
    u = excitation("test", FS, DUR, seed=2)
    truth = _run(cfg, "test", 2, []).y
    r = residual(truth, build_plant(cfg, []).process(u))
    c = timing_sensitivity(cfg, u)
    tau = float(np.sum(r * c) / np.sum(c * c))
    assert tau == pytest.approx(EDGE_LATE / FINE, rel=0.05)
    noiseless = residual(build_plant(cfg.with_sample_rate(FS * FINE), []).process(
        np.vstack([np.repeat(u[:1], EDGE_LATE, axis=0), np.repeat(u, FINE, axis=0)[:-EDGE_LATE]]))[::FINE],
        build_plant(cfg, []).process(u))
    assert np.linalg.norm(align_timing(noiseless, c)) < 0.01 * np.linalg.norm(noiseless)


def test_alignment_is_bounded_to_the_convention():
    """A lag longer than the convention's bound is not aligned away: only ±TIMING_CONVENTION_SAMPLES is removed."""
    c = np.sin(np.linspace(0, 20, 1000))[:, None] * np.ones((1, 2))
    r = 0.5 * c
    left = align_timing(r, c)
    assert np.allclose(left, (0.5 - TIMING_CONVENTION_SAMPLES) * c)


def test_a_null_recorded_under_another_timing_convention_with_coloured_noise_is_none(cfg):
    """No effect, DAC edges a twentieth of a sample late, AR(1) noise: the gap (0.2 % of the signal, ~8× the noise)
    is the discretisation convention, reproducible but not an effect: `none`."""
    train, test = _run(cfg, "train", 1, []), _run(cfg, "test", 2, [])
    res = json_ready(diagnose(cfg, train, test, DiagnosisOptions(candidates=CANDIDATES, max_stack=1)))
    assert res["verdict"] == "none", (res["verdict"], res["confidence_reason"])


def test_a_small_resonance_at_the_noise_level_is_still_named(cfg):
    """The same records with a lightly damped 300 Hz resonance at 0.035 % of the signal (~1.3× the noise, a sixth of
    the convention's gap): still `unmodelled_mode`."""
    mode = [("unmodelled_mode", {"freq": 300.0, "damping": 0.03, "gains": [0.03, 0.0]})]
    train, test = _run(cfg, "train", 1, mode), _run(cfg, "test", 2, mode)
    res = json_ready(diagnose(cfg, train, test, DiagnosisOptions(candidates=CANDIDATES, max_stack=1)))
    assert res["verdict"] == "unmodelled_mode", (res["verdict"], res["confidence_reason"])
