"""Shared passes of the diagnosis's hot loops give the numbers of the plain computations they replace: several
base-excited modes integrated in one pass over their base (each gets what it gets alone), and the unmodelled-mode
stage's gain terms summed in one compiled pass (the sums of ``static_gain``, in its order)."""
from __future__ import annotations

import numpy as np

from piezo_ff_ros.core.lti import static_gain
from piezo_ff_ros.core.models.effects import BaseExcitedNonlinearMode, UnmodelledMode
from piezo_ff_ros.core.models.effects.modes import base_excited_deflections

FS = 20_000.0


def _base(n: int = 8000) -> np.ndarray:
    t = np.arange(n) / FS
    rng = np.random.default_rng(3)
    return np.stack([5e-6 * np.sign(np.sin(2 * np.pi * 7 * t)) + 1e-7 * rng.standard_normal(n),
                     3e-6 * np.sin(2 * np.pi * 450 * t)], axis=1)


def test_modes_sharing_one_base_pass_get_their_own_numbers():
    """Each row of the shared pass, minus the linear twin's row, is exactly what the stage of that mode alone adds
    (low and high frequencies: one and several RK4 sub-steps per sample; a mode nonlinear on one axis only)."""
    y = _base()
    for freq, zeta in ((120.0, 0.03), (7000.0, 0.01)):
        cubic = np.array([[2.0, -0.5], [0.0, 30.0], [0.0, 0.0]])
        quad = np.array([[1.0, 0.0], [0.0, 4.0], [0.0, 0.0]])
        D = base_excited_deflections(y, freq, zeta, cubic, quad, 1 / FS)
        assert D.shape == (3,) + y.shape
        for k in range(2):
            alone = BaseExcitedNonlinearMode(freq, zeta, cubic[k], quad[k], 1 / FS).deflection_change(y)
            assert np.array_equal(D[k] - D[2], alone)
            assert np.max(np.abs(alone)) > 0
        # the linear twin moves (it is the deflection, not the change), and alone adds nothing
        assert np.max(np.abs(D[2])) > 0
        assert not np.any(BaseExcitedNonlinearMode(freq, zeta, 0.0, 0.0, 1 / FS).deflection_change(y))


def test_unmodelled_mode_adds_its_terms_as_static_gain_does():
    """The stage's output equals ``y + Σ static_gain(BP·)G + static_gain(HP·)H + static_gain(y − BP − HP)L``
    built from its own filters, bit for bit, in one block or several; without high-/low-pass gains only the band-pass
    terms."""
    y = _base(6000)
    rng = np.random.default_rng(4)
    G, H, L = (rng.standard_normal((2, 2, 2)) for _ in range(3))
    for hp, lp in ((None, None), (H, None), (H, L)):
        st = UnmodelledMode([300.0, 2500.0], [0.02, 0.1], G, 1 / FS, 2, hp, lp)
        ref = UnmodelledMode([300.0, 2500.0], [0.02, 0.1], G, 1 / FS, 2, hp, lp)
        expect = y.copy()
        for m in range(2):
            bp = ref.bandpass(y, m)
            expect += static_gain(bp, G[m])
            if hp is not None:
                h = ref.highpass(y, m)
                expect += static_gain(h, H[m])
                if lp is not None:
                    expect += static_gain(y - bp - h, L[m])
        whole = st.process(y)
        assert np.array_equal(whole, expect)
        st.reset()
        assert np.array_equal(np.vstack([st.process(y[:1]), st.process(y[1:2501]), st.process(y[2501:])]), whole)
