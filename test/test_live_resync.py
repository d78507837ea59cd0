"""Re-synchronisation on the applied voltage, crossfade consistency and nested swaps — core only.

A fake driver (``VoltageGuard`` + a stall: safe ramp, held samples, late blocks dropped, then a slew-limited
restart) applies what it can and reports it with a lag of a few blocks, as ``voltage_applied`` does; the plant
(same models as the compensator) gets what was applied.  Without the re-synchronisation the held position keeps an
offset after the stall (the defect); with it, it comes back to the target.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.hot_swap import HotSwapCascade
from piezo_ff_ros.core.models.bouc_wen import BoucWenModel
from piezo_ff_ros.core.models.plant import Plant
from piezo_ff_ros.core.param_map import config_to_params, params_to_config
from piezo_ff_ros.core.safety import SafeRampConfig, VoltageGuard

ROOT = Path(__file__).resolve().parents[1]
FS = 20000.0
BLOCK = 200
CTRL = {"A": (-2000.0 * np.eye(2)).tolist(), "B": (2000.0 * np.eye(2)).tolist(),
        "C": np.eye(2).tolist(), "D": np.zeros((2, 2)).tolist()}


@pytest.fixture(scope="module")
def cfg():
    c = load_config(ROOT / "config" / "pt230_94.yaml")
    return replace(c, vibration=replace(c.vibration, controller=CTRL)).validate()


def held_run(cfg, resync: bool, stall=(40, 60), seconds=3.0, lag=3):
    """Hold 10 µm; blocks ``stall[0] … stall[1]-1`` arrive too late: the driver ramps to 0 V and holds."""
    n_blocks = int(seconds * FS) // BLOCK
    hs = HotSwapCascade(cfg, crossfade_samples=200)
    guard = VoltageGuard(replace(cfg.limits, slew=2e5), 2, FS)   # a slower amplifier than the config assumes
    plant = Plant(cfg)
    target = np.array([10e-6, 0.0])
    ys, outbox = [], []
    for b in range(n_blocks):
        k0 = b * BLOCK
        u_cmd = hs.process(np.tile(target, (BLOCK, 1)), k0=k0)
        if stall[0] <= b < stall[1]:
            ramp = guard.ramp_to_safe(SafeRampConfig(duration=0.0, slew=1e4))   # within one block
            applied = np.vstack([ramp, guard.hold(BLOCK - ramp.shape[0])]) if ramp.shape[0] < BLOCK else ramp
        else:
            applied = guard.apply(u_cmd)
        ys.append(plant.process(applied))
        outbox.append((k0, applied))
        if resync and len(outbox) > lag:
            hs.applied(*outbox.pop(0))
    return np.vstack(ys), hs


def test_stall_leaves_an_offset_without_resync_and_none_with_it(cfg):
    y_ref, _ = held_run(cfg, resync=True, stall=(0, 0))    # no stall: where the held point settles
    y_bad, _ = held_run(cfg, resync=False)
    y_ok, hs = held_run(cfg, resync=True)
    err_bad = np.max(np.abs(y_bad[-2000:] - y_ref[-2000:]))
    err_ok = np.max(np.abs(y_ok[-2000:] - y_ref[-2000:]))
    print(f"held-point error 2 s after a 0.2 s stall: {err_bad * 1e9:.1f} nm without, {err_ok * 1e9:.4f} nm with "
          "re-synchronisation")
    assert err_bad > 20e-9          # the defect: a lasting offset (the models no longer describe the plant)
    assert err_ok < 0.5e-9, err_ok  # re-synchronised: back on target
    assert hs.resyncs > 0 and hs.applied_blocks > 0


def test_applied_as_commanded_changes_nothing(cfg):
    t = np.arange(20 * BLOCK) / FS
    ref = np.column_stack([10e-6 + 5e-6 * np.sin(2 * np.pi * 4 * t), 3e-6 * np.cos(2 * np.pi * 2 * t)])
    a, b = HotSwapCascade(cfg), HotSwapCascade(cfg)
    out_a, out_b = [], []
    for i in range(20):
        blk = ref[i * BLOCK:(i + 1) * BLOCK]
        out_a.append(a.process(blk))
        out_b.append(b.process(blk, k0=1000 + i * BLOCK))
        if i >= 2:
            assert b.applied(1000 + (i - 2) * BLOCK, out_b[i - 2]) == "match"
    np.testing.assert_array_equal(np.vstack(out_a), np.vstack(out_b))
    assert b.resyncs == 0
    assert b.applied(0, out_b[0]) == "ignored"   # before the tracked stream
    # a driver's slew limiter rebuilds the voltage as u_prev + (u − u_prev): last-bit differences are no mismatch
    c = HotSwapCascade(cfg)
    u0 = c.process(ref[:BLOCK], k0=0)
    assert c.applied(0, np.nextafter(u0, np.inf)) == "match"


def test_gap_in_the_applied_stream_is_a_hold(cfg):
    hs = HotSwapCascade(cfg)
    ref = np.tile([5e-6, 1e-6], (BLOCK, 1))
    u0 = hs.process(ref, k0=0)
    hs.process(ref, k0=BLOCK)
    hs.process(ref, k0=2 * BLOCK)
    hs.applied(0, u0)
    # block 1 was never applied (dropped); block 2 applied as the held voltage
    assert hs.applied(2 * BLOCK, np.tile(u0[-1], (BLOCK, 1))) == "resync"
    np.testing.assert_array_equal(hs.active.hysteresis.bw_state.u_prev, u0[-1])


def test_crossfade_leaves_the_hysteresis_inverse_on_the_voltage_sent(cfg):
    t = np.arange(30 * BLOCK) / FS
    ref = np.column_stack([10e-6 + 8e-6 * np.sin(2 * np.pi * 5 * t), 4e-6 * np.sin(2 * np.pi * 3 * t)])
    p = config_to_params(cfg)
    for change in ({"cascade.creep": False}, {"hysteresis.A": [v * 1.01 for v in p["hysteresis.A"]]}):
        new = params_to_config(change, cfg)
        hs = HotSwapCascade(cfg, crossfade_samples=500)
        outs = []
        for i in range(30):
            if i == 10:
                hs.request(new)
            outs.append(hs.process(ref[i * BLOCK:(i + 1) * BLOCK]))
            if i == 10:
                assert hs.crossfading
        assert not hs.crossfading
        u = np.vstack(outs)
        hyst = hs.active.hysteresis
        np.testing.assert_array_equal(hyst.bw_state.u_prev, u[-1])
        # its h is the Bouc-Wen state of the voltages sent (same parameters as the inverse)
        model = BoucWenModel(hyst.cfg)
        if "cascade.creep" in change:   # same hysteresis throughout: from the start
            model.process(u)
            np.testing.assert_allclose(hyst.bw_state.h, model.bw_state.h, rtol=1e-9, atol=1e-18)


def test_second_swap_during_a_fade_keeps_fading_out_the_first_old_cascade(cfg):
    t = np.arange(30 * BLOCK) / FS
    ref = np.column_stack([10e-6 + 8e-6 * np.sin(2 * np.pi * 5 * t), 4e-6 * np.sin(2 * np.pi * 3 * t)])
    v2 = replace(cfg, cascade=replace(cfg.cascade, creep=False))
    p = config_to_params(cfg)
    v3 = params_to_config({"cascade.creep": False, "creep.K": [v * 1.02 for v in p["creep.K"]],
                           "vibration.controller.A": [-1500.0, 0.0, 0.0, -1500.0],
                           "vibration.controller.B": [1500.0, 0.0, 0.0, 1500.0]}, cfg)
    hs = HotSwapCascade(cfg, crossfade_samples=1000)
    outs = []
    for i in range(30):
        if i == 10:
            hs.request(v2)
        if i == 11:
            hs.request(v3)
            leaves = hs._fade.leaves() if hs._fade else []
        outs.append(hs.process(ref[i * BLOCK:(i + 1) * BLOCK]))
    assert hs.swaps == 2 and not hs.crossfading
    u = np.vstack(outs)
    du = np.abs(np.diff(u, axis=0))
    normal = du[500:10 * BLOCK - 1].max()
    assert du[10 * BLOCK - 1:].max() < 1.5 * normal   # no step from dropping the first old cascade
    assert len(leaves) == 2  # at the second request the first fade (old, v2) was still running


def test_in_flight_memory_is_bounded_when_nothing_comes_back(cfg):
    hs = HotSwapCascade(cfg, max_inflight_samples=5 * BLOCK)
    ref = np.tile([5e-6, 1e-6], (BLOCK, 1))
    for i in range(23):
        hs.process(ref, k0=i * BLOCK)
        assert hs._inflight_samples == sum(len(r.u) for r in hs._inflight) <= 5 * BLOCK
