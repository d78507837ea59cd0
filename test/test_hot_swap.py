"""HotSwapCascade (core/hot_swap.py): runtime reconfiguration at block boundaries, bumpless — pure, no ROS."""
import copy
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from piezo_ff_ros.core.compensators.cascade import CompensatorCascade
from piezo_ff_ros.core.config import ConfigError
from piezo_ff_ros.core.hot_swap import HotSwapCascade
from piezo_ff_ros.core.param_map import config_to_params, params_to_config

FS = 20000.0
CTRL = {"A": (-2000.0 * np.eye(2)).tolist(), "B": (2000.0 * np.eye(2)).tolist(),
        "C": np.eye(2).tolist(), "D": np.zeros((2, 2)).tolist()}


@pytest.fixture(scope="module")
def cfg(paper_config):
    # a ready controller instead of an H∞ synthesis keeps these tests fast and independent of the synthesis module
    return replace(paper_config, vibration=replace(paper_config.vibration, controller=CTRL)).validate()


def reference(n=6000):
    t = np.arange(n) / FS
    return np.column_stack([20e-6 * np.sin(2 * np.pi * 10 * t) + 10e-6,
                            15e-6 * np.sin(2 * np.pi * 7 * t + 0.3) + 5e-6])


def run(hs, ref, bs=200, at=None, action=None):
    out = []
    for i in range(0, len(ref), bs):
        if at is not None and i == at:
            action(hs)
        out.append(hs.process(ref[i:i + bs]))
    return np.vstack(out)


def test_swap_to_identical_config_is_invisible(cfg):
    ref = reference()
    plain = run(HotSwapCascade(cfg), ref)
    swapped = run(HotSwapCascade(cfg, crossfade_samples=300), ref, at=2400, action=lambda h: h.request(cfg))
    np.testing.assert_array_equal(plain, swapped)


def test_stage_switch_is_bumpless_and_converges(cfg):
    ref = reference()
    new = replace(cfg, cascade=replace(cfg.cascade, creep=False))
    at = 3000
    hs = HotSwapCascade(cfg, crossfade_samples=400)
    u = run(hs, ref, at=at, action=lambda h: h.request(new))
    assert hs.version == 2 and hs.swaps == 1
    # reference: the same switch done crudely (new cascade from rest, no crossfade) jumps
    crude_old = CompensatorCascade(cfg).process(ref[:at])
    crude_new = CompensatorCascade(new).process(ref[at:])
    jump_crude = np.max(np.abs(crude_new[0] - crude_old[-1]))
    du = np.abs(np.diff(u, axis=0))
    normal = du[500:at - 1].max()  # after the start-up transient from rest
    around = du[at - 1:at + 400].max()
    assert jump_crude > 5 * normal            # the switch does change the output noticeably...
    assert around < 1.5 * normal              # ...but bumplessly: no step bigger than the signal's own
    assert not hs.crossfading
    # after the crossfade the output is the new cascade's alone, and it differs from the old cascade's
    old_only = CompensatorCascade(cfg).process(ref)
    assert np.max(np.abs(u[-1000:] - old_only[-1000:])) > 3 * normal
    tail = reference(8000)[6000:]
    twin = copy.deepcopy(hs.active)
    np.testing.assert_array_equal(hs.process(tail), twin.process(tail))


def test_background_build_keeps_old_cascade_until_ready(cfg):
    gate = threading.Event()

    def slow_factory(c, controller=None):
        if c.cascade.creep is False:
            gate.wait(5)
        return CompensatorCascade(c, controller=controller)

    ref = reference(4000)
    new = replace(cfg, cascade=replace(cfg.cascade, creep=False))
    hs = HotSwapCascade(cfg, crossfade_samples=0, factory=slow_factory)
    ref_out = run(HotSwapCascade(cfg, crossfade_samples=0), ref)
    out = [hs.process(ref[:1000])]
    v = hs.request(new, background=True)
    out.append(hs.process(ref[1000:2000]))          # build not finished: old cascade still running
    assert hs.version == 1 and hs.pending_version == v
    gate.set()
    assert hs.wait_pending(5)
    out.append(hs.process(ref[2000:]))              # swapped at this block boundary
    assert hs.version == v
    out = np.vstack(out)
    np.testing.assert_array_equal(out[:2000], ref_out[:2000])
    assert not np.array_equal(out[2000:], ref_out[2000:])


