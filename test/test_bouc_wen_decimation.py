"""The Bouc-Wen fit's subsampling is set by the record's sines, not by the driver's brief slew-limited ramp to a
sine's first value (the graph records one before the paper's quarter-period-apart pair of sines): the fit is as
good as on the records without the ramp."""
import numpy as np

from piezo_ff_ros.core.characterisation import CharacterisationSettings, hysteresis_trajectories
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.identification.bouc_wen import identify_bouc_wen
from piezo_ff_ros.core.models.plant import Plant
from piezo_ff_ros.core.recording.run import RunData

FS = 2000.0
SLEW = 5.0   # V per sample: the driver's slew limit at 20 kHz (100 V/ms), here per sample of the record
AXES = ("x", "y")


def _runs(ramp: bool):
    """The two-axis hysteresis plan on S0 (hysteresis only), each run from rest, with or without the ramp the
    driver makes from 0 V to the run's first voltage."""
    plant = Plant(load_config().with_sample_rate(FS), stages=("hysteresis",))
    plan = hysteresis_trajectories(CharacterisationSettings(sine_frequency=1.0, sine_periods=1), AXES)
    out = {}
    for role, trajs in plan.items():
        out[role] = []
        for name, traj in trajs:
            _, u = traj.sample(FS)
            n = int(np.ceil(np.max(np.abs(u[0])) / SLEW)) if ramp else 0
            lead = np.linspace(0.0, 1.0, n + 1)[:, None] * u[0][None, :]   # 0 V, then n equal steps to u[0]
            u = np.vstack([lead, u]) if ramp else u
            plant.reset()
            out[role].append(RunData(np.arange(len(u)) / FS, u, plant.process(u), AXES, meta={"experiment": name}))
    return out


def test_a_slew_ramp_at_the_start_of_a_run_does_not_set_the_subsampling():
    plain, ramped = _runs(False), _runs(True)
    fraction = 0.01
    sine_step = max(np.abs(np.diff(r.u, axis=0)).max() for r in plain["fit"])     # 0.63 V per sample at 2 kHz
    u_range = np.ptp(np.vstack([r.u for r in plain["fit"]]))
    by_the_sines = int(fraction * u_range / sine_step)
    # the ramp is there, and its steps alone would hold the fit at the native rate (×1)
    assert np.abs(np.diff(ramped["fit"][-1].u, axis=0)).max() > fraction * u_range > 5 * sine_step
    fit = identify_bouc_wen(ramped["fit"], ramped["validation"], max_step_fraction=fraction, max_nfev=20)
    assert by_the_sines >= 5 and fit.info["decimation"] == by_the_sines
    assert np.all(fit.fit_validation >= 99.5), fit.fit_validation
