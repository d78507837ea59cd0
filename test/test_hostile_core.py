"""Hostile input to the compensator's and the driver's cores: refused with one line, counted, nothing poisoned or
pinned, the output recovering when the input does (no reset)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezo_ff_ros.core.compensator_core import ERROR, WARN, CompensatorCore, CompensatorSettings, ParameterBook
from piezo_ff_ros.core.param_map import config_to_params
from piezo_ff_ros.core.trajectories.workspace import reachable_range

N = 200
DT = 50_000
S0 = 1_000_000 * DT


@pytest.fixture(scope="module")
def base(paper_config):
    return paper_config


def make_core(base, feedback=True, **settings):
    book = ParameterBook(base)
    book.values.update(config_to_params(base))
    book.values["cascade.vibration"] = False
    cfg = book.end_declarations()
    settings.setdefault("reference_limit", reachable_range(base))
    return CompensatorCore(book, cfg, CompensatorSettings(**settings), applied_feedback=lambda: feedback)


def held(x=1e-6, y=0.0, n=N):
    return np.tile([x, y], (n, 1))


def run(core, blocks, k=0, t=0.0):
    """Feed reference blocks; the voltage blocks produced (None for a refused block)."""
    out = []
    for b in blocks:
        em = core.on_reference(S0 + k * DT, b, t)
        out.append(em.voltage[0].u if em.voltage else None)
        k += b.shape[0]
        t += 0.01
    return out


def test_reachable_range_is_the_static_reach_with_a_margin(base):
    lim = reachable_range(base, margin=1.0)
    g0 = (np.asarray(base.creep.K) + base.creep.Cr.dc_gain()) @ np.asarray(base.hysteresis.Dp)
    for i in range(2):
        assert lim[2 * i + 1] == pytest.approx(np.abs(g0[i]).sum() * base.limits.voltage)
        assert lim[2 * i] == -lim[2 * i + 1]
    assert reachable_range(base)[1] == pytest.approx(2 * lim[1])
    assert 20e-6 < lim[1] < 1e-4   # the PT230.94: some tens of µm


@pytest.mark.parametrize("bad", ["1e308 sample", "1e10 block", "1 m block"])
def test_an_unreachable_reference_is_refused_and_leaves_nothing_behind(base, bad):
    core, clean = make_core(base), make_core(base)
    block = {"1e308 sample": held(), "1e10 block": held(1e10, 1e10), "1 m block": held(1.0)}[bad]
    if bad == "1e308 sample":
        block[7, 0] = 1e308
    before = run(core, [held()] * 5)
    em = core.on_reference(S0 + 5 * N * DT, block, 0.05)
    assert em.voltage == [] and len(em.log) == 1 and em.log[0][0] == ERROR
    assert "reference_limit" in em.log[0][1] and "\n" not in em.log[0][1]
    assert core.rejected_blocks == 1 and core.diagnostics()[0] == ERROR
    after = run(core, [held()] * 50, k=6 * N, t=0.06)
    ref = run(clean, [held()] * 5 + [held()] * 50)
    # the refused block changed no state: the voltages are those of a compensator that never saw it
    for got, want in zip(before + after, ref[:5] + ref[5:]):
        np.testing.assert_array_equal(got, want)
    assert np.max(np.abs(after[-1])) < 50.0
    assert core.diagnostics()[0] == WARN   # the refusal is over; its count stays


def test_an_unreachable_reference_point_is_refused(base):
    core = make_core(base)
    em = core.set_point([1.0, 0.0])
    assert em.hold_timer is None and "reference_limit" in em.log[0][1] and core.pacer.point is None
    assert core.set_point([1e-6, 0.0]).hold_timer == "start"


def test_a_saturating_reference_within_the_limit_does_not_pin_the_output(base):
    lim = reachable_range(base)
    core = make_core(base)
    out = run(core, [held(0.999 * lim[1], 0.999 * lim[3])] * 100 + [held()] * 5)
    assert np.all(np.abs(out[99][-1]) >= 199.999)                # at the limit while the reference is out there
    assert np.all(np.abs(out[101]) < base.limits.voltage * 0.999)  # off it as soon as the reference is back


def test_the_limit_is_adjustable_and_off_when_empty(base):
    # blocks of 2 samples: the limit is checked on every sample of a block whatever its length, and the cascade
    # takes ~0.1 s per sample of a 1 m reference (its hysteresis path is integrated in steps along the huge input)
    core = make_core(base, reference_limit=())
    assert core.on_reference(S0, held(1.0, n=2), 0.0).voltage
    core = make_core(base)
    assert core.propose([("reference_limit", [1.0, -1.0, 0.0, 1.0])]).reason.startswith("reference_limit:")
    core.commit([("reference_limit", [-2.0, 2.0, -2.0, 2.0])])
    assert core.on_reference(S0, held(1.0, n=2), 0.0).voltage


def test_bypass_bounds_the_reference_by_the_voltage_limit(base):
    core = make_core(base, bypass=True)
    assert core.on_reference(S0, held(150.0), 0.0).voltage
    em = core.on_reference(S0 + N * DT, held(1e10), 0.01)
    assert not em.voltage and "limits.voltage" in em.log[0][1]


def test_off_grid_and_empty_reference_blocks_are_refused(base):
    core = make_core(base)
    em = core.on_reference(S0 + 1, held(), 0.0)
    assert not em.voltage and "off the 50000 ns sample grid" in em.log[0][1]
    assert not core.on_reference(S0, np.zeros((0, 2)), 0.0).voltage
    assert core.rejected_blocks == 2 and core.blocks == 0


@pytest.mark.parametrize("case", ["NaN", "1e10", "off grid", "foreign", "far ahead"])
def test_poisoned_applied_voltage_is_refused_and_changes_no_state(base, case):
    core, clean = make_core(base), make_core(base)
    ks = [S0 + i * N * DT for i in range(30)]
    outs = []
    for i, k in enumerate(ks):
        u = core.on_reference(k, held(5e-6), i * 0.01).voltage[0].u
        v = clean.on_reference(k, held(5e-6), i * 0.01).voltage[0].u
        np.testing.assert_array_equal(u, v)
        outs.append(u)
        if i == 3:
            bad = {"NaN": np.full((N, 2), np.nan), "1e10": np.full((N, 2), 1e10), "off grid": outs[0] * 0.5,
                   "foreign": np.zeros((N, 2)), "far ahead": None}[case]
            if case == "far ahead":   # a stamp 1e12 samples ahead: a hold that long asked for 14.6 TiB
                bad = outs[0]
            em = core.on_applied(ks[0] + (1 if case == "off grid" else 10**12 * DT if case == "far ahead" else 0),
                                 bad, 0.03,
                                 foreign="sender /intruder is not the paired driver" if case == "foreign" else "")
            assert len(em.log) == 1 and em.log[0][0] == ERROR and "voltage_applied block rejected" in em.log[0][1]
            assert core.applied_rejected == 1 and core.hs.resyncs == 0
            assert core.diagnostics()[0] == ERROR
    assert np.all(np.isfinite(np.vstack(outs)))


def test_the_cascade_never_follows_a_hold_of_absurd_length(base):
    """Beneath the compensator's own check: the hot-swap cascade ignores an applied block far beyond the stream."""
    from piezo_ff_ros.core.hot_swap import HotSwapCascade

    hs = HotSwapCascade(make_core(base).cfg)
    u = hs.process(held(5e-6), k0=0)
    assert hs.applied(10**12, u) == "ignored"     # a 1e12-sample hold: 14.6 TiB before
    u1 = hs.process(held(5e-6), k0=N)
    assert hs.applied(N, u1) in ("match", "resync")   # tracking restarted with the next block


