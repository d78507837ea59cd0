"""The base-excited mode's refinement evaluates its Jacobian's columns through one batched pass per frequency (the
``workers`` map of ``scipy.optimize.least_squares``): the fit — parameters, standard errors, training RMS — is the
one the column-by-column evaluation gives, bit for bit, alone and on linear resonances, on the whole run and on
windows."""
from __future__ import annotations

import numpy as np
import pytest

from bench.synthetic.in_family import excitation
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis import fit_modes
from piezo_ff_ros.core.diagnosis.candidates import FitContext
from piezo_ff_ros.core.diagnosis.replay import Windows, simulate
from piezo_ff_ros.core.models import effects as fx

FS = 5000.0


@pytest.fixture(scope="module")
def ctxs():
    cfg = load_config().with_sample_rate(FS)
    u = excitation("train", FS, 6.0, seed=2, amplitude=150.0)
    truth = [("amplitude_dependent_dynamics", {"form": "base_excited", "freq": 650.0, "damping": 0.03,
                                               "cubic": [8.0, -3.0], "quadratic_damping": [2.0, 0.5]})]
    y = fx.build_plant(cfg, truth, noise_std=20e-9, seed=5).process(u)
    y_base = simulate(cfg, u, [])
    whole = FitContext(cfg, [], u, y, y_base, Windows.whole(len(u)))
    spread = FitContext(cfg, [], u, y, y_base, Windows.spread(len(u), 8000, 4, 1000))
    return whole, spread


def _same(a, b):
    assert a.params == b.params
    assert a.stderr == b.stderr
    assert a.train_rms == b.train_rms
    assert a.extra["theta"] == b.extra["theta"]


@pytest.mark.parametrize("which", ["whole", "spread"])
def test_batched_jacobian_gives_the_column_by_column_fit(ctxs, which, monkeypatch):
    ctx = ctxs[0] if which == "whole" else ctxs[1]
    assert fit_modes._LSQ_WORKERS, "the installed scipy's least_squares takes workers"
    batched = fit_modes.fit_base_excited_mode(ctx)
    calls = []
    real = fit_modes.base_excited_deflections
    monkeypatch.setattr(fit_modes, "base_excited_deflections",
                        lambda y, f, z, c, q, dt: calls.append(np.atleast_2d(c).shape[0]) or real(y, f, z, c, q, dt))
    monkeypatch.setattr(fit_modes, "_LSQ_WORKERS", False)
    plain = fit_modes.fit_base_excited_mode(ctx)
    _same(batched, plain)
    assert np.isfinite(batched.train_rms) and batched.params["form"] == "base_excited"
    assert max(calls) > 1          # the grid's shared passes (the plain refinement's are one mode each)


def test_batched_jacobian_on_linear_resonances(ctxs, monkeypatch):
    ctx = ctxs[1]
    linear = fit_modes._linear_modes(ctx, [(650.0, 0.03)])
    batched = fit_modes.fit_base_excited_mode(ctx, linear)
    monkeypatch.setattr(fit_modes, "_LSQ_WORKERS", False)
    _same(batched, fit_modes.fit_base_excited_mode(ctx, linear))


def test_the_refinement_does_batch(ctxs, monkeypatch):
    """With ``workers`` the refinement's passes carry several modes (else the test above compares a path with
    itself)."""
    ctx = ctxs[0]
    sizes = []
    real = fit_modes.base_excited_deflections
    monkeypatch.setattr(fit_modes, "base_excited_deflections",
                        lambda y, f, z, c, q, dt: sizes.append(np.atleast_2d(c).shape[0]) or real(y, f, z, c, q, dt))
    fit_modes._fit_base_excited_on(ctx, None, np.r_[np.log(650.0), np.log(0.03), 1.0, 1.0, 0.5, 0.5, 1.0, 1.0], 4)
    assert any(1 < k < 9 for k in sizes)