def test_failed_build_keeps_old_config(cfg):
    def failing(c, controller=None):
        if c.cascade.hysteresis is False:
            raise RuntimeError("vibration: H∞ synthesis failed (γ = 1.3 > gamma_max)")
        return CompensatorCascade(c, controller=controller)

    hs = HotSwapCascade(cfg, factory=failing)
    hs.process(reference(400))
    hs.request(replace(cfg, cascade=replace(cfg.cascade, hysteresis=False)))
    hs.process(reference(400))
    assert hs.version == 1 and hs.failed_builds == 1 and "gamma_max" in hs.last_error


def test_params_round_trip_and_field_named_errors(cfg):
    p = config_to_params(cfg)
    assert len(p["hysteresis.Dp"]) == 4 and abs(p["hysteresis.Dp"][0] - 0.1663e-6) < 1e-15
    back = params_to_config(p, cfg)
    assert back.creep == cfg.creep and back.dynamics == cfg.dynamics and back.cascade == cfg.cascade
    np.testing.assert_array_equal(back.hysteresis.arrays()["Dp"], cfg.hysteresis.arrays()["Dp"])
    for bad, field in [({"hysteresis.Dp": [1.0, 2.0, 2.0, 4.0]}, "hysteresis.Dp"),
                       ({"creep.K": [1.0, 2.0, 3.0]}, "creep.K"),
                       ({"vibration.t_r": -0.1}, "vibration.t_r"),
                       ({"cascade.creep": "yes"}, "cascade.creep"),
                       ({"creep.Cr.xx.den": [1.0, -0.5], "creep.Cr.xx.den_deg": [1]}, "creep.Cr.xx"),
                       ({"vibration.controller.A": [1.0, 0.0, 0.0, 1.0]}, "vibration.controller.A"),
                       ({"hysteresis.Dpp": [1.0]}, "hysteresis.Dpp")]:
        with pytest.raises(ConfigError) as e:
            params_to_config(bad, cfg)
        assert str(e.value).startswith(field), str(e.value)


def _generated_state():
    """Every generated kernel module loaded in this process and how many type signatures each compiled."""
    from piezo_ff_ros.core.kernels import specialise
    return {name: len(getattr(fn, "signatures", ()) or ()) for name, fn in specialise.generated_kernels().items()}


def test_a_new_structure_compiles_while_building_never_on_the_live_path(cfg):
    """Kernels specialised to a stage's structure compile on first use (≈ 1 s): a swap to a controller of a new
    order must compile them while the new cascade is built (off the block path), not in the first live blocks —
    a 1 s stall there would let the driver's stale-input watchdog ramp the stage to safe."""
    rng = np.random.default_rng(20261123)
    n = 5   # an order no other test uses: its kernels are not compiled yet in this process
    A = np.diag(-rng.uniform(500.0, 5000.0, n))
    A[1, 2], A[2, 1] = 3000.0, -3000.0
    new_ctrl = {"A": A.tolist(), "B": rng.uniform(100.0, 900.0, (n, 2)).round(3).tolist(),
                "C": rng.uniform(0.1, 0.4, (2, n)).round(4).tolist(), "D": [[0.93, 0.011], [0.012, 0.91]]}
    new = replace(cfg, vibration=replace(cfg.vibration, controller=new_ctrl)).validate()
    hs = HotSwapCascade(cfg, crossfade_samples=200)
    ref = reference(2000)
    hs.process(ref[:200], k0=0)
    hs.request(new, background=False)          # built (and warmed) here
    built = _generated_state()
    for i in range(200, 2000, 200):            # swap, crossfade, then the new cascade alone
        hs.process(ref[i:i + 200], k0=i)
        hs.applied(i, np.zeros((200, 2)))
    assert hs.version == 2 and not hs.crossfading
    assert _generated_state() == built
