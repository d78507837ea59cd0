"""Amplifier roll-offs of forms the candidates were not written for (a 3rd-order Butterworth filter, a
resonant 2nd-order amplifier), at an FSM-like 6.4 kHz: named `amplifier_bandwidth`, not the generic mode family.  The truths
are continuous-time filters (scipy, exact ZOH at 25× the record's rate) in front of the nominal model replayed by
the benchmark's own code at that rate, sampled at the record's."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from bench.diagnosis import truth
from bench.synthetic.in_family import excitation
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import DiagnosisOptions, diagnose
from piezo_ff_ros.core.recording.run import RunData

FS = 6400.0
DUR = 3.0
NOISE = 20e-9
CANDS = ("amplifier_bandwidth", "input_delay", "unmodelled_mode", "gain_mismatch")


def _analog_filter(kind: str):
    wc = 2 * np.pi * 900.0
    if kind == "butter3":
        return signal.butter(3, wc, analog=True)
    z = 0.4                                   # a resonant amplifier stage
    return [wc ** 2], [1, 2 * z * wc, wc ** 2]


#: the truth runs at OVER× the record's rate (the voltage a staircase held by the DAC, the filter and the plant
#: continuous in between) and is sampled at the record's rate: no second hold between filter and plant
OVER = 25


def _runs(cfg, kind):
    b, a = _analog_filter(kind)
    bd, ad, _ = signal.cont2discrete((b, a), 1 / (OVER * FS), method="zoh")
    bd = np.ravel(bd)
    nom = truth.nominal_matrices(cfg.with_sample_rate(OVER * FS))
    out = []
    for j, k in enumerate(("train", "test")):
        u = excitation(k, FS, DUR, seed=3 + j, amplitude=120.0)
        uf = np.repeat(u, OVER, axis=0)
        zi = signal.lfilter_zi(bd, ad)[:, None] * uf[:1]          # the amplifier settled at the first voltage
        v = signal.lfilter(bd, ad, uf, axis=0, zi=zi)[0]
        y = truth.simulate(nom, [], v)[::OVER] + NOISE * np.random.default_rng(40 + j).standard_normal(u.shape)
        out.append(RunData(np.arange(len(u)) / FS, u, y, ("x", "y")))
    return out


@pytest.mark.parametrize("kind", ["butter3", "resonant2"])
def test_rolloff_of_another_form_is_amplifier_bandwidth(kind):
    cfg = load_config().with_sample_rate(FS)
    train, test = _runs(cfg, kind)
    res = diagnose(cfg, train, test, DiagnosisOptions(candidates=CANDS, max_stack=1))
    h = res["heldout"]
    assert res["verdict"] == "amplifier_bandwidth", [(r["effect"], r["heldout_after_nrmse_percent"], r["n_params"])
                                                     for r in res["ranking"]]
    assert h["after_nrmse_percent"] < 0.4 * h["before_nrmse_percent"]
