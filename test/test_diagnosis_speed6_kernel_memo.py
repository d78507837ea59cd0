"""A rebuilt plant reuses its specialised bank loops without writing their source again, and replays the same
numbers as the first one."""
from __future__ import annotations

import numpy as np

from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.kernels import specialise
from piezo_ff_ros.core.models.effects import build_plant


def test_same_structure_is_generated_once_and_shared(monkeypatch):
    cfg = load_config()
    u = np.cumsum(np.random.default_rng(0).standard_normal((4000, 2)), axis=0) * 0.5
    first = build_plant(cfg, [("input_delay", {"delay": 1e-4})])
    y_first = first.process(u)
    calls = []
    real_bank, real_inverse = specialise.bank_loop_source, specialise.inverse_loop_source
    monkeypatch.setattr(specialise, "bank_loop_source", lambda *a, **k: calls.append(a) or real_bank(*a, **k))
    monkeypatch.setattr(specialise, "inverse_loop_source",
                        lambda *a, **k: calls.append(a) or real_inverse(*a, **k))
    again = build_plant(cfg, [("input_delay", {"delay": 1e-4})])
    assert np.array_equal(again.process(u), y_first)
    assert calls == [], "the loop source of an already loaded structure was written again"


def test_a_new_structure_gets_its_own_loop():
    rng = np.random.default_rng(1)
    W = rng.standard_normal((12, 3))
    sizes = np.array([2, 1, 2])
    D = np.eye(2)
    a = specialise.bank_loop_module(W, sizes, D)
    assert specialise.bank_loop_module(W * 2.0, sizes, D) is a          # values are arguments, not structure
    W0 = W.copy()
    W0[4, 1] = 0.0                                                      # one coefficient less: another structure
    b = specialise.bank_loop_module(W0, sizes, D)
    assert b is not a
    assert b.__name__ == specialise.load_generated(
        specialise.bank_loop_source(specialise.bank_structure(W0, sizes, D)), "bankloop").__name__