def test_valid_applied_voltage_still_resynchronises(base):
    core = make_core(base)
    u0 = core.on_reference(S0, held(5e-6), 0.0).voltage[0].u
    core.on_reference(S0 + N * DT, held(5e-6), 0.01)
    core.on_applied(S0, 0.5 * u0, 0.02)
    assert core.hs.resyncs == 1 and core.applied_rejected == 0


def test_refusals_are_logged_at_most_once_a_second_but_all_counted(base, monkeypatch):
    import piezo_ff_ros.core.compensator_core as cc

    now = [100.0]
    monkeypatch.setattr(cc.time, "monotonic", lambda: now[0])
    core = make_core(base)
    lines = sum(len(core.on_reference(S0 + i * N * DT, held(1.0), 0.0).log) for i in range(500))
    assert lines == 1 and core.rejected_blocks == 500
    now[0] += 1.5
    assert "(501 so far)" in core.on_reference(S0, held(1.0), 0.0).log[0][1]


# ---------------------------------------------------------------------------------------------------------------
# the driver's core


@pytest.fixture()
def driver(base):
    from piezo_ff_ros.core.hardware import DriverCore, DriverSettings, LockstepSim

    class Gain:
        def process(self, u):
            return 1e-7 * np.asarray(u)

        def reset(self):
            pass

    clock = [0.0]
    settings = DriverSettings(sample_rate=base.sample_rate, n_axes=2, limits=base.limits)
    return DriverCore(settings, LockstepSim(base.sample_rate, 2, Gain()), now=lambda: clock[0]), clock


def test_driver_is_not_locked_out_by_one_off_grid_first_block(driver):
    core, _ = driver
    core.start()
    em = core.on_block(S0 + 1, np.zeros((N, 2)))
    assert any("off the 50000 ns sample grid" in t for _, t in em.log)
    applied = []
    for i in range(20):
        em = core.on_block(S0 + i * N * DT, np.full((N, 2), 1.0))
        assert not [t for lvl, t in em.log if lvl == ERROR], em.log
        applied += em.applied
    assert core.status()["rejected_blocks"] == 1 and core.status()["blocks_applied"] == 20
    assert core.health()[0] >= WARN


def test_driver_reanchors_after_a_safe_ramp(driver):
    core, clock = driver
    core.start()
    for i in range(5):
        core.on_block(S0 + i * N * DT, np.full((N, 2), 1.0))
    clock[0] += 1.0
    core.tick()
    assert core.state == "safe"
    far = S0 + 10**7 * N * DT   # a new stream far from the old one: applied at once, no confirmation needed
    em = core.on_block(far, np.full((N, 2), 2.0))
    assert core.state == "active" and not any("held back" in t for _, t in em.log)
    assert core.next_stamp == far + N * DT


def test_driver_counts_samples_at_the_limit_whoever_clamped_them(driver, base):
    core, _ = driver
    core.start()
    v = base.limits.voltage
    core.on_block(S0, np.full((N, 2), v))            # clamped by the compensator already: exactly at the limit
    core.on_block(S0 + N * DT, np.full((N, 2), 2 * v))   # clamped here
    core.on_block(S0 + 2 * N * DT, np.full((N, 2), 0.5 * v))
    assert core.status()["saturated_samples"] == 2 * N
