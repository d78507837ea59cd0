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


def test_modes_of_several_dampings_in_one_pass_get_their_own_numbers():
    """A pass with a damping per mode gives, for each damping, the numbers of a pass with that damping alone."""
    y = _base()
    zetas = (0.01, 0.03, 0.1)
    cubic = np.tile([[1e-3, 1e-3], [0.0, 0.0], [0.0, 0.0]], (3, 1))
    quad = np.tile([[0.0, 0.0], [1e-3, 1e-3], [0.0, 0.0]], (3, 1))
    for freq in (60.0, 4000.0):
        D = base_excited_deflections(y, freq, np.repeat(zetas, 3), cubic, quad, 1 / FS)
        for i, z in enumerate(zetas):
            assert np.array_equal(D[3 * i:3 * i + 3], base_excited_deflections(y, freq, z, cubic[:3], quad[:3], 1 / FS))
        assert not np.array_equal(D[0], D[3])


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


def _run(n: int = 400):
    from piezo_ff_ros.core.recording.run import RunData

    t = np.arange(n) / FS
    u = np.stack([np.sin(2 * np.pi * 50 * t), np.cos(2 * np.pi * 30 * t)], axis=1)
    return RunData(t, u, 1e-6 * u, ("x", "y"))


def test_run_check_finds_nan_and_inf_and_passes_huge_finite_values():
    """The NaN/Inf check names the first bad sample whatever its kind, and a run of finite values whose sum
    overflows (the fast path's blind spot) still passes."""
    import pytest

    from piezo_ff_ros.core.diagnosis.replay import check_run

    check_run(_run(), "train")
    for bad, what in ((np.nan, "y"), (np.inf, "u"), (-np.inf, "y")):
        r = _run()
        getattr(r, what)[123, 1] = bad
        with pytest.raises(ValueError, match=f"train: {what} has NaN/Inf \\(first at sample 123\\)"):
            check_run(r, "train")
    r = _run()
    r.y[:, 0] = 8e307 * np.sign(np.sin(np.arange(len(r.t)) + 0.5))
    r.y[:4, 0] = 8e307  # the first partial sums overflow
    with np.errstate(over="ignore", invalid="ignore"):
        assert not np.isfinite(np.sum(r.y))
    check_run(r, "train")


def test_run_check_time_uniformity_against_the_median_step():
    """Time steps spread by less than 1e-3 of the median step pass; a larger spread, a repeated or a backward stamp
    is refused; a spread larger than 1e-3 of the smallest step but not of the median passes (the median decides)."""
    import pytest

    from piezo_ff_ros.core.diagnosis.replay import check_run
    from piezo_ff_ros.core.recording.run import RunData

    base = _run()
    dt = 1 / FS
    for steps, ok in ((np.full(399, dt) * (1 + 4e-4 * np.sin(np.arange(399))), True),
                      (np.r_[np.full(398, dt), 1.002 * dt], False),
                      (np.r_[np.full(200, dt), 0.0, np.full(198, dt)], False),
                      (np.r_[np.full(200, dt), -dt, np.full(198, dt)], False),
                      # the smallest step 0.9995 dt, the median dt: a spread of 1.5e-3 dt is refused; one of
                      # 0.9997e-3 dt (above 1e-3 of the smallest step, below 1e-3 of the median) passes
                      (np.r_[np.full(397, dt), 0.9995 * dt, 1.001 * dt], False),
                      (np.r_[np.full(397, dt), 0.9995 * dt, 1.0004997 * dt], True)):
        t = np.r_[0.0, np.cumsum(steps)]
        run = RunData(t, base.u, base.y, base.axes)
        if ok:
            check_run(run, "train")
        else:
            with pytest.raises(ValueError, match="train: time is not uniformly increasing"):
                check_run(run, "train")
