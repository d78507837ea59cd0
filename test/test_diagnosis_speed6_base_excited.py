"""The base-excited mode's lanes run side by side without branches and give the numbers of the plain loop that
integrates each oscillator on its own (the loop below, compiled alike): the diagnosis grid's nine oscillators,
one nonlinear mode with its linear twin, a softening spring held at its stiffness floor, a strong quadratic
damping, one and many RK4 sub-steps per sample, and the stage fed block by block."""
from __future__ import annotations

import math

import numpy as np
import pytest

from piezo_ff_ros.core._jit import njit
from piezo_ff_ros.core.models.effects import BaseExcitedNonlinearMode
from piezo_ff_ros.core.models.effects.common import LEVEL_REF
from piezo_ff_ros.core.models.effects.modes import MIN_STIFFNESS_FACTOR, RK4_OMEGA_STEP, base_excited_deflections

FS = 20_000.0


@njit(cache=False)
def _plain_accel(xs, vs, w, z, c3, c2, ref, linear):  # pragma: no cover - compiled
    if linear:
        return -2.0 * z * w * vs - w * w * xs
    fk = max(MIN_STIFFNESS_FACTOR, 1.0 + c3 * (xs / ref) ** 2)
    return -2.0 * z * w * (1.0 + c2 * abs(vs) / (w * ref)) * vs - w * w * xs * fk


@njit(cache=False)
def _plain_run(y, w, zeta, kc, kq, ref, dt, osc, hist, out):  # pragma: no cover - compiled
    """One oscillator after the other within each sub-step, each with a branch on its linearity."""
    N, n = y.shape
    K = kc.shape[0]
    sub = max(1, int(math.ceil(w * dt / RK4_OMEGA_STEP)))
    h = dt / sub
    X = np.empty((K, n))
    V = np.empty((K, n))
    for t in range(N):
        for j in range(n):
            yk = y[t, j]
            seen = hist[j, 2]
            if seen < 1.0:
                hist[j, 0] = yk
                hist[j, 1] = yk
            elif seen < 2.0:
                hist[j, 1] = hist[j, 0]
            dv = (yk - 2.0 * hist[j, 0] + hist[j, 1]) / dt if seen >= 1.0 else 0.0
            for k in range(K):
                X[k, j] = osc[k, j, 0]
                V[k, j] = osc[k, j, 1] - dv
            hist[j, 1] = hist[j, 0]
            hist[j, 0] = yk
            hist[j, 2] = seen + 1.0
        for _ in range(sub):
            for k in range(K):
                for j in range(n):
                    x = X[k, j]
                    v = V[k, j]
                    c3 = kc[k, j]
                    c2 = kq[k, j]
                    ln = c3 == 0.0 and c2 == 0.0
                    z = zeta[k]
                    k_v = _plain_accel(x, v, w, z, c3, c2, ref, ln)
                    kx = 0.0 + 1.0 * v
                    kv = 0.0 + 1.0 * k_v
                    xs, vs = x + 0.5 * h * v, v + 0.5 * h * k_v
                    k_v = _plain_accel(xs, vs, w, z, c3, c2, ref, ln)
                    kx += 2.0 * vs
                    kv += 2.0 * k_v
                    xs, vs = x + 0.5 * h * vs, v + 0.5 * h * k_v
                    k_v = _plain_accel(xs, vs, w, z, c3, c2, ref, ln)
                    kx += 2.0 * vs
                    kv += 2.0 * k_v
                    xs, vs = x + h * vs, v + h * k_v
                    k_v = _plain_accel(xs, vs, w, z, c3, c2, ref, ln)
                    kx += 1.0 * vs
                    kv += 1.0 * k_v
                    X[k, j] = x + h * kx / 6.0
                    V[k, j] = v + h * kv / 6.0
        for k in range(K):
            for j in range(n):
                osc[k, j, 0] = X[k, j]
                osc[k, j, 1] = V[k, j]
                out[k, t, j] = X[k, j]


