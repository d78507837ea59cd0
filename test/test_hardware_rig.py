"""BackendRig (core/hardware/rig.py): the commissioning code's process/reset over any backend — the existing
open-loop characterisation runs unchanged on the lockstep and clocked simulators, within the limits; no sensor →
refused."""
import numpy as np
import pytest

from piezo_ff_ros.core.characterisation import run_open_loop
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.hardware import ClockedSim, DriverSettings, LockstepSim
from piezo_ff_ros.core.hardware.rig import BackendRig, RigError
from piezo_ff_ros.core.models.plant import Plant
from piezo_ff_ros.core.trajectories import from_dict

CFG = load_config()
FS = CFG.sample_rate


def settings(**kw):
    return DriverSettings(sample_rate=FS, n_axes=2, limits=CFG.limits, **kw)


def test_open_loop_characterisation_on_the_lockstep_rig_equals_the_plant():
    rig = BackendRig(LockstepSim(FS, 2, Plant(CFG)), settings(), block=500)
    traj = from_dict({"type": "circle", "radius": 40.0, "frequency": 20.0, "revolutions": 2})  # volts here
    r = run_open_loop(rig, traj, FS, "circle", ("x", "y"))
    np.testing.assert_array_equal(r.y, Plant(CFG).process(r.u))
    assert rig.limited_samples == 0


def test_clocked_rig_paced_by_the_device_gives_the_plant_answer_to_the_applied_voltage():
    clock = {"n": 0}
    now = lambda: clock["n"] / FS  # noqa: E731

    def sleep(dt):
        clock["n"] += 40

    sim = ClockedSim(FS, 2, Plant(CFG), fifo_depth=4000, latency_samples=30, now=now)
    rig = BackendRig(sim, settings(write_ahead=0.05), block=400, now=now, sleep=sleep)
    u = 30.0 * np.column_stack([np.sin(np.arange(6000) / 300.0), np.cos(np.arange(6000) / 500.0)])
    u[:50] *= np.linspace(0, 1, 50)[:, None]
    y = rig.process(u)
    y_ref = Plant(CFG).process(np.vstack([np.zeros((1, 2)), u]))[1:]   # the device idled at 0 V before
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-15)
    y2 = rig.process(u[:1000])                                         # contiguous with the first call
    assert y2.shape == (1000, 2)


def test_limits_hold_and_strict_mode_refuses_a_clamped_run():
    rig = BackendRig(LockstepSim(FS, 2, Plant(CFG)), settings(), strict=False)
    rig.process(np.full((100, 2), 500.0))
    assert rig.limited_samples == 100
    applied = np.vstack([b for _, b in rig.core.backend.take_applied()] or [np.zeros((0, 2))])
    strict = BackendRig(LockstepSim(FS, 2, Plant(CFG)), settings(), strict=True)
    with pytest.raises(RigError, match="clamped or slew-limited"):
        strict.process(np.full((100, 2), 500.0))
    assert applied.size == 0 or np.abs(applied).max() <= CFG.limits.voltage


def test_a_device_without_sensor_is_refused():
    with pytest.raises(RigError, match="no sensor"):
        BackendRig(LockstepSim(FS, 2, None), settings())