def _plain(y, freq, damping, cubic, quad, dt):
    kc = np.ascontiguousarray(np.atleast_2d(np.asarray(cubic, float)))
    kq = np.ascontiguousarray(np.atleast_2d(np.asarray(quad, float)))
    K, n = kc.shape
    out = np.empty((K,) + y.shape)
    zeta = np.ascontiguousarray(np.broadcast_to(np.asarray(damping, float), (K,)))
    _plain_run(np.ascontiguousarray(y, float), 2 * math.pi * freq, zeta, kc, kq, LEVEL_REF, dt,
               np.zeros((K, n, 2)), np.zeros((n, 3)), out)
    return out


def _base(n=6000, amp=5e-6, seed=3):
    t = np.arange(n) / FS
    rng = np.random.default_rng(seed)
    return np.stack([amp * np.sign(np.sin(2 * np.pi * 7 * t)) + 1e-7 * rng.standard_normal(n),
                     0.6 * amp * np.sin(2 * np.pi * 450 * t) + 1e-7 * rng.standard_normal(n)], axis=1)


@pytest.mark.parametrize("freq", [60.0, 900.0, 3000.0, 8900.0])
def test_grid_oscillators_equal_the_plain_loop(freq):
    """The diagnosis grid: per damping, a cubic-only and a quadratic-only mode and their linear twin."""
    y = _base()
    n, eps, zeros = 2, 1e-3, np.zeros(2)
    zetas = (0.01, 0.03, 0.1)
    cubic = np.tile(np.stack([np.full(n, eps), zeros, zeros]), (3, 1))
    quad = np.tile(np.stack([zeros, np.full(n, eps), zeros]), (3, 1))
    damping = np.repeat(np.asarray(zetas), 3)
    assert np.array_equal(base_excited_deflections(y, freq, damping, cubic, quad, 1 / FS),
                          _plain(y, freq, damping, cubic, quad, 1 / FS))


@pytest.mark.parametrize("cubic,quad", [([2.0, -0.5], [1.0, 0.0]),
                                         ([-50.0, -30.0], [0.0, 50.0]),     # softening to the stiffness floor
                                         ([50.0, 0.0], [50.0, 2.0]),
                                         ([0.0, 0.0], [0.0, 0.0])])
@pytest.mark.parametrize("amp", [5e-6, 4e-5])
def test_one_mode_and_its_twin_equal_the_plain_loop(cubic, quad, amp):
    y = _base(amp=amp)
    c = np.array([cubic, [0.0, 0.0]])
    q = np.array([quad, [0.0, 0.0]])
    for freq, zeta in ((150.0, 0.02), (5000.0, 0.005)):
        got = base_excited_deflections(y, freq, zeta, c, q, 1 / FS)
        # a strong stiffening spring at the large amplitude blows up (inf, NaN): the same non-finite numbers
        assert np.array_equal(got, _plain(y, freq, zeta, c, q, 1 / FS), equal_nan=True)


def test_floor_is_reached_by_the_softening_case():
    """The stiffness floor case above does reach the floor (else it would not test the selected branch there)."""
    y = _base(amp=4e-5)
    d = _plain(y, 150.0, 0.02, np.array([[-50.0, -30.0]]), np.array([[0.0, 50.0]]), 1 / FS)[0]
    assert np.any(1.0 - 50.0 * (d[:, 0] / LEVEL_REF) ** 2 < MIN_STIFFNESS_FACTOR)


def test_stage_block_by_block_equals_the_plain_loop():
    y = _base(n=5000)
    st = BaseExcitedNonlinearMode(700.0, 0.02, [3.0, -1.0], [2.0, 0.5], 1 / FS, 2, [1.0, 0.7])
    blocks = [st.deflection_change(y[i:i + 777]) for i in range(0, len(y), 777)]
    ref = _plain(y, 700.0, 0.02, np.array([[3.0, -1.0], [0.0, 0.0]]), np.array([[2.0, 0.5], [0.0, 0.0]]), 1 / FS)
    assert np.array_equal(np.concatenate(blocks), (ref[0] - ref[1]) * np.array([1.0, 0.7]))
